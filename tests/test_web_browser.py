"""The real page in headless Chromium (Debian's `chromium`, driven by Playwright) against a
simulated daemon behind a real control socket: the chart and temperature follow the loop, a
change with a login is applied at the first period boundary, without one it is refused, the
page at phone size shows what matters, and a mash program started from the page (a file or
pasted YAML, checked before anything is sent) is shown and steered by its buttons.

Outside CI a machine without /usr/bin/chromium skips these tests, saying why
(`apt-get install chromium`); in CI (CI set) it fails them, as `.ci/run` installs it."""

from __future__ import annotations

import struct
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from programs import require_program
from test_reload import BASE, HERMS, doughed_in
from webpage import CHROMIUM, CHROMIUM_ARGS, PASSWORD, PHONE, TIMEOUT, Site, site

from hermsd.api.protocol import ProgramAction
from hermsd.config import read

TEMPERATURE_RED = (0xC6, 0x28, 0x28)  # the temperature line's colour in app.js
MASH_GREEN = (0x2E, 0x7D, 0x32)  # the mash line's
HLT_SETPOINT_ORANGE = (
    0xEF,
    0x6C,
    0x00,
)  # the dashed line of the HLT's setpoint the outer loop chose
WAIT_MS = TIMEOUT * 1000


require_program(CHROMIUM, "chromium", what="the browser tests")

from playwright.sync_api import Browser, Page, sync_playwright  # noqa: E402


@pytest.fixture(scope="module")
def browser() -> Iterator[Browser]:
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        yield browser
        browser.close()


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Site]:
    with site(tmp_path_factory.mktemp("web")) as served:
        yield served


@pytest.fixture
def page(browser: Browser, live: Site) -> Iterator[Page]:
    with _opened(browser, live) as opened:
        yield opened


@contextmanager
def _opened(browser: Browser, served: Site, script: str = "", shown: bool = True) -> Iterator[Page]:
    """The page of `served` at phone size, `script` run before its own, once it shows a
    status (`shown`; else at once); no script error in it."""
    context = browser.new_context(viewport=PHONE)
    if script:
        context.add_init_script(script)
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    page.goto(served.url)
    if shown:
        _until(page, "document.body.dataset.t !== undefined")
    yield page
    context.close()
    assert errors == [], f"the page's script failed: {errors}"


def _until(page: Page, expression: str) -> None:
    """Until `expression` is true in the page (polled: the page's CSP, rightly, forbids the
    eval that Playwright's wait_for_function needs)."""
    for _ in range(int(WAIT_MS / 20)):
        if page.evaluate(expression):
            return
        page.wait_for_timeout(20)
    raise AssertionError(f"not within {TIMEOUT:g} s: {expression}")


def test_the_chart_and_the_temperature_follow_the_loop(page: Page, live: Site) -> None:
    points, pv = page.evaluate("window.hermsd.points()"), page.text_content("#pv")
    assert pv is not None and pv.endswith("°C")
    # The simulated tun heats at full power from 20 °C: the shown PV and the chart move.
    _until(
        page,
        f"window.hermsd.points() >= {points + 5} && "
        f"document.getElementById('pv').textContent !== {pv!r}",
    )
    shown = float((page.text_content("#pv") or "").split()[0])
    newest = live.events.periods[-1]
    assert newest.pv is not None and 20.0 < shown <= newest.pv + 0.01
    drawn = page.evaluate("window.hermsd.chart().data[1].filter((v) => v !== null).length")
    assert drawn >= points + 5


def _log_in(page: Page) -> None:
    page.fill("#password", PASSWORD)
    page.click("#login-button")
    page.wait_for_selector("#changes", state="visible", timeout=WAIT_MS)
    _until(page, "session.logged_in")


def test_a_setpoint_change_with_login_is_applied_at_the_next_period(page: Page, live: Site) -> None:
    _log_in(page)
    with live.held():  # the command must wait for one boundary only
        mark = len(live.events.periods)
        page.fill("#setpoint-input", "72.5")
        page.click("#setpoint-button")
        live.wait_for_command()
        live.step()  # one period
        page.wait_for_selector("#message.ok", timeout=WAIT_MS)
        stepped = live.events.periods[mark - 1 :]
    assert len(stepped) == 2 and stepped[0].setpoint != 72.5 == stepped[1].setpoint
    assert page.text_content("#message") == "setpoint 72.5 °C: done"
    assert page.text_content("#setpoint") == "72.5 °C"


def test_a_bad_setpoint_is_refused_with_the_daemons_reason(page: Page, live: Site) -> None:
    _log_in(page)
    setpoint = live.daemon.setpoint
    page.fill("#setpoint-input", "120")  # above safety.max_temp
    page.click("#setpoint-button")
    page.wait_for_selector("#message.error", timeout=WAIT_MS)
    assert "refused, nothing changed" in (page.text_content("#message") or "")
    assert live.daemon.setpoint == setpoint


def test_the_same_change_without_login_is_refused(page: Page, live: Site) -> None:
    assert page.is_visible("#login-form") and not page.is_visible("#changes")
    setpoint = live.daemon.setpoint
    reply = page.evaluate(
        """fetch('/api/command', {method: 'POST', headers: {'Content-Type':
        'application/json'}, body: JSON.stringify({cmd: 'set', setpoint: 61})})
        .then(async (r) => [r.status, (await r.json()).error])"""
    )
    assert reply == [401, "log in to change anything"]
    at = live.daemon.clock.monotonic()
    _until(page, f"Number(document.body.dataset.t) > {at + 5}")
    assert live.daemon.setpoint == setpoint != 61


def test_at_phone_size_the_page_shows_the_essentials(page: Page, live: Site) -> None:
    _until(page, "window.hermsd.points() > 10")
    assert page.evaluate("document.documentElement.scrollWidth") <= PHONE["width"]
    assert page.locator("#chart canvas").count() == 1  # one chart, however the page loaded
    for selector in ("#pv", "#setpoint", "#output", "#mode", "#chart canvas"):
        box = page.locator(selector).bounding_box()
        assert box is not None and box["y"] + box["height"] <= PHONE["height"], selector
    pv = page.text_content("#pv") or ""
    assert pv.endswith(" °C") and 20.0 < float(pv.split()[0]) < 100.0
    shot = page.screenshot()
    width, height, pixels = _decode_png(shot)
    assert (width, height) == (PHONE["width"], PHONE["height"])
    colours = {pixels[i : i + 3] for i in range(0, len(pixels), 3)}
    assert len(colours) > 100, "the screenshot is (nearly) blank"
    chart = page.locator("#chart canvas").bounding_box()
    assert chart is not None
    red = _rows_of_colour(pixels, width, chart, TEMPERATURE_RED)
    assert len(red) > 50, "no temperature line drawn in the chart"


def _rows_of_colour(
    pixels: bytes, width: int, box: dict[str, float], colour: tuple[int, int, int]
) -> list[int]:
    """The row (y) of each pixel in `box` near `colour`."""
    found = []
    for y in range(int(box["y"]), int(box["y"] + box["height"])):
        for x in range(int(box["x"]), int(box["x"] + box["width"])):
            r, g, b = pixels[3 * (y * width + x) : 3 * (y * width + x) + 3]
            if abs(r - colour[0]) + abs(g - colour[1]) + abs(b - colour[2]) < 40:
                found.append(y)
    return found


def _decode_png(data: bytes) -> tuple[int, int, bytes]:
    """Width, height and RGB bytes of an 8-bit RGB or RGBA PNG (what Chromium writes)."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    position, idat = 8, b""
    width = height = kind = 0
    while position < len(data):
        (length,) = struct.unpack(">I", data[position : position + 4])
        tag = data[position + 4 : position + 8]
        body = data[position + 8 : position + 8 + length]
        if tag == b"IHDR":
            width, height, depth, kind, _c, _f, interlace = struct.unpack(">IIBBBBB", body)
            assert depth == 8 and kind in (2, 6) and interlace == 0
        elif tag == b"IDAT":
            idat += body
        position += 12 + length
    channels = 3 if kind == 2 else 4
    raw = zlib.decompress(idat)
    stride = width * channels
    rows: list[bytearray] = []
    previous = bytearray(stride)
    for y in range(height):
        start = y * (stride + 1)
        kind_of_filter = raw[start]
        row = bytearray(raw[start + 1 : start + 1 + stride])
        for i in range(stride):
            left = row[i - channels] if i >= channels else 0
            up = previous[i]
            corner = previous[i - channels] if i >= channels else 0
            if kind_of_filter == 1:
                row[i] = (row[i] + left) & 0xFF
            elif kind_of_filter == 2:
                row[i] = (row[i] + up) & 0xFF
            elif kind_of_filter == 3:
                row[i] = (row[i] + (left + up) // 2) & 0xFF
            elif kind_of_filter == 4:
                p = left + up - corner
                pa, pb, pc = abs(p - left), abs(p - up), abs(p - corner)
                predictor = left if pa <= pb and pa <= pc else up if pb <= pc else corner
                row[i] = (row[i] + predictor) & 0xFF
        rows.append(row)
        previous = row
    rgb = bytearray()
    for row in rows:
        if channels == 3:
            rgb += row
        else:
            for x in range(width):
                rgb += row[4 * x : 4 * x + 3]
    return width, height, bytes(rgb)


@contextmanager
def _status_held(page: Page, live: Site, box: str) -> Iterator[dict[str, object]]:
    """Logged in, `box` not shown, the loop held: the status the page shows, to hand it one
    of another day's as the hub would."""
    _log_in(page)
    assert not page.is_visible(box)
    with live.held() as last:
        _until(page, f"window.lastStatus.t === {last}")
        yield page.evaluate("window.lastStatus")


def test_an_alarm_is_shown_with_its_reset(page: Page, live: Site) -> None:
    with _status_held(page, live, "#alarm-box") as status:
        alarm = {
            **status,
            "alarms": ["dry_fire"],
            "latched": ["dry_fire"],  # waits for a reset (the hub's page_status says)
            "alarm_reasons": {"dry_fire": "rose 1.6 °C/min"},
            "state": "alarm",
            "heater_allowed": False,
        }
        page.evaluate("(status) => onEvent({status, rows: [], offset: 0, age: 0})", alarm)
        assert page.text_content("#alarms") == "dry_fire: rose 1.6 °C/min"  # and why
        assert page.text_content("#state") == "alarm"
        with page.expect_response("**/api/command") as answered:
            page.click("#reset-alarm")
            live.wait_for_command()
            live.step()  # applied at the boundary
        # Only what the page showed: an alarm raised since stays latched, to be read first.
        sent = answered.value.request.post_data_json
        assert sent == {"cmd": "reset-alarm", "kinds": ["dry_fire"]}
        assert answered.value.status == 200  # the daemon took it (it had nothing latched)


def test_a_warning_is_shown_in_its_words_and_goes_when_it_is_over(page: Page, live: Site) -> None:
    with _status_held(page, live, "#warning-box") as status:
        words = ["element 2 gives no heat? (docs/two-elements.md)", "latched alarms not saved"]
        warned = {**status, "warnings": words}
        page.evaluate("(status) => onEvent({status, rows: [], offset: 0, age: 0})", warned)
        assert page.is_visible("#warning-box") and not page.is_visible("#alarm-box")
        assert page.text_content("#warnings") == "; ".join(words)
        page.evaluate("(status) => onEvent({status, rows: [], offset: 0, age: 0})", status)
        assert not page.is_visible("#warning-box")


def _program_yaml(setpoint: float) -> str:
    """Three steps the simulated tun, held near `setpoint`, reaches at once: a wait for the
    brewer, a 10-minute rest and a rest until told."""
    return (
        "name: Web mash\n"
        "steps:\n"
        f"  - {{name: Strike, setpoint: {setpoint}, hold: 0s, confirm: Mash in}}\n"
        f"  - {{name: Rest, setpoint: {setpoint}, hold: 10m}}\n"
        f"  - {{name: Mash out, setpoint: {setpoint}, hold: until told}}\n"
    )


def _click_at_boundary(page: Page, live: Site, selector: str) -> str | None:
    """Click, see the command wait for the period boundary (nothing changed yet), run that
    period; the step the period ran."""
    mark = len(live.events.periods)
    page.click(selector)
    live.wait_for_command()
    assert len(live.events.periods) == mark  # held: no period ran meanwhile
    assert page.is_disabled(selector)  # no second click while the first is on its way
    sent = live.server._commands[-1].command
    if selector in ("#program-confirm", "#program-next-button"):  # for the step shown
        assert sent == ProgramAction(sent.action, page.evaluate("lastStatus.program.step.index"))
    live.step()
    page.wait_for_selector("#message.ok", timeout=WAIT_MS)
    _until(page, f"window.lastStatus.t === {live.events.periods[-1].t}")
    return live.events.periods[-1].step


def _step(page: Page, live: Site, periods: int = 1) -> None:
    """Run `periods` periods and wait until the page shows the last."""
    live.step(periods)
    _until(page, f"window.lastStatus.t === {live.events.periods[-1].t}")


def _shown(page: Page) -> dict[str, str | None]:
    names = ("state", "step", "left", "next")
    return {name: page.text_content(f"#program-{name}") for name in names}


def test_a_program_started_from_the_page_runs_and_its_buttons_steer_it(
    browser: Browser, tmp_path: Path
) -> None:
    with site(tmp_path) as live:
        context = browser.new_context(viewport=PHONE)
        page = context.new_page()
        page.on("dialog", lambda dialog: dialog.accept())  # Stop asks first
        page.goto(live.url)
        _log_in(page)
        with live.held() as last:
            _until(page, f"window.lastStatus && window.lastStatus.t === {last}")
            pv = live.events.periods[-1].pv
            assert pv is not None
            # In band at once (BAND 0.5 °C), and the tun, slowly warming, stays in it.
            setpoint = round(pv + 0.45, 1)
            # Pasted with a mistake: where it is, on the page; nothing reaches the daemon.
            mistaken = _program_yaml(setpoint).replace("hold: 10m", "hold: ten")
            page.fill("#program-yaml", mistaken)
            page.click("#program-start")
            page.wait_for_selector("#program-problems", state="visible", timeout=WAIT_MS)
            problems = page.text_content("#program-problems") or ""
            column = mistaken.splitlines()[3].index("ten") + 1  # the Rest step, line 4
            assert problems.startswith(f"pasted.yaml:4:{column}: steps[1].hold: 'ten' is not")
            assert "60m" in problems  # what would be right
            assert page.text_content("#message") == "the program has errors: nothing was sent"
            assert not live.server._commands and not live.daemon.program.active
            # The program file picked on the phone.
            page.set_input_files(
                "#program-file",
                {
                    "name": "web-mash.yaml",
                    "mimeType": "text/yaml",
                    "buffer": _program_yaml(setpoint).encode(),
                },
            )
            assert page.is_visible("#program-form")
            assert _click_at_boundary(page, live, "#program-start") == "Strike"
            assert not page.is_visible("#program-form")  # one program at a time
            assert not page.is_visible("#program-problems")
            assert page.text_content("#message") == "program start: done"
            assert page.is_visible("#program-box")
            assert page.text_content("#program-name") == "Web mash"

            _step(page, live, 2)  # reached, its hold of 0 s done: it waits for the brewer
            assert page.evaluate("window.lastStatus.program.state") == "waiting"
            assert page.text_content("#program-message") == "Waiting: Mash in"
            assert page.is_visible("#program-confirm")
            assert _shown(page)["next"] == "Rest"

            # Without a login the same commands are refused and change nothing.
            stranger = browser.new_context().new_page()
            stranger.goto(live.url)
            actions = ("next", "pause", "resume", "stop")
            for path, body in [
                ("/api/command", {"cmd": "confirm"}),
                *(("/api/command", {"cmd": "program", "action": a}) for a in actions),
                ("/api/program", {"yaml": _program_yaml(setpoint)}),
            ]:
                reply = stranger.evaluate(
                    """([path, body]) => fetch(path, {method: 'POST', headers:
                    {'Content-Type': 'application/json'}, body: JSON.stringify(body)})
                    .then(async (r) => [r.status, (await r.json()).error])""",
                    [path, body],
                )
                assert reply == [401, "log in to change anything"], body
            assert not live.server._commands  # nothing reached the daemon
            stranger.context.close()

            assert _click_at_boundary(page, live, "#program-confirm") == "Rest"
            assert page.is_enabled("#program-next-button")  # answered: usable again
            # Another phone that still shows Strike waiting: its confirm is for Strike.
            page.evaluate(
                """(token) => { window.second = fetch('/api/command', {method: 'POST',
                headers: {'Content-Type': 'application/json', 'X-CSRF-Token': token},
                body: JSON.stringify({cmd: 'confirm', step: 0})})
                .then(async (r) => [r.status, (await r.json()).error]); }""",
                page.evaluate("session.csrf"),
            )
            live.wait_for_command()
            _step(page, live)
            assert page.evaluate("window.second") == [
                422,
                "refused, nothing changed: confirm was for step 1, which is not the current "
                "one (step 2/3 'Rest' is holding; look at the status and send it again for "
                "that step if meant)",
            ]
            assert _shown(page)["step"] == f"2 of 3: Rest, {setpoint:g} °C"
            left = page.evaluate("window.lastStatus.program.time_left_s")
            assert left is not None  # reached in the period that began it
            assert not page.is_visible("#program-confirm")
            _step(page, live, 2)  # two periods of 5 s off the hold
            assert page.evaluate("window.lastStatus.program.time_left_s") == left - 10.0
            minutes, seconds = divmod(round(left - 10.0), 60)
            assert _shown(page) == {
                "state": "holding",
                "step": f"2 of 3: Rest, {setpoint:g} °C",
                "left": f"{minutes} min {seconds} s",
                "next": "Mash out",
            }

            assert _click_at_boundary(page, live, "#program-next-button") == "Mash out"
            assert _shown(page)["next"] == "last step"

            _click_at_boundary(page, live, "#program-pause")
            assert _shown(page)["state"] == "paused" and page.is_visible("#program-resume")
            assert not page.is_visible("#program-pause")
            _click_at_boundary(page, live, "#program-resume")
            assert _shown(page)["state"] != "paused" and page.is_visible("#program-pause")

            assert _click_at_boundary(page, live, "#program-stop") is None
            assert not page.is_visible("#program-box")
            assert page.is_visible("#program-form")  # another may start
        context.close()


BAD_RED = "rgb(179, 38, 30)"  # app.css's --bad, #b3261e


def _commands(page: Page) -> dict[str, bool]:
    """Each command button on the page (shown or not): whether it is enabled."""
    found: dict[str, bool] = page.evaluate(
        """Object.fromEntries([...document.querySelectorAll('.needs-login')]
        .map((button) => [button.id, !button.disabled]))"""
    )
    assert len(found) >= 9, found  # setpoint, mode, program start, reset, confirm, next, ...
    return found


def test_a_page_opened_after_the_daemon_stopped_says_no_daemon_in_red_and_sends_nothing(
    browser: Browser, tmp_path: Path
) -> None:
    with site(tmp_path) as stopped:
        stopped.stop_answering()
        context = browser.new_context(viewport=PHONE)
        page = context.new_page()
        page.goto(stopped.url)
        _log_in(page)  # the login needs no daemon
        _until(page, "document.getElementById('conn').textContent === 'no daemon'")
        assert (
            page.evaluate("getComputedStyle(document.getElementById('conn')).backgroundColor")
            == BAD_RED
        )
        assert page.is_visible("#conn")
        assert not any(_commands(page).values())
        # No reading is shown, so none without its age: not the last status the hub kept.
        assert page.text_content("#pv") == "—" and page.text_content("#state") == "—"
        assert page.text_content("#age") == "—"
        assert page.evaluate("window.lastStatus") is None
        context.close()


def test_a_reading_older_than_two_periods_is_shown_red_with_its_age(page: Page, live: Site) -> None:
    with _status_held(page, live, "#alarm-box") as status:
        assert page.text_content("#conn") == "live" and all(_commands(page).values())
        page.evaluate(
            "(status) => onEvent({status, rows: [], offset: 0, age: 25, stale_after: 10})",
            status,
        )
        assert page.text_content("#conn") == "reading 25 s old"
        assert (
            page.evaluate("getComputedStyle(document.getElementById('conn')).backgroundColor")
            == BAD_RED
        )
        assert page.text_content("#age") == "25 s old"
        assert not any(_commands(page).values())
        page.evaluate(
            "(status) => onEvent({status, rows: [], offset: 0, age: 1, stale_after: 10})",
            status,
        )
        assert page.text_content("#conn") == "live" and all(_commands(page).values())
        assert page.text_content("#age") == "1 s old"


class _FullDisk:
    """A flight recorder whose disk is full: what the daemon reads of it."""

    failing = "writing hermsd-1.mcap: [Errno 28] No space left on device"
    lost = 0
    dropped = 0

    def write(self, topic: str, log_time_ns: int, message: dict[str, object]) -> None:
        pass


def test_a_log_that_cannot_be_written_is_a_warning_on_the_page(page: Page, live: Site) -> None:
    with live.held():
        recorder, live.daemon.recorder = live.daemon.recorder, _FullDisk()
    try:
        _until(page, "!document.getElementById('warning-box').hidden")
        assert page.text_content("#warnings") == (
            f"log failing (control goes on, this brew is not recorded): {_FullDisk.failing}"
        )
    finally:
        with live.held():
            live.daemon.recorder = recorder
    _until(page, "document.getElementById('warning-box').hidden")  # writing again


# -- a HERMS: the mash's line and the pump --------------------------------------------------


@pytest.fixture(scope="module")
def herms(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Site]:
    """A HERMS whose mash was doughed in at about 70 °C while the HLT heats from 20 °C."""
    with site(tmp_path_factory.mktemp("herms"), text=HERMS, tun=doughed_in()) as served:
        yield served


@pytest.fixture
def herms_page(browser: Browser, herms: Site) -> Iterator[Page]:
    with _opened(browser, herms) as opened:
        yield opened


def test_without_a_mash_side_the_page_shows_nothing_of_it(page: Page) -> None:
    _until(page, "window.hermsd.points() > 3")
    _log_in(page)
    boxes = "['mash-box', 'hlt-aim-box', 'pump-box', 'pump-row', 'current-box']"
    hidden = f"{boxes}.map((id) => document.getElementById(id).hidden)"
    assert page.evaluate(hidden) == [True, True, True, True, True]
    assert page.text_content("#setpoint-label") == "Setpoint"
    labels = page.evaluate("window.hermsd.chart().series.map((s) => s.label)")
    assert labels == ["Time", "Temperature °C", "Setpoint °C", "Output %"]


def test_at_phone_size_the_mash_is_the_charts_second_line_above_the_hlts(
    herms_page: Page, herms: Site
) -> None:
    page = herms_page
    _until(page, "window.hermsd.points() > 10 && window.hermsd.chart().series.length === 6")
    assert page.evaluate("document.documentElement.scrollWidth") <= PHONE["width"]
    legend = page.locator(".u-legend").text_content() or ""
    assert "Mash °C" in legend and "Temperature °C" in legend
    for selector in ("#pv", "#mash", "#pump", "#chart canvas"):
        box = page.locator(selector).bounding_box()
        assert box is not None and box["y"] + box["height"] <= PHONE["height"], selector
    with herms.held() as last:  # a status pushed between the two reads would move the mash
        _until(page, f"window.lastStatus.t === {last}")
        status = page.evaluate("window.lastStatus")
        assert page.text_content("#mash") == f"{status['mash']['celsius']:.1f} °C"
    assert 60.0 < status["mash"]["celsius"] <= 70.2 and page.text_content("#pump") == "off"
    shot = page.screenshot()
    width, _height, pixels = _decode_png(shot)
    chart = page.locator("#chart canvas").bounding_box()
    assert chart is not None
    mash = _rows_of_colour(pixels, width, chart, MASH_GREEN)
    hlt = _rows_of_colour(pixels, width, chart, TEMPERATURE_RED)
    assert len(mash) > 50, "no mash line drawn in the chart"
    assert len(hlt) > 50, "no temperature line drawn in the chart"
    # the mash near 70 °C, the HLT below 40 °C: the mash's line higher on the screen
    assert sum(mash) / len(mash) < sum(hlt) / len(hlt) - 20


def test_the_pump_button_starts_and_stops_the_pump_at_the_next_period(
    herms_page: Page, herms: Site
) -> None:
    page = herms_page
    _log_in(page)
    assert page.is_visible("#pump-button") and page.text_content("#pump-button") == "Start pump"
    for shown, button, done in (("on", "Stop pump", True), ("off", "Start pump", False)):
        with herms.held():
            mark = len(herms.events.periods)
            page.click("#pump-button")
            herms.wait_for_command()
            assert page.is_disabled("#pump-button")  # no second click on its way
            herms.step()
            page.wait_for_selector("#message.ok", timeout=WAIT_MS)
            stepped = herms.events.periods[mark - 1 :]
        assert page.text_content("#message") == f"pump {shown}: done"
        assert [record.pump for record in stepped] == [not done, done]
        assert page.text_content("#pump") == shown
        assert page.text_content("#pump-button") == button


def test_a_prepared_pump_start_is_shown_starting_and_its_button_cancels_it(
    herms_page: Page, herms: Site
) -> None:
    """While hermsd sends the coil's load ahead of a pump start it commanded (the status's
    `mash.pump_start_in`), the pump is shown starting, not off, and the button stops it."""
    with _status_held(herms_page, herms, "#alarm-box") as status:
        mash = status["mash"]
        assert isinstance(mash, dict)
        starting = {**status, "pump": False, "mash": {**mash, "pump_start_in": 42.4}}
        herms_page.evaluate("(status) => onEvent({status, rows: [], offset: 0, age: 0})", starting)
        assert herms_page.text_content("#pump") == "starting in 42 s"
        assert herms_page.text_content("#pump-button") == "Stop pump"
        with herms_page.expect_request("**/api/command") as sent:
            herms_page.click("#pump-button")
            herms.wait_for_command()
        assert sent.value.post_data_json == {"cmd": "set", "pump": False}


def test_the_pump_timers_next_turn_is_shown_beside_the_pump(herms_page: Page, herms: Site) -> None:
    """A program's pump timer (`mash.pump_turn_in`, s) is said as the status line says it."""
    with _status_held(herms_page, herms, "#alarm-box") as status:
        mash = status["mash"]
        assert isinstance(mash, dict)
        for pump, turn_in, shown in (
            (True, 240.0, "on, off in 4 min (timer)"),
            (False, 75.4, "off, on in 75 s (timer)"),
            (True, None, "on"),
        ):
            timed = {**status, "pump": pump, "mash": {**mash, "pump_turn_in": turn_in}}
            herms_page.evaluate("(status) => onEvent({status, rows: [], offset: 0, age: 0})", timed)
            assert herms_page.text_content("#pump") == shown


def test_a_faulty_mash_sensor_is_said_where_its_reading_was(herms_page: Page, herms: Site) -> None:
    with _status_held(herms_page, herms, "#alarm-box") as status:
        why = "no answer from the LM92 at 0x49"
        faulty = {**status, "mash": {"celsius": None, "fault": why}}
        herms_page.evaluate("(status) => onEvent({status, rows: [], offset: 0, age: 0})", faulty)
        assert herms_page.text_content("#mash") == "sensor fault"
        assert herms_page.get_attribute("#mash", "title") == why
        assert herms_page.evaluate("window.hermsd.chart().series.length") == 6  # a gap, kept


def test_the_hlts_setpoint_the_outer_loop_chose_is_shown_beside_the_mashs_and_drawn_dashed(
    herms_page: Page, herms: Site
) -> None:
    page = herms_page
    _until(page, "window.hermsd.points() > 10 && window.hermsd.chart().series.length === 6")
    with herms.held() as last:
        _until(page, f"window.lastStatus.t === {last}")
        status = page.evaluate("window.lastStatus")
        aim, phase = status["mash"]["hlt_setpoint"], status["mash"]["phase"]
        records = {round(r.t, 3): r.hlt_setpoint for r in herms.events.periods}
        drawn = page.evaluate(
            "(() => { const d = window.hermsd.chart().data; "
            "return d[0].map((x, i) => [d[0][i], d[5][i]]); })()"
        )
        offset = page.evaluate("window.hermsd.chart().data[0].at(-1)") - status["t"]
    # the mash's setpoint is the brewer's (66 °C); the HLT's is the outer loop's, at most
    # 10 °C (herms.max_hlt_above_mash) above it, with its phase
    assert page.text_content("#setpoint-label") == "Mash setpoint"
    assert page.text_content("#setpoint") == "66.0 °C"
    assert isinstance(aim, float) and phase in ("climb", "coast", "hold", "ready", "held")
    assert aim <= 66.0 + 10.0
    assert page.text_content("#hlt-aim") == f"→ {aim:.1f} °C ({phase})"
    hlt_aim = page.locator("#hlt-aim").bounding_box()
    assert hlt_aim is not None and hlt_aim["y"] + hlt_aim["height"] <= PHONE["height"]
    legend = page.locator(".u-legend").text_content() or ""
    assert "HLT setpoint °C" in legend
    # each row of the chart's dashed line is the HLT setpoint the loop recorded that period
    for x, value in drawn:
        t = round(x - offset, 3)
        if t in records:
            expected = records[t]
            assert value == (None if expected is None else round(expected, 3)), t
    assert sum(1 for _x, value in drawn if value is not None) > 10
    width, _height, pixels = _decode_png(page.screenshot())
    chart = page.locator("#chart canvas").bounding_box()
    assert chart is not None
    assert len(_rows_of_colour(pixels, width, chart, HLT_SETPOINT_ORANGE)) > 20, "no dashed line"


def test_an_element_current_input_shows_its_latest_amps_against_the_ssr(
    browser: Browser, tmp_path_factory: pytest.TempPathFactory
) -> None:
    """`current.kind: sim`: the element's watts over the simulated mains' 230 V while the SSR
    was on at the latest sample (the heat-up from 20 °C: full power)."""
    amps = read.parse(BASE).tun.element_watts / 230.0
    text = BASE + "\ncurrent:\n  kind: sim\n"
    with (
        site(tmp_path_factory.mktemp("current"), text=text) as served,
        _opened(browser, served) as opened,
    ):
        _until(opened, "!document.getElementById('current-box').hidden")
        _until(opened, "document.getElementById('current').textContent.endsWith('(SSR on)')")
        assert opened.text_content("#current") == f"{amps:.1f} A (SSR on)"
