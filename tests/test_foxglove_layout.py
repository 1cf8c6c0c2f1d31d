"""The Foxglove layout and its documentation name only topics and fields the log holds."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from hermsd.log.topics import LOG_TOPIC, PROGRAM_TOPIC, TOPICS

DOCS = Path(__file__).parent.parent / "docs"
LAYOUT = json.loads((DOCS / "foxglove-layout.json").read_text(encoding="utf-8"))

# What the mash program adds to the log (the interface its branch writes): the period
# record's step fields, and the program topic's fields.
PROGRAM_PERIOD_FIELDS = {"step", "step_index", "step_left_s", "next_step"}
PROGRAM_FIELDS = {"t", "event", "program", "step", "name", "setpoint", "message"}


def fields_of(topic: str) -> set[str]:
    if topic == PROGRAM_TOPIC:
        return PROGRAM_FIELDS
    fields = set(TOPICS[topic].schema["properties"])
    return fields | PROGRAM_PERIOD_FIELDS if topic == "/hermsd/period" else fields


def panel_paths(config: dict[str, Any]) -> list[str]:
    return [p["value"] for p in config.get("paths", [])]


def leaves(node: Any) -> list[str]:
    if isinstance(node, str):
        return [node]
    return [*leaves(node["first"]), *leaves(node["second"])]


def test_every_plotted_path_is_a_field_of_a_logged_topic() -> None:
    paths = [p for c in LAYOUT["configById"].values() for p in panel_paths(c)]
    assert {"/hermsd/period.pv", "/hermsd/period.setpoint"} <= set(paths)
    assert {"/hermsd/period.output", "/hermsd/period.applied"} <= set(paths)
    for path in paths:
        topic, _, field = path.partition(".")
        assert field in fields_of(topic), path


def test_the_log_and_program_panels_show_their_topics() -> None:
    configs = LAYOUT["configById"]
    [log_panel] = [c for key, c in configs.items() if key.startswith("RosOut!")]
    assert log_panel["topicToRender"] == LOG_TOPIC
    assert TOPICS[LOG_TOPIC].schema_name == "foxglove.Log"  # what Foxglove's Log panel reads
    [raw] = [c for key, c in configs.items() if key.startswith("RawMessages!")]
    assert raw["topicPath"] == PROGRAM_TOPIC


def test_the_layout_shows_every_panel_it_configures() -> None:
    assert sorted(leaves(LAYOUT["layout"])) == sorted(LAYOUT["configById"])


def test_the_docs_name_every_topic_and_field_of_the_period() -> None:
    text = (DOCS / "foxglove.md").read_text(encoding="utf-8")
    for topic, spec in TOPICS.items():
        assert f"`{topic}`" in text and spec.schema_name in text, topic
    for field in fields_of("/hermsd/period") | PROGRAM_FIELDS:
        assert f"`{field}`" in text, field
