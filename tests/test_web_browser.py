"""The real page in headless Chromium (Debian's `chromium`, driven by Playwright) against a
simulated daemon behind a real control socket: the chart and temperature follow the loop, a
change with a login is applied at the first period boundary, without one it is refused, and
the page at phone size shows what matters.

Outside CI a machine without /usr/bin/chromium skips these tests (`apt-get install
chromium`); in CI (CI set) it fails them, as `.ci/run` installs it."""

from __future__ import annotations

import os
import struct
import zlib
from collections.abc import Iterator

import pytest
from webpage import CHROMIUM, CHROMIUM_ARGS, PASSWORD, PHONE, TIMEOUT, Site, site

TEMPERATURE_RED = (0xC6, 0x28, 0x28)  # the temperature line's colour in app.js
WAIT_MS = TIMEOUT * 1000


if not CHROMIUM.exists():
    if os.environ.get("CI"):
        pytest.fail(f"{CHROMIUM} is missing: .ci/run installs Debian's chromium", pytrace=False)
    pytest.skip(f"{CHROMIUM} is missing (apt-get install chromium)", allow_module_level=True)

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
    context = browser.new_context(viewport=PHONE)
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    page.goto(live.url)
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
    red = _count_colour(pixels, width, chart, TEMPERATURE_RED)
    assert red > 50, "no temperature line drawn in the chart"


def _count_colour(
    pixels: bytes, width: int, box: dict[str, float], colour: tuple[int, int, int]
) -> int:
    found = 0
    for y in range(int(box["y"]), int(box["y"] + box["height"])):
        for x in range(int(box["x"]), int(box["x"] + box["width"])):
            r, g, b = pixels[3 * (y * width + x) : 3 * (y * width + x) + 3]
            if abs(r - colour[0]) + abs(g - colour[1]) + abs(b - colour[2]) < 40:
                found += 1
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


PROGRAM = {  # the last step of a three-step mash, as INTERFACES.md's status field has it
    "name": "Hochkurz",
    "state": "holding",
    "step": {"index": 2, "name": "Mash out", "setpoint": 76.0},
    "steps": 3,
    "time_left_s": 600.0,
    "next": None,
    "message": None,
    "starts_at": None,
}


def test_a_running_program_is_shown_and_its_buttons_send_the_sockets_commands(
    page: Page, live: Site
) -> None:
    _log_in(page)
    assert not page.is_visible("#program-box")  # this daemon's status has no program
    with live.held() as last:  # no new period may redraw the page meanwhile
        _until(page, f"window.lastStatus.t === {last}")
        status = page.evaluate("window.lastStatus")
        waiting = {**PROGRAM, "state": "waiting", "message": "Mash in", "time_left_s": None}
        page.evaluate(
            "(status) => onEvent({status, rows: [], offset: 0})", {**status, "program": PROGRAM}
        )
        shown = {
            name: page.text_content(f"#program-{name}")
            for name in ("name", "state", "step", "left", "next")
        }
        assert shown == {
            "name": "Hochkurz",
            "state": "holding",
            "step": "3 of 3: Mash out, 76 °C",
            "left": "10 min 0 s",
            "next": "last step",
        }
        assert not page.is_visible("#program-confirm")
        with page.expect_request("**/api/command") as sent:
            page.click("#program-pause")
        assert sent.value.post_data_json == {"cmd": "program", "action": "pause"}

        page.evaluate(
            "(status) => onEvent({status, rows: [], offset: 0})", {**status, "program": waiting}
        )
        assert page.text_content("#program-message") == "Waiting: Mash in"
        with page.expect_request("**/api/command") as sent:
            page.click("#program-confirm")
        assert sent.value.post_data_json == {"cmd": "confirm"}


def test_an_alarm_is_shown_with_its_reset(page: Page, live: Site) -> None:
    _log_in(page)
    assert not page.is_visible("#alarm-box")
    with live.held() as last:
        _until(page, f"window.lastStatus.t === {last}")
        status = page.evaluate("window.lastStatus")
        alarm = {**status, "alarms": ["dry fire"], "state": "alarm", "heater_allowed": False}
        page.evaluate("(status) => onEvent({status, rows: [], offset: 0})", alarm)
        assert page.text_content("#alarms") == "dry fire"
        assert page.text_content("#state") == "alarm"
        with page.expect_response("**/api/command") as answered:
            page.click("#reset-alarm")
            live.wait_for_command()
            live.step()  # applied at the boundary
        assert answered.value.request.post_data_json == {"cmd": "reset-alarm"}
        assert answered.value.status == 200  # the daemon took it (it had nothing latched)
