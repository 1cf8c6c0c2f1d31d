"""`python -m hermsd.cli`, as the tests and benches run it."""

import sys

from hermsd.cli import main

sys.exit(main())
