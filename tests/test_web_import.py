"""A recipe from the page: a BeerXML file (its bytes, base64) or pasted XML made into the
program `hermsd program import` writes, by its own code and checks, logged in only, a
refusal in one line; the program then starts as any program from the page."""

from __future__ import annotations

import base64
import time
from pathlib import Path

import pytest
from test_beerxml import maerzen
from test_web import LoggedIn, _client, live, logged_in
from webpage import TIMEOUT, Site

from hermsd.cli import main

__all__ = ["live", "logged_in"]  # the fixtures, shared with test_web.py

DATA = Path(__file__).parent / "data" / "beerxml"
IMPORT = "/api/program/import"


def _file(name: str) -> dict[str, object]:
    return {"data": base64.b64encode((DATA / name).read_bytes()).decode(), "filename": name}


def _cli_import(name: str, capsys: pytest.CaptureFixture[str]) -> str:
    """What `hermsd program import NAME` prints, run beside the file (its header names it)."""
    capsys.readouterr()
    assert main(["program", "import", name]) == 0
    return capsys.readouterr().out


@pytest.fixture
def beside_the_samples(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(DATA)


def test_an_uploaded_recipe_makes_the_clis_program_and_it_starts(
    live: Site,
    logged_in: LoggedIn,
    capsys: pytest.CaptureFixture[str],
    beside_the_samples: None,
) -> None:
    client, token = logged_in
    headers = {"x-csrf-token": token}
    reply = client.post(IMPORT, json=_file("single-infusion.xml"), headers=headers)
    assert reply.status_code == 200, reply.text
    made = reply.json()
    assert made["yaml"] == _cli_import("single-infusion.xml", capsys)
    assert not live.daemon.program.active  # made only: nothing sent to the daemon
    body = {"yaml": made["yaml"], "filename": "single-infusion.yaml"}
    try:
        started = client.post("/api/program", json=body, headers=headers)
        assert started.status_code == 200, started.text
        program = started.json()["status"]["program"]
        assert (program["name"], program["steps"]) == (made["name"], made["steps"])
    finally:
        stop = {"cmd": "program", "action": "stop"}
        assert client.post("/api/command", json=stop, headers=headers).status_code == 200
    deadline = time.monotonic() + TIMEOUT
    while live.daemon.program.active:
        assert time.monotonic() < deadline
        time.sleep(0.01)


def test_pasted_xml_and_a_recipe_chosen_among_several(
    logged_in: LoggedIn, capsys: pytest.CaptureFixture[str], beside_the_samples: None
) -> None:
    client, token = logged_in
    headers = {"x-csrf-token": token}
    pasted = {"xml": (DATA / "two-recipes.xml").read_text("utf-8"), "filename": "two-recipes.xml"}
    reply = client.post(IMPORT, json=pasted, headers=headers)
    assert reply.status_code == 400
    error = reply.json()["error"]
    assert "\n" not in error and error.startswith("two-recipes.xml: holds 2 recipes")
    assert error.endswith("choose one with the Recipe field")
    chosen = {**pasted, "recipe": "Weizen Step Mash"}
    reply = client.post(IMPORT, json=chosen, headers=headers)
    assert reply.status_code == 200, reply.text
    capsys.readouterr()
    assert main(["program", "import", "two-recipes.xml", "--recipe", "Weizen Step Mash"]) == 0
    assert reply.json()["yaml"] == capsys.readouterr().out


def test_a_latin_1_recipe_uploaded_or_pasted_makes_the_clis_program(
    logged_in: LoggedIn,
    capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The file's bytes are read in the ISO-8859-1 they declare; pasted, the XML is text the
    browser has decoded already, its declaration naming the bytes it was saved as."""
    client, token = logged_in
    data = maerzen(tmp_path).read_bytes()
    monkeypatch.chdir(tmp_path)
    made = _cli_import("maerzen.xml", capsys)
    assert "#   recipe: Märzen\n" in made
    uploaded = {"data": base64.b64encode(data).decode(), "filename": "maerzen.xml"}
    pasted = {"xml": data.decode("iso-8859-1"), "filename": "maerzen.xml"}
    for body in (uploaded, pasted):
        reply = client.post(IMPORT, json=body, headers={"x-csrf-token": token})
        assert reply.status_code == 200, reply.text
        assert (reply.json()["name"], reply.json()["yaml"]) == ("Märzen", made)


@pytest.mark.parametrize(
    ("body", "status", "says"),
    [
        ({**_file("two-recipes.xml"), "recipe": "Dunkel Decoction"}, 400, "decoction"),
        ({"xml": "<RECIPES><RECIPE>", "filename": "cut.xml"}, 400, "cut.xml:1"),
        (
            {"data": base64.b64encode(b"<RECIPES>M\xe4rzen").decode(), "filename": "m.xml"},
            400,
            "m.xml:1:11: byte 0xE4 is not UTF-8 text (save the file as UTF-8, or declare",
        ),
        ({"xml": "  "}, 400, "choose a BeerXML file or paste its XML"),
        ({"data": "not base64!", "filename": "x.xml"}, 400, "base64"),
        ({"xml": "<a/>", "filename": "../x.xml"}, 400, "filename: expected a file"),
        ({"xml": "<a/>", "run": True}, 400, "unknown field(s) run"),
        ({"xml": "x" * 600_000}, 400, "longer than 524288 bytes"),
    ],
)
def test_a_recipe_that_makes_no_program_is_refused_in_one_line(
    live: Site, logged_in: LoggedIn, body: dict[str, object], status: int, says: str
) -> None:
    client, token = logged_in
    reply = client.post(IMPORT, json=body, headers={"x-csrf-token": token})
    error = reply.json()["error"]
    assert reply.status_code == status and says in error and "\n" not in error, error
    assert not live.daemon.program.active


def test_an_import_needs_the_login_and_its_token(live: Site, logged_in: LoggedIn) -> None:
    body = _file("single-infusion.xml")
    with _client(live) as stranger:
        assert stranger.post(IMPORT, json=body).status_code == 401
    client, _token = logged_in
    assert client.post(IMPORT, json=body).status_code == 403
