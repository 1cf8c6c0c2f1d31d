"""JSON text from outside the daemon, read with its size and nesting bounded before parsing.

Why: `json.loads` recurses once per nesting level, so a line of a few thousand `[` raises
RecursionError (not a JSONDecodeError) deep in the parser; a server that expects only the
latter loses its thread to one short line. Every reader of JSON from outside (the control
socket's requests, the web page's POST bodies; the MQTT bridge takes plain numbers and words,
no JSON) goes through `loads`, which refuses a text over its byte limit or nested deeper
than MAX_DEPTH before the parser sees it, and refuses NaN and ±Infinity, which are no JSON
numbers.
"""

from __future__ import annotations

import functools
import json
import re
from typing import Any

MAX_DEPTH = 16
"""Nesting levels of arrays and objects: a program start, the deepest request, uses 4."""

_ESCAPE = re.compile(r"\\.", re.DOTALL)
_SHAPE: dict[int, str | None] = {code: None for code in range(128)}  # ASCII but brackets: gone
_SHAPE.update({ord("["): "(", ord("{"): "(", ord("]"): ")", ord("}"): ")"})
"""Outside strings, JSON is ASCII: anything else left in can only stop a match below, which
then says the text is deeper than it may be; the parser refuses that text anyway."""


class JsonTextError(ValueError):
    """Text that is not an acceptable JSON value; the message says why in one line."""


def deeper_than(text: str, levels: int) -> bool:
    """Whether arrays and objects in `text` nest deeper than `levels` (strings' contents not
    counted). Escapes dropped, the strings' contents lie between the quotes; the brackets
    outside, as parentheses, are matched by one regular expression without backtracking: a
    scan in C, linear whatever the text holds, so that the server thread holds the
    interpreter's lock (the control loop waiting for it) for no walk in Python over 64 KiB of
    brackets (bench/json_depth.py)."""
    outside = "".join(_ESCAPE.sub("", text).split('"')[::2])
    return _deeper_pattern(levels + 1).match(outside.translate(_SHAPE)) is not None


def _balanced(levels: int) -> str:
    """Complete groups nested at most `levels` deep, each taken whole (possessive)."""
    return "" if levels == 0 else rf"(?:\({_balanced(levels - 1)}\))*+"


@functools.cache
def _deeper_pattern(levels: int) -> re.Pattern[str]:
    """What opens `levels` groups one inside another: complete groups too shallow to, then
    one opened, and within it `levels` - 1 more."""
    pattern = ""
    for level in range(1, levels + 1):
        pattern += _balanced(levels - level) + r"\("
    return re.compile(pattern)


def _no_constant(name: str) -> float:
    raise JsonTextError(f"{name} is not a number here (send a finite number)")


def loads(data: str | bytes, max_bytes: int, max_depth: int = MAX_DEPTH) -> Any:
    """The JSON value in `data`, or JsonTextError saying what is wrong with it."""
    if len(data) > max_bytes:
        raise JsonTextError(f"longer than {max_bytes} bytes")
    if isinstance(data, bytes):
        try:
            text = data.decode("utf-8")
        except UnicodeDecodeError:
            raise JsonTextError("not UTF-8 text") from None
    else:
        text = data
    if deeper_than(text, max_depth):
        raise JsonTextError(f"nested deeper than {max_depth} levels")
    try:
        return json.loads(text, parse_constant=_no_constant)
    except json.JSONDecodeError as error:
        raise JsonTextError(f"not JSON: {error.msg} at column {error.colno}") from None
    except RecursionError:  # not reachable within MAX_DEPTH; kept as the last line of defence
        raise JsonTextError(f"nested deeper than {max_depth} levels") from None
