"""The bounded JSON reader every request goes through: depth and size refused before parsing."""

import pytest

from hermsd.api.jsontext import MAX_DEPTH, JsonTextError, deeper_than, loads


@pytest.mark.parametrize(
    ("text", "depth"),
    [
        # By hand: [ [ "[[[" , { } ] ] opens [, [, { : three levels; the string's do not count.
        ('[["[[[",{}]]', 3),
        ('{"a": "\\"[[[["}', 1),
        ("[[],[[]],[[[]]]]", 4),  # siblings 2, 3 and 4 deep under one array: the deepest
        ('{"a": [{"b": [1]}], "c": "]]"}', 4),
        ("[[[", 3),  # opened, never closed: as deep as it went
        ('["\\\\", [[]]]', 3),  # an escaped backslash ends the string
        ("[]" * 100, 1),
        ('"[[["', 0),
    ],
)
def test_depth_counts_brackets_outside_strings_only(text: str, depth: int) -> None:
    assert deeper_than(text, depth - 1) or depth == 0
    assert not deeper_than(text, depth)


@pytest.mark.parametrize("opener", ["[", '{"a":'])
def test_a_deep_line_is_refused_not_a_recursion_error(opener: str) -> None:
    with pytest.raises(JsonTextError, match=f"deeper than {MAX_DEPTH}"):
        loads(opener * 3000, max_bytes=1 << 16)


def test_the_deepest_allowed_value_parses() -> None:
    text = "[" * MAX_DEPTH + "]" * MAX_DEPTH
    value = loads(text, max_bytes=1 << 16)
    for _ in range(MAX_DEPTH - 1):
        value = value[0]
    assert value == []
    with pytest.raises(JsonTextError):
        loads("[" + text + "]", max_bytes=1 << 16)


def test_size_bytes_and_constants_refused() -> None:
    with pytest.raises(JsonTextError, match="longer than 10 bytes"):
        loads(b'{"a": "0123456789"}', max_bytes=10)
    with pytest.raises(JsonTextError, match="not UTF-8"):
        loads(b'"\xff"', max_bytes=10)
    with pytest.raises(JsonTextError, match="NaN is not a number"):
        loads("[NaN]", max_bytes=10)
    with pytest.raises(JsonTextError, match="not JSON"):
        loads("[1,", max_bytes=10)
