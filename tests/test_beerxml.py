"""`hermsd program import`: BeerXML 1.0 mash steps as a program file.

The samples in tests/data/beerxml are written for these tests, laid out as the BeerXML 1.0
standard's example recipe. Expected values are worked by hand from the samples' numbers.
"""

from __future__ import annotations

import errno
from pathlib import Path
from typing import Any

import pytest
import yaml

from hermsd.cli import main
from hermsd.durations import parse_duration
from hermsd.program import model
from hermsd.program.beerxml import BeerXMLError, read, to_yaml

DATA = Path(__file__).parent / "data" / "beerxml"
SINGLE = DATA / "single-infusion.xml"
TWO = DATA / "two-recipes.xml"
PROFILE = DATA / "mash-profile.xml"


def program_of(path: Path, recipe: str | None = None) -> dict[str, Any]:
    """The imported program as the YAML loader sees it, holds in seconds."""
    loaded: dict[str, Any] = yaml.safe_load(to_yaml(read(path, recipe)))
    for step in loaded["steps"]:
        step["hold"] = parse_duration(step["hold"])
    return loaded


def write(tmp_path: Path, text: str, name: str = "recipe.xml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def one_step(step: str) -> str:
    """A file with one recipe whose mash has `step` as its only MASH_STEP's fields."""
    return (
        '<?xml version="1.0"?>\n<RECIPES>\n<RECIPE><NAME>R</NAME><VERSION>1</VERSION>\n'
        "<MASH><NAME>M</NAME><VERSION>1</VERSION><GRAIN_TEMP>20</GRAIN_TEMP><MASH_STEPS>\n"
        f"<MASH_STEP><NAME>Rest</NAME><VERSION>1</VERSION>\n{step}\n</MASH_STEP>\n"
        "</MASH_STEPS></MASH></RECIPE>\n</RECIPES>\n"
    )


def test_single_infusion_gets_a_strike_step_at_the_infusion_temperature() -> None:
    program = program_of(SINGLE)
    assert program["name"] == "Garage Pale Ale"
    assert program["steps"] == [
        {"name": "Strike", "setpoint": 74.2, "hold": 0.0, "confirm": "Mash in"},
        {"name": "Saccharification", "setpoint": 67, "hold": 3600.0, "pump": True},
    ]


def test_header_says_where_the_program_came_from() -> None:
    text = to_yaml(read(SINGLE))
    header = [line for line in text.splitlines() if line.startswith("#")]
    assert header[0] == "# A mash program for hermsd"
    assert any(str(SINGLE) in line for line in header)
    assert any("Garage Pale Ale" in line for line in header)
    assert any("Single Infusion, Medium Body" in line for line in header)


def test_step_mash_ramps_from_the_step_before_and_names_each_step_once() -> None:
    program = program_of(TWO, "weizen step mash")  # the name is matched regardless of case
    # INFUSE_TEMP 165.2 F = (165.2 − 32)·5/9 = 74.0 °C; ramps (66 − 52)/14 = 1.0 and
    # (76 − 66)/5 = 2.0 °C/min; 10.5 min = 630 s. The first rest has no step to ramp from.
    assert program["steps"] == [
        {"name": "Strike", "setpoint": 74, "hold": 0.0, "confirm": "Mash in"},
        {"name": "Rest", "setpoint": 52, "hold": 900.0, "pump": True},
        {"name": "Rest 2", "setpoint": 66, "hold": 3600.0, "ramp": 1.0, "pump": True},
        {"name": "Mash Out", "setpoint": 76, "hold": 630.0, "ramp": 2.0, "pump": True},
    ]
    assert "# RAMP_TIME 2 min not used" in to_yaml(read(TWO, "Weizen Step Mash"))


def test_a_temperature_mash_has_no_strike_step() -> None:
    program = program_of(PROFILE)  # a <MASHS> export: the mash profile's name is the program's
    assert program["name"] == "Temperature Mash, Two Rests"
    assert [s["name"] for s in program["steps"]] == ["Beta Rest", "Alpha Rest"]
    assert program["steps"][1]["ramp"] == 1.5  # (72 − 63)/6


def test_without_infuse_temp_the_strike_is_the_first_rest_temperature(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        one_step("<TYPE>Infusion</TYPE><STEP_TEMP>65.5</STEP_TEMP><STEP_TIME>75</STEP_TIME>"),
    )
    program = program_of(path)
    assert program["steps"][0] == {
        "name": "Strike",
        "setpoint": 65.5,
        "hold": 0.0,
        "confirm": "Mash in",
    }
    assert "INFUSE_TEMP not given" in to_yaml(read(path))


def test_several_recipes_need_a_choice() -> None:
    with pytest.raises(BeerXMLError) as caught:
        read(TWO)
    message = str(caught.value)
    assert "'Weizen Step Mash'" in message and "'Dunkel Decoction'" in message
    assert "--recipe" in message
    with pytest.raises(BeerXMLError, match="no recipe is named 'Stout'"):
        read(TWO, "Stout")


def test_a_decoction_is_refused_with_its_line() -> None:
    with pytest.raises(BeerXMLError) as caught:
        read(TWO, "Dunkel Decoction")
    text = TWO.read_text().splitlines()
    line = int(str(caught.value).split(":")[1])
    assert text[line - 1].strip() == "<MASH_STEP>"
    assert "Decoction to Saccharification" in text[line]
    assert "decoction" in str(caught.value) and "cannot" in str(caught.value)


@pytest.mark.parametrize(
    ("fields", "expected"),
    [
        (
            "<TYPE>Infusion</TYPE><STEP_TEMP>152 F</STEP_TEMP><STEP_TIME>60</STEP_TIME>",
            "STEP_TEMP is '152 F', not a number",
        ),
        (  # the bound and its words agree: water at 100 °C is no mash
            "<TYPE>Infusion</TYPE><STEP_TEMP>100</STEP_TEMP><STEP_TIME>60</STEP_TIME>",
            "STEP_TEMP is 100 °C: expected above 0 and below 100 °C (liquid water)",
        ),
        (
            "<TYPE>Infusion</TYPE><STEP_TEMP>152</STEP_TEMP><STEP_TIME>60</STEP_TIME>",
            "is 152 °C: expected above 0 and below 100 °C (liquid water) (BeerXML gives °C: "
            "was it written in °F?)",
        ),
        ("<TYPE>Infusion</TYPE><STEP_TEMP>66</STEP_TEMP>", "STEP_TIME is missing"),
        (
            "<TYPE>Infusion</TYPE><STEP_TEMP>66</STEP_TEMP><STEP_TIME>-5</STEP_TIME>",
            "expected a finite number >= 0",
        ),
        (
            "<TYPE>Sparge</TYPE><STEP_TEMP>66</STEP_TEMP><STEP_TIME>60</STEP_TIME>",
            "TYPE 'Sparge' is not Infusion, Temperature or Decoction",
        ),
        (
            "<TYPE>Infusion</TYPE><STEP_TEMP>66</STEP_TEMP><STEP_TIME>60</STEP_TIME>"
            "<INFUSE_TEMP>hot</INFUSE_TEMP>",
            "expected a temperature such as 74.5 C",
        ),
        (
            "<TYPE>Infusion</TYPE><STEP_TEMP>66</STEP_TEMP><STEP_TIME>60</STEP_TIME>"
            "<INFUSE_TEMP>240 F</INFUSE_TEMP>",
            "is 115.556 °C: expected above 0 and below 100 °C",
        ),
    ],
)
def test_bad_values_name_the_file_line_and_what_is_right(
    tmp_path: Path, fields: str, expected: str
) -> None:
    path = write(tmp_path, one_step(fields))
    with pytest.raises(BeerXMLError) as caught:
        read(path)
    message = str(caught.value)
    line = 5 if "missing" in expected else 6  # the field's line; the step's when it is absent
    assert message.startswith(f"{path}:{line}: MASH_STEP 'Rest': ")
    assert expected in message
    assert "\n" not in message


def test_bad_xml_names_line_and_column(tmp_path: Path) -> None:
    path = write(tmp_path, "<RECIPES>\n  <RECIPE><NAME>R</NAME>\n  </RECIPES>\n")
    with pytest.raises(BeerXMLError, match=rf"^{path}:3:5: not XML: mismatched tag$"):
        read(path)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        (
            "<RECIPES><RECIPE><NAME>Extract IPA</NAME></RECIPE></RECIPES>",
            "1: recipe 'Extract IPA' has no MASH",
        ),
        (
            "<RECIPES><RECIPE><NAME>R</NAME><MASH><NAME>M</NAME></MASH></RECIPE></RECIPES>",
            "1: the MASH has no MASH_STEP",
        ),
        ("<RECIPES></RECIPES>", "1: <RECIPES> holds no recipe"),
        ("<html><body/></html>", "1: the document is <HTML>, not BeerXML"),
    ],
)
def test_nothing_to_import_is_said(tmp_path: Path, text: str, expected: str) -> None:
    path = write(tmp_path, text)
    with pytest.raises(BeerXMLError, match=f"^{path}:{expected}"):
        read(path)


def test_an_entity_bomb_is_refused_before_it_expands(tmp_path: Path) -> None:
    entities = "".join(f'<!ENTITY e{n} "{f"&e{n - 1};" * 10 if n else "boom"}">' for n in range(10))
    path = write(
        tmp_path,
        f"<?xml version='1.0'?>\n<!DOCTYPE RECIPES [{entities}]>\n"
        "<RECIPES><RECIPE><NAME>&e9;</NAME></RECIPE></RECIPES>",
    )
    with pytest.raises(BeerXMLError, match=rf"^{path}:2: a document type declaration"):
        read(path)


def test_cli_writes_the_file_and_never_replaces_one(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "pale.yaml"
    assert main(["program", "import", str(SINGLE), "-o", str(out)]) == 0
    assert out.read_text(encoding="utf-8") == to_yaml(read(SINGLE))
    out.write_text("# edited by hand\n")
    assert main(["program", "import", str(SINGLE), "-o", str(out)]) == 2
    assert out.read_text() == "# edited by hand\n"
    assert "exists" in capsys.readouterr().err


def test_cli_error_is_one_line_without_traceback(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["program", "import", str(TWO)]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.count("\n") == 1
    assert captured.err.startswith(f"hermsd: {TWO}: holds 2 recipes")
    assert main(["program", "import", str(DATA / "missing.xml")]) == 2
    assert capsys.readouterr().err == f"hermsd: {DATA / 'missing.xml'}: no such file\n"


def test_cli_prints_to_stdout_by_default(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["program", "import", str(TWO), "--recipe", "Weizen Step Mash"]) == 0
    assert capsys.readouterr().out == to_yaml(read(TWO, "Weizen Step Mash"))


def test_an_import_that_program_check_would_refuse_is_not_written(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # A 10 MB step name: shortened in the step, but said in full in its comment, the file
    # would be far over the 64 KiB a program file may be.
    name = "Rest " + "x" * (10 * 1024 * 1024)
    fields = "<TYPE>Temperature</TYPE><STEP_TEMP>66</STEP_TEMP><STEP_TIME>60</STEP_TIME>"
    text = one_step(fields).replace("<NAME>Rest</NAME>", f"<NAME>{name}</NAME>")
    path = write(tmp_path, text)
    out = tmp_path / "huge.yaml"
    assert main(["program", "import", str(path), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and len(err) < 400
    assert err.startswith(f"hermsd: {path}: its program breaks the program file's rules: ")
    assert "bytes long, more than the 64 KiB" in err
    assert not out.exists()
    # A step refused for what it holds names that step in one short line too.
    path = write(tmp_path, text.replace("<STEP_TEMP>66", "<STEP_TEMP>hot"))
    assert main(["program", "import", str(path), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and len(err) < 400 and "STEP_TEMP" in err
    assert not out.exists()


def test_a_recipe_step_named_strike_is_renamed_not_merged(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        "<MASH><NAME>Only a mash</NAME><MASH_STEPS><MASH_STEP><NAME>Strike</NAME>"
        "<TYPE>Infusion</TYPE><STEP_TEMP>66</STEP_TEMP><STEP_TIME>60</STEP_TIME>"
        "</MASH_STEP></MASH_STEPS></MASH>",
    )
    program = program_of(path)  # a <MASH> alone, as some programs export a mash profile
    assert program["name"] == "Only a mash"
    assert [s["name"] for s in program["steps"]] == ["Strike", "Strike 2"]
    assert program["steps"][1]["setpoint"] == 66


def test_more_steps_than_a_program_holds_are_refused(tmp_path: Path) -> None:
    step = (
        "<MASH_STEP><NAME>Rest</NAME><TYPE>Temperature</TYPE><STEP_TEMP>60</STEP_TEMP>"
        "<STEP_TIME>1</STEP_TIME></MASH_STEP>"
    )
    path = write(tmp_path, f"<MASH><NAME>M</NAME><MASH_STEPS>{step * 51}</MASH_STEPS></MASH>")
    with pytest.raises(BeerXMLError, match=r":1: the mash gives 51 steps, more than the 50"):
        read(path)
    path = write(tmp_path, f"<MASH><NAME>M</NAME><MASH_STEPS>{step * 50}</MASH_STEPS></MASH>")
    assert len(read(path).steps) == 50


class _FillsUp:
    """A file that takes ten characters, then finds the disk full."""

    def __init__(self, file: Any) -> None:
        self.file = file

    def __enter__(self) -> _FillsUp:
        return self

    def __exit__(self, *_: object) -> None:
        self.file.close()

    def write(self, text: str) -> int:
        self.file.write(text[:10])
        self.file.flush()
        raise OSError(errno.ENOSPC, "No space left on device")


def test_a_program_cut_by_a_full_disk_is_not_left_behind(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    real_open = Path.open
    monkeypatch.setattr(Path, "open", lambda self, *a, **k: _FillsUp(real_open(self, *a, **k)))
    out = tmp_path / "pale.yaml"
    assert main(["program", "import", str(SINGLE), "-o", str(out)]) == 2
    assert capsys.readouterr().err == f"hermsd: {out}: cannot write: No space left on device\n"
    assert not out.exists()  # a cut program would run with steps missing


@pytest.mark.parametrize(
    ("encoding", "detail"),
    [("klingon", "unknown encoding: klingon"), ("shift_jis", "multi-byte encodings")],
)
def test_an_encoding_that_cannot_be_read_is_said(
    tmp_path: Path, encoding: str, detail: str
) -> None:
    path = tmp_path / "recipe.xml"
    path.write_bytes(f'<?xml version="1.0" encoding="{encoding}"?>\n<RECIPES/>\n'.encode())
    with pytest.raises(BeerXMLError, match=rf"^{path}:1: the declared encoding cannot be read: "):
        read(path)
    with pytest.raises(BeerXMLError, match=detail):
        read(path)


def test_a_windows_encoded_file_is_read(tmp_path: Path) -> None:
    path = tmp_path / "recipe.xml"
    path.write_bytes(
        one_step("<TYPE>Temperature</TYPE><STEP_TEMP>66</STEP_TEMP><STEP_TIME>60</STEP_TIME>")
        .replace('<?xml version="1.0"?>', '<?xml version="1.0" encoding="windows-1252"?>')
        .replace("<NAME>Rest</NAME>", "<NAME>Rast \u20ac</NAME>")
        .encode("windows-1252")
    )
    assert [s.name for s in read(path).steps] == ["Rast \u20ac"]


def latin_1(tmp_path: Path, name: bytes) -> Path:
    """A one-step file declared ISO-8859-1 (as BeerSmith declares it), its step named `name`."""
    path = tmp_path / "recipe.xml"
    path.write_bytes(
        one_step("<TYPE>Temperature</TYPE><STEP_TEMP>66</STEP_TEMP><STEP_TIME>60</STEP_TIME>")
        .replace('<?xml version="1.0"?>', '<?xml version="1.0" encoding="ISO-8859-1"?>')
        .encode("ascii")
        .replace(b"<NAME>Rest</NAME>", b"<NAME>" + name + b"</NAME>")
    )
    return path


def maerzen(directory: Path) -> Path:
    """The single-infusion sample saved as the ISO-8859-1 it declares, its recipe named Märzen:
    the ä is the one byte 0xE4."""
    path = directory / "maerzen.xml"
    text = SINGLE.read_text(encoding="utf-8").replace("Garage Pale Ale", "Märzen")
    path.write_bytes(text.encode("iso-8859-1"))
    assert b"<NAME>M\xe4rzen</NAME>" in path.read_bytes()
    return path


def test_a_latin_1_file_is_read_in_the_encoding_it_declares(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["program", "import", str(maerzen(tmp_path))]) == 0
    out = capsys.readouterr().out
    assert "#   recipe: Märzen\n" in out and yaml.safe_load(out)["name"] == "Märzen"


@pytest.mark.parametrize(
    ("declaration", "encoding"),
    [("", "UTF-8"), (' encoding="UTF-8"', "UTF-8"), (' encoding="us-ascii"', "us-ascii")],
)
def test_bytes_that_are_no_text_in_the_declared_encoding_are_said_where_they_are(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], declaration: str, encoding: str
) -> None:
    path = tmp_path / "recipe.xml"
    data = maerzen(tmp_path).read_bytes().replace(b' encoding="ISO-8859-1"', declaration.encode())
    path.write_bytes(data)
    at = data.index(b"\xe4")
    line, column = data.count(b"\n", 0, at) + 1, at - data.rindex(b"\n", 0, at)
    assert main(["program", "import", str(path)]) == 2
    assert capsys.readouterr().err == (
        f"hermsd: {path}:{line}:{column}: byte 0xE4 is not {encoding} text (save the file as "
        'UTF-8, or declare the encoding it is in, e.g. <?xml version="1.0" '
        'encoding="ISO-8859-1"?> for Latin-1)\n'
    )


def test_beersmiths_windows_text_declared_latin_1_is_read_as_windows_1252(
    tmp_path: Path,
) -> None:
    """BeerSmith declares ISO-8859-1 and writes Windows-1252: 0x96 is its en dash, 0x85 its
    ellipsis (in ISO-8859-1, control characters U+0096 and U+0085)."""
    path = latin_1(tmp_path, b"Rest \x96 62\xb0C\x85")
    assert [s.name for s in read(path).steps] == ["Rest \u2013 62\u00b0C\u2026"]


def test_a_control_character_that_is_no_windows_text_names_its_line_and_field(
    tmp_path: Path,
) -> None:
    path = latin_1(tmp_path, b"Rest \x81")
    with pytest.raises(BeerXMLError) as caught:
        read(path)
    assert str(caught.value) == (
        f"{path}:5: NAME: the control character #x81 is not text (delete it)"
    )


@pytest.mark.parametrize(
    ("path", "recipe"), [(SINGLE, None), (PROFILE, None), (TWO, "Weizen Step Mash")]
)
def test_an_imported_program_is_one_the_daemon_runs(path: Path, recipe: str | None) -> None:
    """The written file passes the program file's own checks, step for step as imported."""
    imported = read(path, recipe)
    program = model.parse(to_yaml(imported), str(path))
    assert [s.name for s in program.steps] == [s.name for s in imported.steps]
    assert [s.setpoint for s in program.steps] == [s.setpoint for s in imported.steps]
    assert [s.hold for s in program.steps] == [60.0 * s.hold_min for s in imported.steps]
    assert [s.confirm for s in program.steps] == [s.confirm for s in imported.steps]
    # The pump runs in every mash step; the Strike's is left to the default, off.
    assert [s.pump for s in program.steps] == [
        None if s.confirm is not None else True for s in imported.steps
    ]


LONG_RECIPE = "Weihenstephaner Hefeweissbier Clone (All Grain)"  # 47 characters
LONG_STEP = "Protein rest with a long decoction-free hold"  # 44 characters


def test_long_names_and_fast_ramps_are_fitted_to_what_a_program_takes(tmp_path: Path) -> None:
    def step(name: str, celsius: int, ramp_min: float) -> str:
        return (
            f"<MASH_STEP><NAME>{name}</NAME><TYPE>Temperature</TYPE><STEP_TEMP>{celsius}"
            f"</STEP_TEMP><STEP_TIME>10</STEP_TIME><RAMP_TIME>{ramp_min}</RAMP_TIME></MASH_STEP>"
        )

    path = write(
        tmp_path,
        f"<RECIPES><RECIPE><NAME>{LONG_RECIPE}</NAME><MASH><NAME>M</NAME><MASH_STEPS>"
        + step(LONG_STEP, 50, 0)
        + step(LONG_STEP, 62, 1)  # 12 °C in 1 min: faster than the 10 °C/min a program ramps
        + step("Mash out", 78, 4)  # 16 °C in 4 min: 4 °C/min, kept
        + "</MASH_STEPS></MASH></RECIPE></RECIPES>",
    )
    text = to_yaml(read(path))
    program = program_of(path)
    assert program["name"] == LONG_RECIPE[:39] + "…"  # 40 characters; in full in the header
    assert f"#   recipe: {LONG_RECIPE}" in text
    names = [s["name"] for s in program["steps"]]
    assert names == [LONG_STEP[:39] + "…", LONG_STEP[:37] + "… 2", "Mash out"]
    assert all(len(name) <= 40 for name in names)
    assert f"# name in the recipe: {LONG_STEP}" in text
    assert "ramp" not in program["steps"][1]
    assert "12 °C/min is faster than a program ramps" in text
    assert program["steps"][2]["ramp"] == 4.0


@pytest.mark.parametrize(
    ("ramp_min", "says"),
    [
        # 10 °C at the slowest ramp, 0.07 °C/min, takes 142.9 min: 142 is the most said
        ("2000", "RAMP_TIME 2000 min for the 10 °C rise is 0.005 °C/min"),
        ("1e308", "RAMP_TIME 1e+308 min for the 10 °C rise is 1e-307 °C/min"),
        ("143", "RAMP_TIME 143 min for the 10 °C rise is 0.0699 °C/min"),
    ],
)
def test_a_ramp_slower_than_a_program_ramps_is_refused_not_changed(
    tmp_path: Path, ramp_min: str, says: str
) -> None:
    path = write(
        tmp_path,
        "<RECIPES><RECIPE><NAME>R</NAME><MASH><NAME>M</NAME><MASH_STEPS>\n"
        "<MASH_STEP><NAME>A</NAME><TYPE>Temperature</TYPE><STEP_TEMP>66</STEP_TEMP>"
        "<STEP_TIME>60</STEP_TIME></MASH_STEP>\n"
        "<MASH_STEP><NAME>B</NAME><TYPE>Temperature</TYPE><STEP_TEMP>76</STEP_TEMP>"
        f"<STEP_TIME>10</STEP_TIME>\n<RAMP_TIME>{ramp_min}</RAMP_TIME></MASH_STEP>\n"
        "</MASH_STEPS></MASH></RECIPE></RECIPES>",
    )
    with pytest.raises(BeerXMLError) as caught:
        read(path)
    assert str(caught.value) == (
        f"{path}:4: MASH_STEP 'B': {says}, slower than a program ramps (0.07 °C/min at least, "
        "so that any ramp ends within 24 h): give it 142 min or less in the recipe, or 0 to "
        "heat at once"
    )


def test_a_ramp_is_written_within_half_a_percent_of_the_recipes_time(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        "<RECIPES><RECIPE><NAME>R</NAME><MASH><NAME>M</NAME><MASH_STEPS>"
        "<MASH_STEP><NAME>A</NAME><TYPE>Temperature</TYPE><STEP_TEMP>66</STEP_TEMP>"
        "<STEP_TIME>60</STEP_TIME></MASH_STEP>"
        "<MASH_STEP><NAME>B</NAME><TYPE>Temperature</TYPE><STEP_TEMP>76</STEP_TEMP>"
        "<STEP_TIME>10</STEP_TIME><RAMP_TIME>130</RAMP_TIME></MASH_STEP>"
        "</MASH_STEPS></MASH></RECIPE></RECIPES>",
    )
    # 10 °C in 130 min = 0.076923 °C/min, written 0.0769: 130.04 min (two decimals gave
    # 0.08, 125 min)
    assert program_of(path)["steps"][1]["ramp"] == 0.0769


def test_a_rest_longer_than_a_program_holds_is_refused_at_its_line(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        one_step("<TYPE>Temperature</TYPE><STEP_TEMP>66</STEP_TEMP><STEP_TIME>1500</STEP_TIME>"),
    )
    with pytest.raises(BeerXMLError) as caught:
        read(path)
    assert str(caught.value) == (
        f"{path}:6: MASH_STEP 'Rest': STEP_TIME 1500 min is more than the 24 h a rest may hold"
    )
