"""Writing a section of bench/RESULTS.md, headed by where, when and how it was measured.

Every script that writes a section goes through `write`, so each section's first line says
the commit it was measured at, the date, and the command that ran (taken from the script's
own command line, so it cannot drift from what ran):

    Measured at commit 1a2b3c4 on 2026-12-01 with `uv run python bench/x.py --write`.
"""

from __future__ import annotations

import datetime
import shlex
import subprocess
import sys
from pathlib import Path

RESULTS = Path(__file__).with_name("RESULTS.md")
REPOSITORY = Path(__file__).resolve().parents[1]


def command() -> str:
    """The command that is running, as it would be typed at the repository's top."""
    script = Path(sys.argv[0]).resolve()
    try:
        shown = str(script.relative_to(REPOSITORY))
    except ValueError:
        shown = str(script)
    return "uv run python " + shlex.join([shown, *sys.argv[1:]])


def commit() -> str:
    """HEAD's short hash, and whether tracked files (RESULTS.md aside) differ from it."""
    head = _git("rev-parse", "--short", "HEAD")
    changed = _git("status", "--porcelain", "--untracked-files=no", "--", ".", ":!bench/RESULTS.md")
    return f"{head} (with uncommitted changes)" if changed else head


def measured_line(command_line: str) -> str:
    """The line that heads a section: commit, UTC date and the command."""
    today = datetime.datetime.now(datetime.UTC).date().isoformat()
    return f"Measured at commit {commit()} on {today} with `{command_line}`."


def write(heading: str, body: str, path: Path = RESULTS) -> None:
    """Put `heading`, the measured-at line of this run and `body` in place of that section.

    The section is the one whose heading line is exactly `heading`, up to the next `## `
    heading; a heading not yet in the file is appended at its end.
    """
    if not heading.startswith("## ") or "\n" in heading:
        raise ValueError(f"not a section heading: {heading!r}")
    text = f"{heading}\n\n{measured_line(command())}\n\n{body.strip()}\n"
    replace(path, heading, text)


def replace(path: Path, heading: str, text: str) -> None:
    """Swap the section headed exactly `heading` (up to the next `## `) for `text`."""
    old = path.read_text(encoding="utf-8") if path.exists() else "# Benchmark results\n"
    lines = old.splitlines(keepends=True)
    try:
        start = next(i for i, line in enumerate(lines) if line.rstrip("\n") == heading)
    except StopIteration:
        path.write_text(old.rstrip("\n") + "\n\n" + text, encoding="utf-8")
        return
    end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("## ")), len(lines))
    rest = "".join(lines[end:])
    new = "".join(lines[:start]) + text + ("\n" + rest if rest else "")
    path.write_text(new, encoding="utf-8")


def _git(*args: str) -> str:
    return subprocess.run(
        ["git", *args], cwd=REPOSITORY, capture_output=True, text=True, check=True
    ).stdout.strip()
