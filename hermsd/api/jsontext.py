"""JSON text from outside the daemon, read with its size and nesting bounded before parsing.

Why: `json.loads` recurses once per nesting level, so a line of a few thousand `[` raises
RecursionError (not a JSONDecodeError) deep in the parser; a server that expects only the
latter loses its thread to one short line. Every reader of a request (the control socket,
the web page's POST bodies, the MQTT bridge's command payloads) goes through `loads`, which
refuses a text over its byte limit or nested deeper than MAX_DEPTH before the parser sees it,
and refuses NaN and ±Infinity, which are no JSON numbers.
"""

from __future__ import annotations

import json
import re
from typing import Any

MAX_DEPTH = 16
"""Nesting levels of arrays and objects: a program start, the deepest request, uses 4."""

_STRING = re.compile(r'"(?:[^"\\]|\\.)*"', re.DOTALL)
_BRACKET = re.compile(r"[\[\]{}]")


class JsonTextError(ValueError):
    """Text that is not an acceptable JSON value; the message says why in one line."""


def nesting_depth(text: str, stop_above: int = MAX_DEPTH) -> int:
    """The deepest nesting of arrays and objects in `text` (strings' contents not counted),
    counted up to `stop_above` + 1 at most: a linear scan, whatever the text holds."""
    deepest = depth = 0
    for bracket in _BRACKET.finditer(_STRING.sub('""', text)):
        if bracket.group() in "[{":
            depth += 1
            deepest = max(deepest, depth)
            if deepest > stop_above:
                break
        else:
            depth -= 1
    return deepest


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
    if nesting_depth(text, max_depth) > max_depth:
        raise JsonTextError(f"nested deeper than {max_depth} levels")
    try:
        return json.loads(text, parse_constant=_no_constant)
    except json.JSONDecodeError as error:
        raise JsonTextError(f"not JSON: {error.msg} at column {error.colno}") from None
    except RecursionError:  # not reachable within MAX_DEPTH; kept as the last line of defence
        raise JsonTextError(f"nested deeper than {max_depth} levels") from None
