"""The brewer's attention, in headless Chromium at phone size: while an alarm stands or the
page has no live reading, a full-width banner at the top, the title and the icon changed, a
vibration and (after the tap that turns the sound on) a beep every two seconds, and the
screen kept on; a warning changes the title only; nothing of it when all is well. Each state
leaves a phone screenshot in the test's tmp dir.

The vibration and the wake lock are the browser's: headless Chromium has neither a motor nor a
screen, so the page is handed recording stand-ins for `navigator.vibrate` and
`navigator.wakeLock`; the sound is Chromium's own Web Audio."""

from __future__ import annotations

from contextlib import AbstractContextManager
from pathlib import Path
from typing import Any

from playwright.sync_api import Browser, Page
from test_web_browser import _log_in, _opened, _status_held, _until, browser, live
from webpage import PHONE, TIMEOUT, Site, site

from hermsd.web.hub import page_status

__all__ = ["browser", "live"]  # the fixtures, shared with test_web_browser.py

STAND_INS = """
window.vibrations = [];
navigator.vibrate = (pattern) => { window.vibrations.push(pattern); return true; };
window.screenLocks = { asked: 0, held: 0 };
Object.defineProperty(navigator, "wakeLock", { value: { request: async (kind) => {
  window.screenLocks.asked += 1;
  window.screenLocks.held += 1;
  const listeners = [];
  return { type: kind, addEventListener: (name, listener) => listeners.push(listener),
           release: async () => { window.screenLocks.held -= 1; listeners.forEach((f) => f()); } };
} } });
"""
RED_ICON = "%23b3261e"  # the alarm icon's colour, as its data: URL carries it


def _phone(browser: Browser, served: Site) -> AbstractContextManager[Page]:
    """The page of `served` at phone size with the stand-ins, at once; no script error in it."""
    return _opened(browser, served, STAND_INS, shown=False)


def _program(
    state: str, index: int, name: str, setpoint: float, **more: object
) -> dict[str, object]:
    """A program's status as the daemon gives it (hermsd/program/driver.py)."""
    fields = {
        "name": "Step mash",
        "state": state,
        "steps": index + 1,
        "next": None,
        "step": {"index": index, "name": name, "setpoint": setpoint},
        "time_left_s": None,
        "message": None,
        "starts_at": None,
        "rest_in_s": None,
    }
    return {**fields, **more}


def _show(page: Page, status: dict[str, Any]) -> None:
    """Hand the page `status` as the hub would push it (its page_status, `latched` with it)."""
    page.evaluate("(status) => onEvent({status, rows: [], offset: 0, age: 0})", page_status(status))


def _attention(page: Page) -> dict[str, Any]:
    found: dict[str, Any] = page.evaluate(
        """({...window.hermsd.attention(), title: document.title,
             icon: document.querySelector("link[rel=icon]").href,
             vibrations: window.vibrations.length, screen: window.screenLocks.held})"""
    )
    return found


def _banner_cannot_be_missed(page: Page, selector: str) -> None:
    """Across the whole phone's width, on its first screen, and it stays there on a scroll."""
    for scrolled in (0, 600):
        page.evaluate(f"window.scrollTo(0, {scrolled})")
        box = page.locator(selector).bounding_box()
        assert box is not None and box["width"] >= PHONE["width"] - 1, box
        assert box["y"] >= 0 and box["y"] + box["height"] <= PHONE["height"] / 2, box
    page.evaluate("window.scrollTo(0, 0)")


def test_with_nothing_wrong_the_page_asks_for_no_attention(
    browser: Browser, live: Site, tmp_path: Path
) -> None:
    with _phone(browser, live) as page, _status_held(page, live, "#alarm-box") as status:
        _show(page, {**status, "alarms": [], "warnings": [], "program": None})
        page.screenshot(path=tmp_path / "none.png")
        assert not page.is_visible("#alarm-box") and not page.is_visible("#lost-box")
        found = _attention(page)
        assert found["title"] == "hermsd" and RED_ICON not in found["icon"]
        assert not found["alerting"] and found["vibrations"] == 0 and found["screen"] == 0
        running = _program("holding", 0, "Rest", 66.0, time_left_s=600.0)
        _show(page, {**status, "alarms": [], "program": running})
        _until(page, "window.screenLocks.held === 1")  # a program runs: the screen stays on
        assert not _attention(page)["alerting"]
        _show(page, {**status, "alarms": [], "program": {**running, "state": "done"}})
        _until(page, "window.screenLocks.held === 0")


def test_a_warning_changes_the_title_and_sounds_nothing(
    browser: Browser, live: Site, tmp_path: Path
) -> None:
    with _phone(browser, live) as page, _status_held(page, live, "#warning-box") as status:
        page.click("#sound")
        _show(page, {**status, "alarms": [], "warnings": ["latched alarms not saved"]})
        page.screenshot(path=tmp_path / "warning.png")
        assert page.is_visible("#warning-box") and not page.is_visible("#alarm-box")
        found = _attention(page)
        assert found["title"] == "check — hermsd" and RED_ICON not in found["icon"]
        assert not found["alerting"] and found["vibrations"] == 0
        assert found["beeps"] <= 1  # the one that says the sound is on


def test_a_latched_alarm_is_a_banner_a_title_a_beep_and_a_vibration_until_reset(
    browser: Browser, live: Site, tmp_path: Path
) -> None:
    with _phone(browser, live) as page, _status_held(page, live, "#alarm-box") as status:
        page.click("#sound")  # the tap a browser wants before it plays anything
        _until(page, "window.hermsd.attention().sound")
        beeps = _attention(page)["beeps"]
        alarm = {
            **status,
            "alarms": ["dry_fire"],
            "state": "alarm",
            "heater_allowed": False,
            "alarm_reasons": {"dry_fire": "rose 1.6 °C/min"},
        }
        _show(page, alarm)
        page.screenshot(path=tmp_path / "latched-alarm.png")
        _banner_cannot_be_missed(page, "#alarm-box")
        assert page.text_content("#alarms") == "dry_fire: rose 1.6 °C/min"
        assert page.is_visible("#reset-alarm")  # a latched alarm waits for it
        found = _attention(page)
        assert found["title"] == "⚠ ALARM — hermsd" and RED_ICON in found["icon"]
        assert found["alerting"] and found["vibrations"] >= 1 and found["screen"] == 1
        _until(page, f"window.hermsd.attention().beeps >= {beeps + 2}")  # and again: it repeats
        _show(page, {**status, "alarms": [], "program": None})  # reset
        found = _attention(page)
        assert not page.is_visible("#alarm-box") and found["title"] == "hermsd"
        assert not found["alerting"]  # its beeping and vibrating stopped
        _until(page, "window.screenLocks.held === 0")


def test_an_over_temperature_standing_alarms_without_a_reset_button(
    browser: Browser, live: Site, tmp_path: Path
) -> None:
    with _phone(browser, live) as page, _status_held(page, live, "#alarm-box") as status:
        hot = {
            **status,
            "alarms": ["over_temperature"],
            "state": "alarm",
            "alarm_reasons": {"over_temperature": "95.2 °C is above the limit 95.0 °C"},
        }
        _show(page, hot)
        page.screenshot(path=tmp_path / "over-temperature.png")
        _banner_cannot_be_missed(page, "#alarm-box")
        assert not page.is_visible("#reset-alarm")  # it clears itself once the water cools
        assert page.text_content("#alarm-note") == (
            "(over_temperature: the heater is off until it is over)"
        )
        found = _attention(page)
        assert found["title"] == "⚠ ALARM — hermsd" and RED_ICON in found["icon"]
        assert found["alerting"] and found["vibrations"] >= 1 and found["screen"] == 1


def test_a_stopped_daemon_alarms_as_the_tun_is_not_watched(
    browser: Browser, tmp_path: Path
) -> None:
    with site(tmp_path) as stopped:
        stopped.stop_answering()
        with _phone(browser, stopped) as page:
            _log_in(page)
            _until(page, "!document.getElementById('lost-box').hidden")
            page.screenshot(path=tmp_path / "stopped-daemon.png")
            _banner_cannot_be_missed(page, "#lost-box")
            assert "the daemon does not answer" in (page.text_content("#lost") or "")
            found = _attention(page)
            assert found["title"] == "⚠ NO DAEMON — hermsd" and RED_ICON in found["icon"]
            assert found["alerting"] and found["vibrations"] >= 1


def test_stepping_down_the_page_says_cooling_and_when_the_rest_starts(
    browser: Browser, live: Site
) -> None:
    with _phone(browser, live) as page, _status_held(page, live, "#program-box") as status:
        beta = _program("heating", 1, "Beta", 64.0, rest_in_s=700.0)
        _show(page, {**status, "pv": 72.0, "program": beta})
        assert page.text_content("#program-state") == "cooling"
        assert page.text_content("#program-left") == "rest starts in about 12 min"  # 11.7
        _show(page, {**status, "pv": 60.0, "program": {**beta, "rest_in_s": 5000.0}})
        assert page.text_content("#program-state") == "heating"
        assert page.text_content("#program-left") == "rest starts in about 1 h 23 min"
        _show(page, {**status, "pv": 60.0, "program": {**beta, "rest_in_s": None}})
        assert page.text_content("#program-left") == "until in band, or told"


def test_a_status_pushed_before_a_commands_reply_does_not_undo_it(
    browser: Browser, live: Site
) -> None:
    with _phone(browser, live) as page, _status_held(page, live, "#program-box") as status:
        t = float(status["t"])
        started = _program("heating", 0, "Rest", 64.0, rest_in_s=1800.0)
        page.evaluate("(status) => render(status, 0)", {**status, "t": t + 10, "program": started})
        assert page.is_visible("#program-box")
        _show(page, {**status, "t": t + 5, "program": None})  # read before the start
        assert page.is_visible("#program-box")
        assert page.evaluate("window.lastStatus.program.rest_in_s") == 1800.0
        _show(page, {**status, "t": t + 20, "program": None})  # the program was stopped since
        assert not page.is_visible("#program-box")


def test_a_program_started_on_the_simulator_says_when_its_rest_starts(
    browser: Browser, tmp_path: Path
) -> None:
    with site(tmp_path) as served, _phone(browser, served) as page:
        _log_in(page)
        page.fill(
            "#program-yaml", "name: Rest\nsteps:\n  - {name: Rest, setpoint: 64, hold: 10m}\n"
        )
        page.click("#program-start")
        _until(
            page,
            "/^rest starts in about (\\d+ h )?\\d+ min$/.test(document.getElementById("
            "'program-left').textContent)",
        )
        estimate = page.evaluate("window.lastStatus.program.rest_in_s")
        pv = page.evaluate("window.lastStatus.pv")
        # The simulated tun heats from the room at full power: within hours, not seconds.
        assert pv < 63.5 and 60.0 < estimate < 3 * 3600.0


def test_a_recipe_uploaded_on_the_phone_shows_its_program_and_starts(
    browser: Browser, tmp_path: Path
) -> None:
    recipe = Path(__file__).parent / "data" / "beerxml" / "two-recipes.xml"
    with site(tmp_path) as served, _phone(browser, served) as page:
        _log_in(page)
        page.set_input_files("#recipe-file", str(recipe))
        page.click("#recipe-import-button")
        page.wait_for_selector("#message.error", timeout=TIMEOUT * 1000)
        said = page.text_content("#message") or ""
        assert said.startswith("two-recipes.xml: holds 2 recipes")  # one line, which ones
        assert page.input_value("#program-yaml") == ""
        page.fill("#recipe-name", "Weizen Step Mash")
        page.press("#recipe-name", "Enter")  # makes the program; starts nothing
        page.wait_for_selector("#message.ok", timeout=TIMEOUT * 1000)
        made = page.input_value("#program-yaml")
        assert "Weizen Step Mash" in made and not served.daemon.program.active
        assert (page.text_content("#message") or "").endswith("read them, then Start program")
        page.click("#program-start")
        _until(page, "!document.getElementById('program-box').hidden")
        assert served.daemon.program.active
        assert "Weizen Step Mash" in (page.text_content("#program-name") or "")
