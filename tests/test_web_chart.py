"""The chart in headless Chromium at phone size: the setpoint's ±0.5 °C band drawn about its
line, each axis with its unit, the output a thin line on its own 0–100 % scale (no fill that
greys the plot at full power), and its "100" inside the 390 px canvas."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from playwright.sync_api import Browser, Page
from test_web_browser import _opened, _until, browser, live
from webpage import Site

__all__ = ["browser", "live"]  # the fixtures, shared with test_web_browser.py

# Records each text drawn on a canvas with its left and right edge in canvas pixels.
TEXT_SPY = """
window.drawnTexts = [];
const fillText = CanvasRenderingContext2D.prototype.fillText;
CanvasRenderingContext2D.prototype.fillText = function (text, x, y, ...rest) {
  const width = this.measureText(text).width, align = this.textAlign;
  const left = align === "right" || align === "end" ? x - width
    : align === "center" ? x - width / 2 : x;
  const m = this.getTransform();
  window.drawnTexts.push({ text: String(text), canvas: this.canvas.width, rotated: m.b !== 0,
                           left: m.a * left + m.c * y + m.e,
                           right: m.a * (left + width) + m.c * y + m.e });
  return fillText.call(this, text, x, y, ...rest);
};
"""
# The colour (RGBA: transparent where nothing is drawn) at each of `fractions` across the
# plot, at °C `celsius` (or % `percent`).
PIXELS = """([celsius, percent, fractions]) => {
  const u = window.hermsd.chart();
  const y = celsius === null ? u.valToPos(percent, "%", true) : u.valToPos(celsius, "°C", true);
  return fractions.map((f) => Array.from(u.ctx.getImageData(
    Math.round(u.bbox.left + f * u.bbox.width), Math.round(y), 1, 1).data));
}"""
ACROSS = [0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8]
BAND = 0.5  # °C: hermsd.metrics.BAND, the band a program's step counts as reached


@pytest.fixture
def page(browser: Browser, live: Site) -> Iterator[Page]:
    with _opened(browser, live, TEXT_SPY) as opened:
        _until(opened, "window.hermsd.points() > 10")
        yield opened


def _bluish(pixel: list[int]) -> bool:
    """The band's faint blue (the setpoint's #1f5fbf at 0.15 opacity)."""
    return pixel[3] > 0 and pixel[2] - pixel[0] >= 100


def _bare(pixel: list[int]) -> bool:
    """Nothing drawn there but, at most, a grid line (uPlot's rgba(0, 0, 0, 0.07): alpha 18),
    which crosses a sampled pixel wherever a time tick happens to fall."""
    return pixel[3] == 0 or (pixel[:3] == [0, 0, 0] and pixel[3] <= 18)


def test_the_setpoint_band_is_drawn_half_a_degree_either_side(
    page: Page, live: Site, tmp_path: Path
) -> None:
    with live.held() as last:
        _until(page, f"window.lastStatus.t === {last}")
        setpoint = page.evaluate("window.lastStatus.setpoint")
        assert page.evaluate(f"window.lastStatus.pv < {setpoint - 4}")  # far below: no red here
        # Zoomed to the setpoint ±3 °C, the band is a sixth of the plot's height.
        page.evaluate(
            f"window.hermsd.chart().setScale('°C', {{min: {setpoint - 3}, max: {setpoint + 3}}})"
        )
        page.screenshot(path=tmp_path / "band.png")
        for inside in (setpoint + 0.7 * BAND, setpoint - 0.7 * BAND):
            colours = page.evaluate(PIXELS, [inside, None, ACROSS])
            assert sum(map(_bluish, colours)) >= len(ACROSS) - 1, (inside, colours)
        for outside in (setpoint + 1.6 * BAND, setpoint - 1.6 * BAND):
            colours = page.evaluate(PIXELS, [outside, None, ACROSS])
            assert not any(map(_bluish, colours)), (outside, colours)
        # The output is a line, no fill: below it nothing is drawn at full power.
        assert page.evaluate("window.lastStatus.output") > 50
        colours = page.evaluate(PIXELS, [None, 20, ACROSS])
        assert sum(map(_bare, colours)) >= len(ACROSS) - 1, colours


def test_each_axis_says_its_unit_and_100_is_not_cut_off(page: Page) -> None:
    drawn = page.evaluate("window.drawnTexts")
    texts = {text["text"] for text in drawn}
    assert {"°C", "output %", "local time"} <= texts, texts
    hundreds = [text for text in drawn if text["text"] == "100" and not text["rotated"]]
    assert hundreds, "no 100 % tick"
    for hundred in hundreds:
        assert hundred["left"] >= 0 and hundred["right"] <= hundred["canvas"], hundred
