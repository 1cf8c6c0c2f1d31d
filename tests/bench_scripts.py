"""The bench's scripts (bench/*.py) loaded as modules, for tests of what they compute."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

BENCH = Path(__file__).parents[1] / "bench"


def load(name: str) -> ModuleType:
    """A bench script as a module, its sibling scripts importable by name as when it runs."""
    if str(BENCH) not in sys.path:
        sys.path.append(str(BENCH))  # after everything else: no bench script shadows a module
    spec = importlib.util.spec_from_file_location(f"bench_{name}", BENCH / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module
