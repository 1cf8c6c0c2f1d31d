"""A BeerXML 1.0 recipe's mash steps as a hermsd mash program (the YAML `program start` takes).

Brewing software (BeerSmith, Brewfather, Brewtarget) exports recipes as BeerXML 1.0. Its
MASH holds MASH_STEPs with fixed units: STEP_TEMP in °C, STEP_TIME and RAMP_TIME in minutes.
Each step becomes a program step holding STEP_TEMP for STEP_TIME from when the water (the
mash, with a mash sensor) is in the band, with the pump on. A mash that begins with an
infusion gets a Strike step before it: the strike water (INFUSE_TEMP, a display field with
its unit, else the first rest's temperature), held with the pump off until the brewer
confirms "Mash in". RAMP_TIME becomes a ramp rate where the temperature rises from the step
before. A decoction is refused: the HLT cannot boil part of the mash, and a program
that pretended to would leave the rest it follows unheld and the brewer misled.

The XML is read with the standard library's expat, with any document type declaration
refused: BeerXML uses none, and without one no entity can be declared, so neither an entity
expansion bomb nor an external entity can be met (expat ≥ 2.4 also bounds expansion by
itself). The file is read whole only if under MAX_BYTES. So defusedxml would add nothing.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from xml.parsers import expat

from hermsd.files import NotRegularFile, read_regular
from hermsd.program import model

MAX_BYTES = 16 * 1024 * 1024  # a whole recipe database export is a few MB
MAX_STEPS = 50  # as the program file allows
MAX_NAME = model.NAME_LENGTH
STRIKE_NAME = "Strike"
MASH_IN = "Mash in"
MASH_TYPES = ("infusion", "temperature", "decoction")
_DISPLAY_TEMPERATURE = re.compile(r"\s*([-+]?\d+(?:\.\d*)?|\.\d+)\s*(°?\s*[CF])?\s*", re.IGNORECASE)


class BeerXMLError(ValueError):
    """A file that does not give a mash program; the message is one line: FILE:LINE: what."""


@dataclass(slots=True)
class Node:
    """An XML element: its tag (upper case, as BeerXML writes them), text and line."""

    tag: str
    line: int
    text: str = ""
    children: list[Node] = field(default_factory=list)

    def child(self, tag: str) -> Node | None:
        return next((c for c in self.children if c.tag == tag), None)

    def all(self, tag: str) -> list[Node]:
        return [c for c in self.children if c.tag == tag]


@dataclass(frozen=True, slots=True)
class Step:
    """One step of the program as it is written out."""

    name: str
    setpoint: float  # °C
    hold_min: float
    ramp: float | None = None  # °C per minute
    confirm: str | None = None
    note: str | None = None  # a comment written above the step


@dataclass(frozen=True, slots=True)
class Program:
    """The program imported, and where from."""

    name: str
    source: str  # the file
    recipe: str | None  # the recipe's name, None for a mash profile exported alone
    mash: str | None  # the mash profile's name
    steps: tuple[Step, ...]


# -- reading ------------------------------------------------------------------------------------


def read(path: Path, recipe: str | None = None) -> Program:
    """The mash program of the recipe in `path` (the one named `recipe` when it holds several)."""
    try:
        data = read_regular(path, MAX_BYTES)
    except FileNotFoundError:
        raise BeerXMLError(f"{path}: no such file") from None
    except NotRegularFile as error:
        raise BeerXMLError(f"{path}: {error}") from None
    except OSError as error:
        raise BeerXMLError(f"{path}: cannot be read: {error.strerror or error}") from None
    return program_of(data, str(path), recipe)


def program_of(
    data: bytes | str, source: str, recipe: str | None, choose: str = "--recipe NAME"
) -> Program:
    """The mash program of the recipe in `data`, read from `source` (a file, or the web page's
    upload or pasted XML); `choose`: how the brewer names one of several recipes there."""
    return convert(parse(data, source), source, recipe, choose)


def parse(data: bytes | str, source: str) -> Node:
    """The element tree of `data`, each element with its line; BeerXMLError if not XML.

    A file's bytes are read in the encoding its XML declaration names (UTF-8 when it names
    none): expat decodes them, so a recipe saved as ISO-8859-1 reads as written. Text (XML
    pasted in the page) is read as it stands: it is decoded already, and its declaration
    names the encoding of bytes it no longer is."""
    parser = expat.ParserCreate()
    root = Node("", 0)
    stack = [root]
    declared: list[str | None] = [None]  # the XML declaration's encoding, if it names one

    def declaration(_version: str, encoding: str | None, _standalone: int) -> None:
        declared[0] = encoding

    def start(tag: str, _attributes: dict[str, str]) -> None:
        node = Node(tag.upper(), parser.CurrentLineNumber)
        stack[-1].children.append(node)
        stack.append(node)

    def end(_tag: str) -> None:
        stack.pop()

    def text(chunk: str) -> None:
        stack[-1].text += _windows_text(chunk, f"{source}:{parser.CurrentLineNumber}", stack[-1])

    def refuse_doctype(*_: object) -> None:
        raise BeerXMLError(
            f"{source}:{parser.CurrentLineNumber}: a document type declaration (<!DOCTYPE>) "
            "is not read: BeerXML needs none (remove it)"
        )

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.CharacterDataHandler = text
    parser.StartDoctypeDeclHandler = refuse_doctype
    parser.XmlDeclHandler = declaration
    try:
        parser.Parse(data, True)
    except BeerXMLError:
        raise  # a document type declaration, refused
    except expat.ExpatError as error:
        where = f"{source}:{error.lineno}:{error.offset + 1}"
        what = _undecodable(data, declared[0], parser.ErrorByteIndex)
        what = what or f"not XML: {expat.ErrorString(error.code)}"
        raise BeerXMLError(f"{where}: {what}") from None
    except (LookupError, ValueError) as error:  # an encoding Python lacks, or expat cannot use
        raise BeerXMLError(
            f"{source}:1: the declared encoding cannot be read: {error} (save it as UTF-8)"
        ) from None
    return root.children[0]


def _undecodable(data: bytes | str, declared: str | None, stopped_at: int) -> str | None:
    """Why expat stopped at byte `stopped_at`, when it is a byte that is no text in the
    encoding the file declares (expat says only "invalid token"); None when it is not, and
    for text, which is decoded already."""
    if isinstance(data, str):
        return None
    encoding = declared or "UTF-8"
    try:
        data.decode(encoding)
    except UnicodeDecodeError as error:
        if error.start == stopped_at:
            return (
                f"byte 0x{data[stopped_at]:02X} is not {encoding} text (save the file as "
                "UTF-8, or declare the encoding it is in, e.g. "
                '<?xml version="1.0" encoding="ISO-8859-1"?> for Latin-1)'
            )
    return None


_UNDEFINED_IN_1252 = frozenset("\x81\x8d\x8f\x90\x9d")


def _windows_text(chunk: str, where: str, element: Node) -> str:
    """`chunk` with each C1 control character made the Windows-1252 character of its byte:
    BeerSmith writes Windows-1252 but declares ISO-8859-1, where its en dash (0x96) reads as
    the control character U+0096. DEL, or a byte Windows-1252 leaves undefined, is refused
    at its line and field."""
    if not any("\x7f" <= c <= "\x9f" for c in chunk):
        return chunk
    text = []
    for c in chunk:
        if c == "\x7f" or c in _UNDEFINED_IN_1252:
            raise BeerXMLError(
                f"{where}: {element.tag}: the control character #x{ord(c):02X} is not text "
                "(delete it)"
            )
        text.append(bytes([ord(c)]).decode("cp1252") if "\x80" <= c <= "\x9f" else c)
    return "".join(text)


def convert(root: Node, source: str, wanted: str | None, choose: str = "--recipe NAME") -> Program:
    """The program of the recipe (or mash profile) `wanted`, or of the only one in `root`."""
    if root.tag == "RECIPES":
        found = [(_text(r, "NAME"), r.child("MASH"), r) for r in root.all("RECIPE")]
        kind = "recipe"
    elif root.tag == "RECIPE":
        found = [(_text(root, "NAME"), root.child("MASH"), root)]
        kind = "recipe"
    elif root.tag in ("MASHS", "MASH"):
        mashes = root.all("MASH") if root.tag == "MASHS" else [root]
        found = [(_text(m, "NAME"), m, m) for m in mashes]
        kind = "mash profile"
    else:
        raise BeerXMLError(
            f"{source}:{root.line}: the document is <{root.tag}>, not BeerXML "
            "(<RECIPES> holding <RECIPE>s, or <MASHS> holding <MASH>es)"
        )
    if not found:
        raise BeerXMLError(f"{source}:{root.line}: <{root.tag}> holds no {kind}")
    if wanted is not None:
        chosen = [f for f in found if (f[0] or "").casefold() == wanted.strip().casefold()]
        if not chosen:
            raise BeerXMLError(
                f"{source}: no {kind} is named {wanted!r} (it holds {_names(found)})"
            )
    elif len(found) > 1:
        raise BeerXMLError(
            f"{source}: holds {len(found)} {kind}s ({_names(found)}): choose one with {choose}"
        )
    else:
        chosen = found
    name, mash, element = chosen[0]
    if mash is None:
        raise BeerXMLError(
            f"{source}:{element.line}: recipe {_shortened(name or '(unnamed)')!r} has no MASH "
            "(an extract recipe has none): nothing to import"
        )
    steps = _steps(mash, source)
    mash_name = _text(mash, "NAME")
    title = _shortened(name or mash_name or Path(source).stem)  # in full in the header
    return Program(title, source, name if kind == "recipe" else None, mash_name, steps)


def _shortened(name: str, room: int = MAX_NAME) -> str:
    """`name` cut to `room` characters (a program's names are short), an ellipsis at the cut."""
    return name if len(name) <= room else name[: room - 1].rstrip() + "…"


def _names(found: list[tuple[str | None, Node | None, Node]]) -> str:
    return ", ".join(
        repr(_shortened(name)) if name else f"(unnamed, line {e.line})" for name, _, e in found
    )


def _steps(mash: Node, source: str) -> tuple[Step, ...]:
    """The program's steps from the MASH's MASH_STEPS, a Strike step first for an infusion."""
    container = mash.child("MASH_STEPS")
    raw = container.all("MASH_STEP") if container is not None else []
    if not raw:
        where = container.line if container is not None else mash.line
        raise BeerXMLError(f"{source}:{where}: the MASH has no MASH_STEP: nothing to import")
    steps: list[Step] = []
    previous: float | None = None
    for index, element in enumerate(raw):
        name = _text(element, "NAME")
        if not name:
            raise BeerXMLError(f"{source}:{element.line}: MASH_STEP {index + 1} has no NAME")
        shown = _shortened(name)  # in messages: one line, however long the recipe's name
        kind = (_text(element, "TYPE") or "").casefold()
        if kind not in MASH_TYPES:
            raise BeerXMLError(
                f"{source}:{_line(element, 'TYPE')}: MASH_STEP {shown!r}: TYPE "
                f"{_text(element, 'TYPE') or '(missing)'!r} is not Infusion, Temperature or "
                "Decoction"
            )
        if kind == "decoction":
            raise BeerXMLError(
                f"{source}:{element.line}: MASH_STEP {shown!r} is a decoction: the HLT cannot "
                "boil part of the mash, so it is not imported (make it a Temperature step in "
                "the recipe, or write the program by hand with a confirm where the decoction "
                "is pulled)"
            )
        setpoint = _temperature(element, "STEP_TEMP", source, shown)
        hold = _number(element, "STEP_TIME", source, shown, required=True)
        if hold is not None and hold * 60.0 > model.MAX_HOLD_S:
            raise BeerXMLError(
                f"{source}:{_line(element, 'STEP_TIME')}: MASH_STEP {shown!r}: STEP_TIME "
                f"{hold:g} min is more than the {model.MAX_HOLD_S / 3600:g} h a rest may hold"
            )
        ramp_time = _number(element, "RAMP_TIME", source, shown, required=False)
        if index == 0 and kind == "infusion":
            strike = _infuse_temperature(element, source, shown)
            note = None if strike is not None else "INFUSE_TEMP not given: the first rest's"
            steps.append(
                Step(
                    STRIKE_NAME,
                    setpoint if strike is None else strike,
                    0.0,
                    confirm=MASH_IN,
                    note=None if note is None else f"{note} temperature",
                )
            )
        ramp, note = None, None
        if ramp_time:
            if previous is not None and setpoint > previous:
                ramp, note = _ramp(setpoint - previous, ramp_time, element, source, shown)
            else:
                note = f"RAMP_TIME {ramp_time:g} min not used: no rise from a step before"
        steps.append(Step(name, setpoint, hold or 0.0, ramp, note=note))
        previous = setpoint
    if len(steps) > MAX_STEPS:
        raise BeerXMLError(
            f"{source}:{mash.line}: the mash gives {len(steps)} steps, more than the "
            f"{MAX_STEPS} a program may have"
        )
    return tuple(_unique(steps))


def _ramp(
    rise: float, ramp_time: float, element: Node, source: str, step: str
) -> tuple[float | None, str | None]:
    """The rate of a rise of `rise` °C in `ramp_time` min, to 3 significant digits (within
    0.5 % of the recipe's time), and a note when it is not used; a rate slower than a program
    can ramp is refused, as no program step says what the recipe asks."""
    rate = rise / ramp_time
    written = float(f"{rate:.3g}")
    if rate > model.MAX_RAMP:
        return None, (
            f"RAMP_TIME {ramp_time:g} min not used: {written:g} °C/min is faster than "
            f"a program ramps ({model.MAX_RAMP:g} °C/min at most): heated at once"
        )
    if rate < model.MIN_RAMP:
        longest = math.floor(rise / model.MIN_RAMP)
        raise BeerXMLError(
            f"{source}:{_line(element, 'RAMP_TIME')}: MASH_STEP {step!r}: RAMP_TIME "
            f"{ramp_time:g} min for the {rise:g} °C rise is {written:g} °C/min, slower than a "
            f"program ramps ({model.MIN_RAMP:g} °C/min at least, so that any ramp ends "
            f"within {model.MAX_HOLD_S / 3600:g} h): give it {longest} min or less in the "
            "recipe, or 0 to heat at once"
        )
    return written, None


def _unique(steps: list[Step]) -> list[Step]:
    """The steps with names short enough and unique (a program names each step once):
    "Rest", "Rest 2"; a name shortened says its full text in the step's comment."""
    seen: set[str] = set()
    unique = []
    for step in steps:
        name, n = _shortened(step.name), 1
        while name.casefold() in seen:
            n += 1
            name = f"{_shortened(step.name, MAX_NAME - len(str(n)) - 1)} {n}"
        seen.add(name.casefold())
        unique.append(step if name == step.name else _renamed(step, name))
    return unique


def _renamed(step: Step, name: str) -> Step:
    note = step.note
    if len(step.name) > MAX_NAME:
        shortened = f"name in the recipe: {step.name}"
        note = shortened if note is None else f"{note}; {shortened}"
    return Step(name, step.setpoint, step.hold_min, step.ramp, step.confirm, note)


def _text(element: Node, tag: str) -> str | None:
    """The child's text with its white space made single spaces; None if absent or blank."""
    child = element.child(tag)
    text = " ".join(child.text.split()) if child is not None else ""
    return text or None


def _line(element: Node, tag: str) -> int:
    child = element.child(tag)
    return child.line if child is not None else element.line


def _number(element: Node, tag: str, source: str, step: str, *, required: bool) -> float | None:
    """A plain non-negative number, as BeerXML writes its fixed-unit fields."""
    text = _text(element, tag)
    where = f"{source}:{_line(element, tag)}: MASH_STEP {step!r}: {tag}"
    if text is None:
        if required:
            raise BeerXMLError(f"{where} is missing")
        return None
    try:
        value = float(text)
    except ValueError:
        raise BeerXMLError(
            f"{where} is {text!r}, not a number (BeerXML writes °C and minutes as plain "
            "numbers, without units)"
        ) from None
    if not math.isfinite(value) or value < 0:
        raise BeerXMLError(f"{where} is {text!r}: expected a finite number >= 0")
    return value


def _temperature(element: Node, tag: str, source: str, step: str) -> float:
    value = _number(element, tag, source, step, required=True)
    assert value is not None  # required
    return _water(value, f"{source}:{_line(element, tag)}: MASH_STEP {step!r}: {tag}")


def _water(celsius: float, where: str) -> float:
    """`celsius` if liquid water can be at it; a °F value is said to be one."""
    if not 0.0 < celsius < 100.0:
        hint = " (BeerXML gives °C: was it written in °F?)" if celsius >= 100.0 else ""
        raise BeerXMLError(
            f"{where} is {celsius:g} °C: expected above 0 and below 100 °C (liquid water){hint}"
        )
    return round(celsius, 2)


def _infuse_temperature(element: Node, source: str, step: str) -> float | None:
    """INFUSE_TEMP, a display field with its unit ("74.5 C", "166.1 F"), in °C; None if absent.

    Without a unit it is taken as °C, the unit of every BeerXML temperature.
    """
    text = _text(element, "INFUSE_TEMP")
    if text is None:
        return None
    where = f"{source}:{_line(element, 'INFUSE_TEMP')}: MASH_STEP {step!r}: INFUSE_TEMP"
    match = _DISPLAY_TEMPERATURE.fullmatch(text)
    if match is None:
        raise BeerXMLError(f"{where} is {text!r}: expected a temperature such as 74.5 C or 166 F")
    value = float(match[1])
    if (match[2] or "C").upper().endswith("F"):
        value = (value - 32.0) * 5.0 / 9.0
    return _water(value, where)


# -- writing ------------------------------------------------------------------------------------


def to_yaml(program: Program) -> str:
    """The program file's text: a header saying where it came from, then the steps; checked
    by the program file's own rules, so that `program start` never refuses what was written."""
    text = _yaml(program)
    try:
        model.parse(text, program.source)
    except model.ProgramError as error:
        raise BeerXMLError(
            f"{program.source}: its program breaks the program file's rules: "
            f"{model.one_line(error)}"
        ) from None
    return text


def _yaml(program: Program) -> str:
    lines = [
        "# A mash program for hermsd",
        _comment(f"Imported by `hermsd program import` from the BeerXML file {program.source}"),
    ]
    if program.recipe is not None:
        lines.append(_comment(f"  recipe: {program.recipe}"))
    if program.mash is not None:
        lines.append(_comment(f"  mash: {program.mash}"))
    lines += [
        "# Temperatures in °C; each hold counts from when the water is within ±0.5 °C.",
        f"name: {_quoted(program.name)}",
        "steps:",
    ]
    for step in program.steps:
        if step.note is not None:
            lines.append("  " + _comment(step.note))
        lines.append(f"  - name: {_quoted(step.name)}")
        lines.append(f"    setpoint: {step.setpoint:g}")
        lines.append(f"    hold: {_duration(step.hold_min)}")
        if step.ramp is not None:
            lines.append(f"    ramp: {step.ramp:g}")
        if step.confirm is not None:
            lines.append(f"    confirm: {_quoted(step.confirm)}")
        else:
            lines.append("    pump: on")  # a mash step: recirculated (the Strike's stays off)
    return "\n".join(lines) + "\n"


def _comment(text: str) -> str:
    """`text` as one YAML comment line (a file name may hold a line break)."""
    return "# " + "".join(c if c.isprintable() else " " for c in text)


def _quoted(text: str) -> str:
    """A YAML double-quoted scalar (a JSON string is one; white space is already single)."""
    return json.dumps(text, ensure_ascii=False)


def _duration(minutes: float) -> str:
    """Minutes as the program file writes a duration: 60m, 10m30s, 45s, 0s."""
    whole, seconds = divmod(round(minutes * 60.0), 60)
    if not whole:
        return f"{seconds}s"
    return f"{whole}m{seconds}s" if seconds else f"{whole}m"
