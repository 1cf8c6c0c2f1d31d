"""The picture of a brew day (`hermsd replay --plot`): what a brewer reads at a glance.

Four panels share one axis of local wall-clock time (the log's record times, in the zone
of the machine that draws):

- events: a label for each setpoint edit, mode change, program step, alarm and water added,
  at the left edge of the line that marks it through every panel; labels are stacked in
  rows so that none overlaps another (`rows`);
- temperature: PV and setpoint;
- error: PV − setpoint against the ±0.5 °C band the tun is held to;
- power: the controller's output and the duty the SSR applied, in colours of their own.

Alarms are shaded across every panel for as long as the period records hold them.

Water poured in is not recorded by anyone: it shows as a sudden PV drop, which replay
detects (`replay.sudden_drops`), so its label says "water added?".
"""

from __future__ import annotations

import bisect
import itertools
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime, timedelta
from pathlib import Path
from typing import TYPE_CHECKING

from hermsd.log.reader import Log, ReplayError, alarms, sudden_drops

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

BAND_C = 0.5  # the band the tun is held to, ± °C
ERROR_SHOWN_C = 3.0  # the error panel's range, ± °C: the band stays readable in a heat-up

COLOURS = {
    "pv": "#1f5fa8",
    "setpoint": "#222222",
    "error": "#1f5fa8",
    "band": "#2ca02c",
    "output": "#e6720f",
    "applied": "#7b52ab",
    "alarm": "#d62728",
    "edit": "#222222",  # setpoint edits: the setpoint line's colour
    "mode": "#8c564b",
    "program": "#2f8f5b",
    "water": "#1796b0",
}

# Program events given a label; a step reached is a triangle on the setpoint line instead.
PROGRAM_LABELS = {
    "started": "program {program}",
    "step_started": "{name} {setpoint}",
    "waiting": "waiting: {message}",
    "confirmed": "confirmed",
    "paused": "paused",
    "resumed": "resumed",
    "skipped": "skipped {name}",
    "finished": "program done",
    "stopped": "program stopped",
}
PROGRAM_ENDS = ("finished", "stopped")

# The daemon's event for a config file edit it applied; the setpoint and mode it names are
# marked from the period records (where a runtime change shows too), the other keys from it.
RELOADED = re.compile(r"config reloaded: (?P<keys>.+) changed")
SHOWN_BY_RECORDS = ("control.setpoint", "control.mode", "control.manual_output")

# Layout, inches (text sizes are points): margins fixed so that the time axis has the same
# pixels whatever the figure's height, which follows from the number of label rows.
WIDTH_IN = 13.0
DPI = 110
LEFT_IN, RIGHT_IN = 0.9, 1.9  # the legends are right of the panels
TITLE_IN, BOTTOM_IN, GAP_IN = 0.55, 0.6, 0.1
ROW_IN = 0.25
PANELS_IN = (3.0, 1.4, 1.6)  # temperature, error, power
LABEL_POINTS = 9
LABEL_GAP_PX = 6.0  # between labels in a row
MAX_ROWS = 10  # of labels; a day with more at one time has the rest marked by lines only


@dataclass(frozen=True, slots=True)
class Marker:
    """An event to label: at `at` s on the replay's clock; `kind` chooses its colour."""

    at: float
    kind: str
    text: str


@dataclass(frozen=True, slots=True)
class Span:
    """An alarm active from `start` to `end` (s on the replay's clock); `open`: still at the
    end of the log."""

    kind: str
    start: float
    end: float
    open: bool


# -- what is drawn -------------------------------------------------------------------------------


def alarm_spans(log: Log) -> list[Span]:
    """Each alarm from its raising (its event, else its first period) to the first period
    without it; raised and cleared between two periods: from its event, no wider."""
    period_s = log.period_s()
    raised = alarms(log)
    spans: list[Span] = []
    active: dict[str, float] = {}
    for record, at in zip(log.periods, log.elapsed, strict=True):
        now = set(record.alarms)
        for kind in sorted(now - active.keys()):
            told = [a["at_s"] for a in raised if a["kind"] == kind and at - period_s <= a["at_s"]]
            active[kind] = min([at, *(t for t in told if t <= at)])
        for kind in sorted(active.keys() - now):
            spans.append(Span(kind, active.pop(kind), at, False))
    spans += [Span(kind, start, log.elapsed[-1], True) for kind, start in sorted(active.items())]
    for alarm in raised:
        if not any(s.kind == alarm["kind"] and s.start <= alarm["at_s"] <= s.end for s in spans):
            spans.append(Span(alarm["kind"], alarm["at_s"], alarm["at_s"], False))
    return sorted(spans, key=lambda s: (s.start, s.kind))


def program_runs(log: Log) -> list[tuple[float, float]]:
    """When a program ran: from its first event to its end (the end of the log if none)."""
    runs: list[tuple[float, float]] = []
    start: float | None = None
    for event in log.program:
        if start is None and event.event not in PROGRAM_ENDS:
            start = event.at
        elif start is not None and event.event in PROGRAM_ENDS:
            runs.append((start, event.at))
            start = None
    if start is not None:
        runs.append((start, math.inf))
    return runs


def markers(log: Log) -> list[Marker]:
    """Every labelled event of the day in time order. Setpoint changes while a program runs
    are its steps (and ramps), labelled as such, not as edits."""
    found: list[Marker] = []
    runs = program_runs(log)
    pairs = itertools.pairwise(zip(log.periods, log.elapsed, strict=True))
    for (before, _), (record, at) in pairs:
        if record.setpoint != before.setpoint and not any(a <= at <= b for a, b in runs):
            found.append(Marker(at, "edit", f"setpoint {_number(record.setpoint)} °C"))
        manual_edit = record.mode == "manual" and record.output != before.output
        if record.mode != before.mode or manual_edit:
            text = f"manual {_number(record.output)} %" if record.mode == "manual" else "auto"
            found.append(Marker(at, "mode", text))
    for logged in log.events:
        match = RELOADED.fullmatch(logged.message)
        keys = [k for k in match["keys"].split(", ") if k not in SHOWN_BY_RECORDS] if match else []
        if keys:
            names = ", ".join(k.removeprefix("control.") for k in keys)
            found.append(Marker(logged.at, "edit", f"{names} changed"))
    for event in log.program:
        template = PROGRAM_LABELS.get(event.event)
        if template is not None:
            setpoint = "" if event.setpoint is None else f"{_number(event.setpoint)} °C"
            fields = {"program": event.program, "name": event.name, "message": event.message}
            text = template.format(**{k: v or "" for k, v in fields.items()}, setpoint=setpoint)
            found.append(Marker(event.at, "program", " ".join(text.split())))
    for drop in sudden_drops(log.elapsed, [p.pv for p in log.periods]):
        fall = _number(round(drop.before - drop.after, 1))
        found.append(Marker(drop.at, "water", f"water added? PV −{fall} °C"))
    for span in alarm_spans(log):
        how_long = "still at the end" if span.open else _duration(span.end - span.start)
        found.append(Marker(span.start, "alarm", f"{span.kind} {how_long}"))
    return sorted(found, key=lambda m: m.at)


def rows(extents: Sequence[tuple[float, float]], gap: float) -> list[int]:
    """The row of each label (0 first), given its (left, right) x extent in pixels: the
    lowest row where it keeps `gap` clear of every label already there. Taken by left edge,
    this uses as few rows as any placement can (interval colouring)."""
    ends: list[float] = []  # the right edge of the last label in each row
    placed = [0] * len(extents)
    for i in sorted(range(len(extents)), key=lambda i: extents[i][0]):
        left, right = extents[i]
        row = next((r for r, end in enumerate(ends) if end + gap <= left), len(ends))
        if row == len(ends):
            ends.append(right)
        else:
            ends[row] = right
        placed[i] = row
    return placed


def title(log: Log) -> str:
    """The vessel, the date and the span of the day, in local time; the program if one ran."""
    vessel = next(
        (
            str(c.config["tun"]["name"])
            for c in reversed(log.configs)
            if isinstance(c.config.get("tun"), dict) and c.config["tun"].get("name")
        ),
        "tun (name not logged)",
    )
    first, last = _local(log.log_time_ns[0]), _local(log.log_time_ns[-1])
    day = f"{first:%A} {first.day} {first:%B %Y}"
    if first.date() == last.date():
        when = f"{day}, {first:%H:%M}–{last:%H:%M}"
    else:
        when = f"{day} {first:%H:%M} – {last:%A} {last.day} {last:%B %Y} {last:%H:%M}"
    names = list(dict.fromkeys(e.program for e in log.program if e.program))
    program = f" · program {', '.join(names)}" if names else ""
    return f"{vessel} · {when}{program}"


def zone(log: Log) -> str:
    """The local zone the times are in, as 'CET, UTC+01:00'."""
    local = datetime.fromtimestamp(log.log_time_ns[0] / 1e9).astimezone()
    offset = local.utcoffset() or timedelta()
    minutes = round(offset.total_seconds() / 60)
    if local.tzname() == "UTC":
        return "UTC"
    sign = "+" if minutes >= 0 else "−"
    return f"{local.tzname()}, UTC{sign}{abs(minutes) // 60:02d}:{abs(minutes) % 60:02d}"


def _day_numbers(whens: Sequence[datetime]) -> list[float]:
    """`whens` as matplotlib's date axis counts (days since its epoch), in one call: one
    per period would be most of the drawing's time."""
    from matplotlib import dates

    return [float(n) for n in dates.date2num(list(whens))]  # type: ignore[no-untyped-call]


def _day_number(when: datetime) -> float:
    return _day_numbers([when])[0]


def _local(log_time_ns: int) -> datetime:
    """Local wall-clock time (naive, as matplotlib's date axis takes it)."""
    return datetime.fromtimestamp(log_time_ns / 1e9)


def _wall(log: Log, at: float) -> datetime:
    """The local time at `at` s on the replay's clock, from the period record before it."""
    i = max(0, bisect.bisect_right(log.elapsed, at) - 1)
    return _local(log.log_time_ns[i] + round((at - log.elapsed[i]) * 1e9))


def _number(value: float) -> str:
    return f"{value:g}"


def _duration(seconds: float) -> str:
    if seconds < 90:
        return f"{seconds:.0f} s"
    minutes = round(seconds / 60)
    return f"{minutes} min" if minutes < 90 else f"{minutes // 60} h {minutes % 60:02d} min"


# -- drawing -------------------------------------------------------------------------------------


def save(log: Log, path: Path) -> None:
    """Draw the day into `path` (PNG, or any format matplotlib writes by the name).

    OSError when it cannot be written (the caller names the file the brewer gave).
    """
    draw(log).savefig(path, dpi=DPI)


def check_format(path: Path) -> None:
    """ReplayError unless matplotlib writes the format `path`'s suffix names (none: a PNG):
    said before the log is read, not after the day is drawn."""
    try:
        from matplotlib.backend_bases import FigureCanvasBase
    except ImportError:
        raise ReplayError(NEEDS_MATPLOTLIB) from None
    formats = FigureCanvasBase.get_supported_filetypes()
    suffix = path.suffix.lower().removeprefix(".")
    if suffix and suffix not in formats:
        raise ReplayError(
            f"--plot {path}: cannot draw a .{suffix} file; the name ends in one of "
            f"{', '.join('.' + name for name in sorted(formats))}"
        )


NEEDS_MATPLOTLIB = "--plot needs matplotlib: uv sync --extra plot (or pip install 'hermsd[plot]')"


def draw(log: Log) -> Figure:
    """The figure of the day; ReplayError when matplotlib is missing."""
    try:  # a figure of its own on the Agg canvas: no GUI, no pyplot state to close
        from matplotlib import dates
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise ReplayError(NEEDS_MATPLOTLIB) from None
    figure = Figure(figsize=(WIDTH_IN, 8.0), dpi=DPI)
    FigureCanvasAgg(figure)
    strip = figure.add_axes((0.0, 0.0, 1.0, 1.0))
    temps, error, power = (figure.add_axes((0.0, 0.0, 1.0, 1.0), sharex=strip) for _ in "abc")
    panels = (temps, error, power)
    _position(figure, strip, panels, label_rows=1)

    x = _with_breaks(log, _day_numbers([_local(ns) for ns in log.log_time_ns]))
    pv = _values(x, [p.pv for p in log.periods])
    setpoint = _values(x, [p.setpoint for p in log.periods])
    temps.plot(x, setpoint, color=COLOURS["setpoint"], lw=1.0, ds="steps-post", label="setpoint")
    temps.plot(x, pv, color=COLOURS["pv"], lw=1.3, label="PV")
    temps.set_ylabel("°C")
    error.axhspan(-BAND_C, BAND_C, color=COLOURS["band"], alpha=0.18, lw=0, label="±0.5 °C band")
    error.axhline(0.0, color=COLOURS["band"], lw=0.6)
    err = [p - s for p, s in zip(pv, setpoint, strict=True)]  # NaN where either is
    error.plot(x, err, color=COLOURS["error"], lw=1.0, label="PV − setpoint")
    error.set_ylim(-ERROR_SHOWN_C, ERROR_SHOWN_C)
    error.set_ylabel(f"error °C\n(±{ERROR_SHOWN_C:g} shown)")
    applied = _values(x, [p.applied for p in log.periods])
    power.fill_between(
        x, applied, step="pre",
        color=COLOURS["applied"], alpha=0.35, lw=0, label="applied (SSR duty)",
    )  # fmt: skip
    output = _values(x, [p.output for p in log.periods])
    power.plot(x, output, color=COLOURS["output"], lw=1.0, ds="steps-post", label="output")
    power.set_ylim(0.0, 105.0)
    power.set_ylabel("%")
    power.set_xlabel(f"local time ({zone(log)})")

    for span in alarm_spans(log):
        start, end = _day_number(_wall(log, span.start)), _day_number(_wall(log, span.end))
        end = max(end, start + (x[-1] - x[0]) * 0.002)  # a short alarm stays visible
        for axes in (strip, *panels):
            axes.axvspan(start, end, color=COLOURS["alarm"], alpha=0.13, lw=0)
    for event in log.program:
        if event.event == "step_reached" and event.setpoint is not None:
            temps.plot(
                _day_number(_wall(log, event.at)), event.setpoint, marker="v", ms=7,
                color=COLOURS["program"], ls="none",
            )  # fmt: skip

    strip.set_xlim(x[0], x[-1])
    locator = dates.AutoDateLocator(minticks=5, maxticks=14)  # type: ignore[no-untyped-call]
    formatter = dates.ConciseDateFormatter(locator, show_offset=False)  # type: ignore[no-untyped-call]
    power.xaxis.set_major_locator(locator)
    power.xaxis.set_major_formatter(formatter)
    for axes in (strip, temps, error):
        axes.tick_params(labelbottom=False)
    for axes in panels:
        axes.grid(True, color="#dddddd", lw=0.6)
        axes.legend(
            loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0,
            fontsize=LABEL_POINTS + 1, frameon=False,
        )  # fmt: skip
    strip.set_yticks([])
    strip.set_ylim(0.0, 1.0)
    strip.set_ylabel("events", rotation=0, ha="right", va="center")
    marked = markers(log)
    at = _day_numbers([_wall(log, m.at) for m in marked])
    _label(figure, strip, panels, list(zip(at, marked, strict=True)))
    figure.suptitle(title(log), x=LEFT_IN / WIDTH_IN, ha="left", fontsize=13)
    return figure


def _label(
    figure: Figure, strip: Axes, panels: Sequence[Axes], placed: list[tuple[float, Marker]]
) -> None:
    """Each marker's line through the panels, and its label in the strip's rows."""
    renderer = figure.canvas.get_renderer()  # type: ignore[attr-defined]
    box_left, box_right = strip.get_window_extent(renderer).intervalx
    pad_px = 0.25 * LABEL_POINTS * figure.dpi / 72.0  # from the box's edge to the text's
    texts, extents = [], []
    for at, marker in placed:
        colour = COLOURS[marker.kind]
        for axes in panels:
            axes.axvline(at, color=colour, lw=0.9, ls=(0, (4, 3)), alpha=0.7)
        strip.axvline(at, color=colour, lw=0.9)
        text = strip.text(
            at, 0.5, marker.text, transform=strip.get_xaxis_transform(), ha="left",
            va="center", fontsize=LABEL_POINTS, color="black" if marker.kind == "edit" else colour,
            bbox={"boxstyle": "round,pad=0.25", "fc": "white", "ec": colour, "lw": 0.8},
            gid="event-label", zorder=5,
        )  # fmt: skip
        width = text.get_window_extent(renderer).width + 2.0 * pad_px  # the box around it
        anchor = strip.transData.transform((at, 0.0))[0]
        # right of its line; where the strip ends first, left of it; inside the strip
        left = anchor + 2.0 if anchor + 2.0 + width <= box_right else anchor - 2.0 - width
        left = min(max(left, box_left), box_right - width)
        texts.append((text, left))
        extents.append((left, left + width))
    placed_rows = rows(extents, LABEL_GAP_PX)
    count = min(max(placed_rows, default=0) + 1, MAX_ROWS)
    _position(figure, strip, panels, label_rows=count)
    inverse = strip.transData.inverted()
    unlabelled = 0
    for (text, left), row in zip(texts, placed_rows, strict=True):
        if row >= MAX_ROWS:
            text.remove()  # its line stays
            unlabelled += 1
            continue
        text.set_x(inverse.transform((left + pad_px, 0.0))[0])
        text.set_y((row + 0.5) / count)
    if unlabelled:
        strip.set_ylabel(f"events\n({unlabelled} lines\nnot labelled)")
    elif not placed:
        strip.set_ylabel("events\n(none)")


def _position(figure: Figure, strip: Axes, panels: Sequence[Axes], label_rows: int) -> None:
    """Lay the axes out from the top, in inches; the figure's height follows."""
    heights = [label_rows * ROW_IN + 0.1, *PANELS_IN]
    total = TITLE_IN + sum(heights) + GAP_IN * len(PANELS_IN) + BOTTOM_IN
    figure.set_size_inches(WIDTH_IN, total)
    top = total - TITLE_IN
    width = (WIDTH_IN - LEFT_IN - RIGHT_IN) / WIDTH_IN
    for axes, height in zip((strip, *panels), heights, strict=True):
        bottom = top - height
        axes.set_position((LEFT_IN / WIDTH_IN, bottom / total, width, height / total))
        top = bottom - GAP_IN


def _with_breaks(log: Log, x: list[float]) -> list[float]:
    """`x` with NaN inserted where periods are missing, so that lines break there."""
    limit = 2.5 * log.period_s() / 86400.0  # in days, as matplotlib counts dates
    broken: list[float] = []
    for i, value in enumerate(x):
        if i and value - x[i - 1] > limit:
            broken.append(math.nan)
        broken.append(value)
    return broken


def _values(x: list[float], values: Sequence[float | None]) -> list[float]:
    """`values` lined up with `x` from `_with_breaks`: NaN at each break and for None."""
    source = iter(values)
    lined_up = [None if math.isnan(value) else next(source) for value in x]
    return [math.nan if value is None else value for value in lined_up]
