"""Every message of simulated runs' logs is valid against the JSON schema its file declares.

Foxglove and any other schema-driven reader know a message only through its schema: a field
the schema leaves out does not exist for them. So every schema is closed (no undeclared
property), and whole runs are checked message by message with a JSON Schema validator: one
element with a mash program and a learned model, two elements with one of them failing, and
a step test (`hermsd tune step --simulate`).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from jsonschema import Draft202012Validator
from mcap.reader import make_reader

from hermsd.cli import commands as cli
from hermsd.log.topics import PERIOD_TOPIC, READING_TOPIC, TOPICS
from hermsd.sim.scenario import Event, Scenario, load_scenario, run

SCENARIOS = Path(__file__).parent.parent / "scenarios"
SHIPPED = Path(__file__).parent.parent / "config" / "hermsd.yaml"

# Two elements as docs/two-elements.md sets them up: the SSR's and the contactor's.
TWO_ELEMENTS = {"tun": {"element_watts": 2000}, "element2": {"backend": "sim", "watts": 3500}}


def logged(directory: Path) -> Iterator[tuple[str, dict[str, Any], dict[str, Any]]]:
    """(topic, schema, message) of every message in the finished files, by mcap's reader."""
    paths = sorted(directory.glob("*.mcap"))
    assert paths and not list(directory.glob("*.part"))
    for path in paths:
        with path.open("rb") as f:
            for schema, channel, message in make_reader(f).iter_messages():
                assert schema is not None and schema.encoding == "jsonschema"
                yield channel.topic, json.loads(schema.data), json.loads(message.data)


def open_objects(schema: Any, where: str = "") -> Iterator[str]:
    """Where an object schema with properties lets an undeclared property through."""
    if isinstance(schema, dict):
        if "properties" in schema and schema.get("additionalProperties") is not False:
            yield where or "(top)"
        for key, value in schema.items():
            yield from open_objects(value, f"{where}/{key}")
    elif isinstance(schema, list):
        for index, value in enumerate(schema):
            yield from open_objects(value, f"{where}/{index}")


def invalid(directory: Path) -> tuple[dict[str, int], list[str]]:
    """Messages per topic, and what is wrong with the first invalid messages."""
    counts: dict[str, int] = {}
    problems: list[str] = []
    validators: dict[str, Draft202012Validator] = {}
    for topic, schema, message in logged(directory):
        counts[topic] = counts.get(topic, 0) + 1
        if topic not in validators:
            Draft202012Validator.check_schema(schema)
            problems += [f"{topic}: open at {at}" for at in open_objects(schema)]
            validators[topic] = Draft202012Validator(schema)
        if len(problems) < 10:
            problems += [
                f"{topic}: {error.json_path}: {error.message}"
                for error in validators[topic].iter_errors(message)
            ]
    return counts, problems


@pytest.fixture(scope="module")
def one_element(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The step mash on one element, a learned model stored, the sensor failing a while."""
    directory = tmp_path_factory.mktemp("one")
    day = load_scenario(SCENARIOS / "step-mash.yaml")
    nack = Event(3600.0, "sensor", ("nack", None), lasts=4.0)  # failed reads: error and errno
    day = dataclasses.replace(day, events=(*day.events, nack))
    run(day, log_dir=directory / "log", state_dir=directory / "state")
    return directory / "log"


@pytest.fixture(scope="module")
def two_elements(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two elements from 50 °C, the SSR's element dead after 75 min (reported: no_heat)."""
    directory = tmp_path_factory.mktemp("two")
    day = Scenario(
        name="two elements",
        duration=1.75 * 3600.0,
        plant={"model": "foptd", "element_watts": 2000, "element2_watts": 3500, "start_c": 50},
        config={**TWO_ELEMENTS, "tun": {**TWO_ELEMENTS["tun"], "litres": 60}},
        events=(Event(1.25 * 3600.0, "heater", "open"),),
    )
    result = run(day, log_dir=directory / "log", keep_records=True)
    assert any(record.no_heat for record in result.records)  # the field is in the log
    return directory / "log"


@pytest.fixture(scope="module")
def step_test(tmp_path_factory: pytest.TempPathFactory) -> Path:
    directory = tmp_path_factory.mktemp("tune")
    logs = directory / "log"
    argv = ["tune", "step", "--simulate", "--config", str(SHIPPED), "--log", str(logs), "--json"]
    cli.main(argv)
    return logs


@pytest.mark.parametrize("run_name", ["one_element", "two_elements", "step_test"])
def test_every_message_is_valid_against_its_closed_schema(
    run_name: str, request: pytest.FixtureRequest
) -> None:
    counts, problems = invalid(request.getfixturevalue(run_name))
    assert problems == []
    assert counts[PERIOD_TOPIC] > 0 and counts[READING_TOPIC] > 0


def test_the_runs_cover_every_topic(one_element: Path, two_elements: Path, step_test: Path) -> None:
    seen = {topic for log in (one_element, two_elements, step_test) for topic, _, _ in logged(log)}
    assert seen == set(TOPICS)


def test_a_field_left_out_of_the_schema_fails_validation() -> None:
    """What the check above catches: a field a message carries and its schema does not."""

    def complaints(schema: dict[str, Any], message: dict[str, Any]) -> list[str]:
        return [error.message for error in Draft202012Validator(schema).iter_errors(message)]

    period = TOPICS[PERIOD_TOPIC].schema
    assert any("'forgotten'" in said for said in complaints(period, {"forgotten": 1.0}))
    config = TOPICS["/hermsd/config"].schema["properties"]["config"]
    assert any("'forgotten'" in said for said in complaints(config, {"forgotten": {}}))
    tun = config["properties"]["tun"]
    assert any("'forgotten'" in said for said in complaints(tun, {"forgotten": 1}))
