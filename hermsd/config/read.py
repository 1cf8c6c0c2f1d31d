"""Reading a config file: the YAML document walked against the schema, every problem with its
line and column; and a config written back (dump, differences)."""

from __future__ import annotations

import dataclasses
import difflib
import os
import re
from dataclasses import dataclass, field
from typing import Any

import yaml

from hermsd.config.rules import _violations
from hermsd.config.schema import (
    _NULLS,
    _RESOLVER,
    _SCHEMA,
    _SECTION_CLASSES,
    RESTART_KEYS,
    Config,
    ConfigError,
    Problem,
    _convert,
    _describe,
    _explicit_tag,
    _Invalid,
    _is_null,
    _plain_value,
    _reads_as_number,
)
from hermsd.files import NotRegularFile, read_regular


class _Reader:
    """Walks a composed YAML document against the schema, collecting every problem."""

    def __init__(self, filename: str) -> None:
        self.filename = filename
        self.problems: list[Problem] = []
        self.marks: dict[str, yaml.Mark] = {}  # key path -> where its value starts
        self.failed: set[str] = set()  # key paths and sections whose value was refused
        self.written: dict[str, tuple[int, int]] = {}  # each section and key -> (line, column)

    def report(self, mark: yaml.Mark | None, key_path: str, message: str) -> None:
        line, column = (mark.line + 1, mark.column + 1) if mark is not None else (1, 1)
        self.problems.append(Problem(self.filename, line, column, key_path, message))

    def items(
        self, node: yaml.MappingNode, prefix: str, known: list[str]
    ) -> list[tuple[str, yaml.Node]]:
        """The (key, value) pairs of a mapping whose keys are known and not repeated."""
        seen: dict[str, int] = {}
        pairs = []
        for key_node, value_node in node.value:
            if not isinstance(key_node, yaml.ScalarNode):
                self.report(
                    key_node.start_mark,
                    prefix,
                    f"a key must be a plain name, got {_describe(key_node)} "
                    f"(one of: {', '.join(known)})",
                )
                continue
            key = key_node.value
            path = f"{prefix}.{key}" if prefix else key
            if key in seen:
                self.report(
                    key_node.start_mark,
                    path,
                    f"duplicate key (first given on line {seen[key]}; keep one of them)",
                )
                continue
            seen[key] = key_node.start_mark.line + 1
            if key not in known:
                self.report(
                    key_node.start_mark, path, f"unknown key ({self._suggest(key, prefix, known)})"
                )
                continue
            self.written[path] = (key_node.start_mark.line + 1, key_node.start_mark.column + 1)
            pairs.append((key, value_node))
        return pairs

    @staticmethod
    def _suggest(key: str, prefix: str, known: list[str]) -> str:
        homes = [
            section for section, table in _SCHEMA.items() if key in table and section != prefix
        ]
        if homes:
            return f"it belongs in the {homes[0]!r} section"
        close = difflib.get_close_matches(key, known, n=1)
        if close:
            return f"did you mean {close[0]!r}?"
        return f"the keys here are: {', '.join(known)}"

    def document(self, root: yaml.Node | None) -> dict[str, dict[str, object]]:
        """The values the document sets, section by section (refused values left out)."""
        values: dict[str, dict[str, object]] = {section: {} for section in _SCHEMA}
        if root is None:
            return values
        sections = list(_SCHEMA)
        if not isinstance(root, yaml.MappingNode) or _explicit_tag(root) is not None:
            self.report(
                root.start_mark,
                "",
                f"the file must be a mapping of sections, got {_describe(root)} "
                f"(sections such as 'control:' at the start of a line: {', '.join(sections)})",
            )
            return values
        for section, node in self.items(root, "", sections):
            values[section] = self.section(section, node)
        return values

    def section(self, section: str, node: yaml.Node) -> dict[str, object]:
        table = _SCHEMA[section]
        if isinstance(node, yaml.ScalarNode) and node.style is None and node.value in _NULLS:
            return {}  # a section whose keys are all commented out
        if not isinstance(node, yaml.MappingNode) or _explicit_tag(node) is not None:
            self.failed.add(section)
            self.report(
                node.start_mark,
                section,
                f"expected a section of keys, got {_describe(node)} (indented 'key: value' "
                f"lines below '{section}:', keys: {', '.join(table)})",
            )
            return {}
        values = {}
        for name, value_node in self.items(node, section, list(table)):
            info = table[name]
            self.marks[info.path] = value_node.start_mark
            try:
                values[name] = _convert(info, value_node)
            except _Invalid as problem:
                self.failed.add(info.path)
                self.report(problem.mark or value_node.start_mark, info.path, str(problem))
        return values

    def cross_check(self, config: Config) -> None:
        """Report the rules between keys that are broken, unless a key they read was refused."""
        for violation in _violations(config):
            keys = violation.keys
            if any(key in self.failed or key.split(".")[0] in self.failed for key in keys):
                continue
            shown = next((key for key in keys if key in self.marks), keys[0])
            self.report(self.marks.get(shown), shown, violation.said(shown))


def _syntax_problem(filename: str, text: str, error: yaml.YAMLError) -> Problem:
    """A parser error as one Problem at the parser's position."""
    if isinstance(error, yaml.reader.ReaderError):
        before = text[: error.position]
        line = before.count("\n") + 1
        column = error.position - (before.rfind("\n") + 1) + 1
        code = ord(error.character) if isinstance(error.character, str) else error.character
        return Problem(
            filename,
            line,
            column,
            "",
            f"the control character #x{code:x} is not allowed in YAML (delete it)",
        )
    assert isinstance(error, yaml.MarkedYAMLError)
    mark = error.problem_mark or error.context_mark
    line, column = (mark.line + 1, mark.column + 1) if mark is not None else (1, 1)
    what = error.problem or "invalid YAML"
    if error.context and error.context_mark is not None and error.context_mark is not mark:
        what = f"{error.context} on line {error.context_mark.line + 1}, {what}"
    hint = (
        "indent with spaces, not tabs"
        if "'\\t'" in what
        else "check the indentation, the ':' after each key and the quotes, here and on the "
        "line above"
    )
    return Problem(filename, line, column, "", f"invalid YAML: {what} ({hint})")


def _compose(text: str) -> yaml.Node | None:
    loader = yaml.SafeLoader(text)
    try:
        return loader.get_single_node()
    finally:
        loader.dispose()


def _root(text: str, filename: str) -> yaml.Node | None:
    """The YAML document's root node; ConfigError for text that is not YAML."""
    try:
        return _compose(text)
    except yaml.YAMLError as error:
        raise ConfigError([_syntax_problem(filename, text, error)]) from None
    except RecursionError:
        raise ConfigError(
            [
                Problem(
                    filename,
                    1,
                    1,
                    "",
                    "the YAML is nested too deeply (this file needs only sections of "
                    "'key: value' lines)",
                )
            ]
        ) from None


@dataclass(frozen=True, slots=True)
class Document:
    """A valid file: its Config, and what it writes down, which a reload must keep."""

    filename: str
    config: Config
    written: dict[str, tuple[int, int]]  # each section and `section.key` -> (line, column)
    cut_line: int  # the last line when it holds a value but no line break, else 0


def parse(text: str, filename: str = "<string>") -> Config:
    """The Config a YAML text describes; ConfigError lists everything wrong with it."""
    return parse_document(text, filename).config


def parse_document(text: str, filename: str = "<string>") -> Document:
    """`parse`, keeping what the text writes down (for `reload_problems`)."""
    reader = _Reader(filename)
    values = reader.document(_root(text, filename))
    config = Config(**{name: _SECTION_CLASSES[name](**values[name]) for name in _SCHEMA})
    reader.cross_check(config)
    if reader.problems:
        raise ConfigError(sorted(reader.problems, key=lambda p: (p.line, p.column)))
    return Document(filename, config, reader.written, _unfinished_last_line(text))


def load(path: str | os.PathLike[str]) -> Config:
    """The Config in a file; ConfigError (never OSError) when it cannot be read or used."""
    return load_document(path).config


def load_document(path: str | os.PathLike[str]) -> Document:
    """`load`, keeping what the file writes down (for `reload_problems`)."""
    filename = os.fspath(path)
    return parse_document(_read_text(filename), filename)


_LINE_BREAKS = ("\n", "\r", "\x85", "\u2028", "\u2029")  # YAML's, and Unicode's


def _unfinished_last_line(text: str) -> int:
    """The last line's number when it holds a value but ends without a line break, else 0.

    Editors end a file with a line break; a save cut short by a full disk or a crash stops
    anywhere, and a number cut short (`kc: 12` of `kc: 120`) may still be a valid number.
    """
    lines = text.splitlines(keepends=True)
    if not lines or lines[-1].endswith(_LINE_BREAKS):
        return 0
    content = lines[-1].strip()
    return len(lines) if content and not content.startswith("#") else 0


def reload_problems(running: Document, edited: Document) -> list[Problem]:
    """Why `edited`, valid on its own, must not replace the running file's config.

    An emptied file is valid YAML, and so is most of a file cut short: taken as they are,
    every key they lost would fall back to its default (auto mode, full power, the default
    temperature limit) in the middle of a brew. So a reload must name every section and
    key the running file named, and its last line must be finished.
    """
    where = edited.filename
    if running.written and not edited.written:
        return [
            Problem(
                where,
                0,
                0,
                "",
                "names no section: an emptied file, or a save cut short (a reload never "
                "falls back to the built-in defaults; put the file back, or restart hermsd "
                "to run on the defaults)",
            )
        ]
    problems = []
    lost = [key for key in running.written if key not in edited.written]
    gone = [key for key in lost if "." not in key or key.split(".")[0] not in lost]
    if gone:
        names = ", ".join(gone)
        problems.append(
            Problem(
                where,
                0,
                0,
                "",
                f"{names} {'is' if len(gone) == 1 else 'are'} no longer in the file, as in a "
                "save cut short (a reload keeps every key of the running file: to return one "
                "to its default, write the default value; a restart takes the file as it is)",
            )
        )
    if edited.cut_line:
        problems.append(
            Problem(
                where,
                edited.cut_line,
                1,
                "",
                "the last line has no line break at its end, as a save cut short leaves it "
                "(end the file with a newline)",
            )
        )
    return problems


@dataclass(frozen=True, slots=True)
class FoundOutput:
    """One output section as far as a damaged file lets it be read, key by key."""

    section: str  # "output", "contactor", "element2" or "pump"
    values: dict[str, object]  # the keys written with a usable value
    refused: dict[str, Problem]  # the keys written with a value that cannot be used
    doubts: list[Problem]  # what may name this device otherwise: unknown keys, unread lines


@dataclass(frozen=True, slots=True)
class FoundOutputs:
    """What `hermsd safe-off` finds in a config file, however damaged."""

    output: FoundOutput
    contactor: FoundOutput
    notes: list[Problem]  # damage outside the output sections, read around
    doubts: list[Problem]  # damage that may hide an output section: nothing is sure then
    element2: FoundOutput = field(default_factory=lambda: FoundOutput("element2", {}, {}, []))
    pump: FoundOutput = field(default_factory=lambda: FoundOutput("pump", {}, {}, []))


_OUTPUT_SECTIONS = ("output", "contactor", "element2", "pump")


def load_outputs(path: str | os.PathLike[str]) -> FoundOutputs:
    """The output sections of a file (`_OUTPUT_SECTIONS`), whatever is wrong with it.

    `hermsd safe-off` must find the heater's switches after any bad edit, so this reads
    in steps, each more tolerant than the last: the whole document; if it is not YAML,
    each output section alone, then each of its lines alone; a file that cannot be read
    at all leaves the built-in defaults. Bytes that are not UTF-8 and control characters
    are read as U+FFFD. Every problem on the way is kept, so the caller can tell a file
    read around its damage from one where an output may have been missed.
    """
    filename = os.fspath(path)
    notes: list[Problem] = []
    doubts: list[Problem] = []
    try:
        data = read_bytes(filename)
    except ConfigError as error:
        return _found_outputs(_Reader(filename), {}, notes, error.problems)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as error:
        notes.append(_not_utf8(filename, data, error))
        text = data.decode("utf-8", "replace")
    printable = yaml.reader.Reader.NON_PRINTABLE.sub("\ufffd", text)
    if printable != text:
        try:
            yaml.reader.Reader(text)
        except yaml.reader.ReaderError as error:
            notes.append(_syntax_problem(filename, text, error))
    reader = _Reader(filename)
    try:
        root = _compose(printable)
    except (yaml.YAMLError, RecursionError) as error:
        if isinstance(error, yaml.YAMLError):
            notes.append(_syntax_problem(filename, printable, error))
        return _found_outputs(reader, _scan_lines(reader, printable), notes, doubts)
    if root is not None and not isinstance(root, yaml.MappingNode):
        return _found_outputs(reader, _scan_lines(reader, printable), notes, doubts)
    nodes = dict(reader.items(root, "", list(_SCHEMA))) if root is not None else {}
    if not nodes:
        doubts.append(Problem(filename, 0, 0, "", "names no section (an emptied file?)"))
    ours = {section: nodes[section] for section in _OUTPUT_SECTIONS if section in nodes}
    return _found_outputs(reader, ours, notes, doubts)


def _found_outputs(
    reader: _Reader,
    nodes: dict[str, yaml.Node],
    notes: list[Problem],
    doubts: list[Problem],
) -> FoundOutputs:
    """The sections' usable values and problems, once their nodes are found."""
    values = {section: reader.section(section, node) for section, node in nodes.items()}
    found = []
    for section in _OUTPUT_SECTIONS:
        refused = {}
        section_doubts = []
        for problem in reader.problems:
            if problem.key_path.split(".")[0] != section:
                continue
            if problem.key_path in reader.failed and problem.key_path != section:
                refused[problem.key_path.split(".")[1]] = problem
            else:
                section_doubts.append(problem)
        found.append(FoundOutput(section, values.get(section, {}), refused, section_doubts))
    doubts = doubts + [p for p in reader.problems if p.key_path.split(".")[0] not in _SCHEMA]
    return FoundOutputs(found[0], found[1], notes, doubts, found[2], found[3])


_HEADER = re.compile(r"[ \t]*(?P<name>[A-Za-z_][A-Za-z0-9_]*)[ \t]*:(?:[ \t]|$)")


def _scan_lines(reader: _Reader, text: str) -> dict[str, yaml.Node]:
    """The output sections of a text that is not YAML as a whole, found line by line.

    A section runs from its `name:` line (at any indentation) to the next line that is
    indented no deeper. Each is read as YAML on its own; failing that, line by line,
    and a line that cannot be read is a doubt about its section. A top-level line that
    is not a known section may hide an output section: a doubt about the whole file.
    """
    lines = text.splitlines()
    blocks: dict[str, list[int]] = {}
    current: tuple[str, int] | None = None  # the output section being read, its indentation
    for number, line in enumerate(lines):
        content = line.strip()
        if not content or content.startswith("#"):
            continue
        indent = len(line) - len(line.lstrip(" \t"))
        header = _HEADER.match(line)
        name = header["name"] if header else ""
        if name in _OUTPUT_SECTIONS:
            if name in blocks:
                reader.report(_mark(number), name, "the section is given twice (keep one)")
                current = None
            else:
                blocks[name] = [number]
                current = (name, indent)
        elif current is not None and indent > current[1]:
            blocks[current[0]].append(number)
        else:
            current = None
            if indent == 0 and name not in _SCHEMA and content not in ("---", "..."):
                reader.report(
                    _mark(number),
                    "",
                    "cannot tell which section this line is, so it may hold an output "
                    f"(the sections: {', '.join(_SCHEMA)})",
                )
    return {
        name: _section_node(reader, name, lines, numbers[0], numbers[-1])
        for name, numbers in blocks.items()
    }


def _mark(line_index: int) -> yaml.Mark:
    return yaml.Mark("", 0, line_index, 0, "", 0)


def _section_node(
    reader: _Reader, section: str, lines: list[str], first: int, last: int
) -> yaml.Node:
    """Lines `first` to `last` (a section) as a mapping node: as YAML, else line by line."""
    block = _mapping_pairs("\n" * first + "\n".join(lines[first : last + 1]), section)
    if block is not None:
        return block[0][1]
    readable: list[tuple[yaml.Node, yaml.Node]] = []
    header = _mapping_pairs("\n" * first + lines[first], section)
    if header is not None and isinstance(header[0][1], yaml.MappingNode):
        readable.extend(header[0][1].value)
    elif header is None or not _is_null(header[0][1]):
        reader.report(_mark(first), section, "this line cannot be read")
    for number in range(first + 1, last + 1):
        content = lines[number].strip()
        if not content or content.startswith("#"):
            continue
        indent = " " * (len(lines[number]) - len(lines[number].lstrip()))  # tabs too
        pairs = _mapping_pairs("\n" * number + indent + content, None)
        if pairs is None:
            reader.report(_mark(number), section, "this line cannot be read")
        else:
            readable.extend(pairs)
    return yaml.MappingNode(_RESOLVER.DEFAULT_MAPPING_TAG, readable)


def _mapping_pairs(text: str, key: str | None) -> list[tuple[yaml.Node, yaml.Node]] | None:
    """The pairs of a text that is one YAML mapping (of just `key`, if given), else None."""
    try:
        root = _compose(text)
    except (yaml.YAMLError, RecursionError):
        return None
    if not isinstance(root, yaml.MappingNode):
        return None
    pairs: list[tuple[yaml.Node, yaml.Node]] = root.value
    if key is not None:
        if len(pairs) != 1 or not isinstance(pairs[0][0], yaml.ScalarNode):
            return None
        if pairs[0][0].value != key:
            return None
    return pairs


def every_valid_value(key_path: str) -> list[object]:
    """Every value of a key that has few (choices, or a short range of whole numbers).

    The default comes first.
    """
    section, name = key_path.split(".")
    info = _SCHEMA[section][name]
    spec = info.spec
    if spec.choices:
        values = list(spec.choices)
    else:
        assert spec.low is not None
        assert spec.high is not None
        values = list(range(int(spec.low), int(spec.high) + 1))
    return [info.default, *(value for value in values if value != info.default)]


def key_range(key_path: str) -> tuple[float, float]:
    """The lowest and highest value a bounded numeric key accepts, as the file's check does."""
    section, name = key_path.split(".")
    spec = _SCHEMA[section][name].spec
    assert spec.low is not None
    assert spec.high is not None
    return spec.low, spec.high


def _read_text(filename: str) -> str:
    """The file's text; ConfigError when it cannot be read or is not UTF-8."""
    data = read_bytes(filename)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as error:
        raise ConfigError([_not_utf8(filename, data, error)]) from None


def _not_utf8(filename: str, data: bytes, error: UnicodeDecodeError) -> Problem:
    line_start = data.rfind(b"\n", 0, error.start) + 1
    line = data.count(b"\n", 0, error.start) + 1
    column = len(data[line_start : error.start].decode("utf-8", "replace")) + 1
    return Problem(
        filename,
        line,
        column,
        "",
        f"byte 0x{data[error.start]:02x} is not UTF-8 text (save the file as "
        "UTF-8; an editor set to Latin-1 writes '°' this way)",
    )


MAX_FILE_BYTES = 1 << 16
"""The largest config file read: over five times the shipped one (every key, commented).

Reading and parsing happen beside the control loop, in its process: the cap bounds how
long a reload can take CPU (and Python's one interpreter lock) from the loop.
"""


SHIPPED_FILE_MAX_BYTES = MAX_FILE_BYTES // 4
"""The shipped, fully commented file stays under a quarter of the cap: room for every key's
notes to grow, and a file past the cap is then far from any config (its message says so)."""


def read_bytes(filename: str) -> bytes:
    """A regular file's bytes, at most MAX_FILE_BYTES of them; ConfigError otherwise (see
    `files.read_regular`: a FIFO or a serial device is never opened)."""
    try:
        return read_regular(filename, MAX_FILE_BYTES)
    except OSError as error:
        raise ConfigError([Problem(filename, 0, 0, "", _unreadable(error))]) from None
    except NotRegularFile as error:
        if error.kind is not None:
            message = f"{error} (name the YAML file itself)"
            raise ConfigError([Problem(filename, 0, 0, "", message)]) from None
        raise ConfigError([_too_long(filename, error.size)]) from None


def check_size(text: str, filename: str) -> None:
    """ConfigError when `text`, written to a file, would be longer than `read_bytes` reads:
    for text made in memory (an import) that must pass the check its file will meet."""
    size = len(text.encode("utf-8"))
    if size > MAX_FILE_BYTES:
        raise ConfigError([_too_long(filename, size)])


def _too_long(filename: str, size: int) -> Problem:
    return Problem(
        filename,
        0,
        0,
        "",
        f"is {size} bytes long, more than the {MAX_FILE_BYTES // 1024} KiB a config file may "
        f"be (the shipped one is under {SHIPPED_FILE_MAX_BYTES // 1024} KiB: is this the right "
        "file?)",
    )


def _unreadable(error: OSError) -> str:
    if isinstance(error, FileNotFoundError):
        return "no such file (check the path, or copy config/hermsd.yaml there)"
    if isinstance(error, PermissionError):
        return "permission denied (make the file readable by the user hermsd runs as)"
    return f"cannot be read: {error.strerror or error} (check the file and its path)"


def to_dict(config: Config) -> dict[str, Any]:
    """The effective configuration as plain JSON-able data, for the log (lists as lists)."""
    return {
        section: {key: list(v) if isinstance(v, tuple) else v for key, v in values.items()}
        for section, values in dataclasses.asdict(config).items()
    }


class _Dumper(yaml.SafeDumper):
    """Quotes text that this module's plain-scalar grammar would read as something else."""


def _represent_text(dumper: yaml.SafeDumper, text: str) -> yaml.ScalarNode:
    plain_is_text = not _reads_as_number(text) and isinstance(_plain_value(text), str)
    style = None if plain_is_text else "'"
    return dumper.represent_scalar("tag:yaml.org,2002:str", text, style=style)


_Dumper.add_representer(str, _represent_text)


def dump_yaml(config: Config) -> str:
    """The effective configuration as YAML that `parse` reads back to the same Config."""
    return _yaml_text(to_dict(config))


def _yaml_text(data: Any) -> str:
    return yaml.dump(
        data, Dumper=_Dumper, sort_keys=False, default_flow_style=False, allow_unicode=True
    )


def value_at(config: Config, path: str) -> Any:
    """The value of `section.key` in `config`."""
    section, name = path.split(".")
    return getattr(getattr(config, section), name)


def differences(old: Config, new: Config) -> list[str]:
    """Every `section.key` whose value differs between two configs, in file order."""
    return [
        f"{section}.{name}"
        for section, fields in _SCHEMA.items()
        for name in fields
        if value_at(old, f"{section}.{name}") != value_at(new, f"{section}.{name}")
    ]


def from_dict(data: Any, source: str = "<logged config>") -> Config:
    """The Config whose `to_dict` a log holds, checked like a file (ConfigError if it is not).

    A log from another version may hold keys this one does not know, or values it refuses:
    they are reported, not guessed at, since replay must run the controller that ran.
    """
    return parse(_yaml_text(data), source)


def restart_keys_changed(old: Config, new: Config) -> list[str]:
    """The keys in RESTART_KEYS whose values differ: a reload cannot apply them."""
    return [path for path in RESTART_KEYS if value_at(old, path) != value_at(new, path)]


def keep_restart_keys(running: Config, edited: Config) -> Config:
    """`edited` with the running values of every key a reload cannot apply."""
    sections: dict[str, dict[str, Any]] = {}
    for path in restart_keys_changed(running, edited):
        section, name = path.split(".")
        sections.setdefault(section, {})[name] = value_at(running, path)
    return dataclasses.replace(
        edited,
        **{
            section: dataclasses.replace(getattr(edited, section), **values)
            for section, values in sections.items()
        },
    )


def on_simulated_tun(config: Config) -> Config:
    """`config` as a simulated run runs it: the SSR, and the second element and the pump when
    they are fitted, are the simulated tun's whatever hardware the file names (a brewer tries
    the service's own file), so that what the run logs and prints names them truly."""
    element2, pump = config.element2, config.pump
    if element2.backend != "none":
        element2 = dataclasses.replace(element2, backend="sim")
    if pump.backend != "none":
        pump = dataclasses.replace(pump, backend="sim")
    output = dataclasses.replace(config.output, backend="sim")
    return dataclasses.replace(config, output=output, element2=element2, pump=pump)
