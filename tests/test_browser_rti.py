"""The radio tomography layer in headless Chromium: before any radio record the page asks routinely and gets
empty answers (no 404, no console error) and shows nothing; once records arrive, the image, its colour bar, the
peak markers with their value, the targets and the RTI panel appear on the 2D map."""

from __future__ import annotations

import base64
import io
import math

import numpy as np
from harness import operator_page
from PIL import Image
from test_rti_api import TOKEN, station  # noqa: F401 - the module's station, a fixture
from test_rti_live import TARGET, sweep_rows


def pixel(page, x: float, y: float) -> tuple[int, int, int]:
    """The 2D map's colour at scene point (x, y)."""
    sx, sy = page.evaluate(f"window.map2d.toScreen({x}, {y})")
    ratio = page.evaluate("window.devicePixelRatio || 1")
    url = page.eval_on_selector("#map2d", "c => c.toDataURL('image/png')")
    image = np.asarray(Image.open(io.BytesIO(base64.b64decode(url.split(",", 1)[1]))).convert("RGB"))
    return tuple(int(c) for c in image[int(sy * ratio), int(sx * ratio)])


def test_the_layer_colour_bar_and_peaks_appear_when_records_arrive(browser, station):  # noqa: F811
    from playwright.sync_api import expect

    failed: list[str] = []
    with operator_page(browser, station.base, TOKEN) as page:
        page.on("response", lambda r: failed.append(f"{r.status} {r.url}") if r.status >= 400 else None)
        page.on("console", lambda m: failed.append(m.text) if m.type == "error" else None)
        page.evaluate("window.map2d.view.cx = 3.2; window.map2d.view.cy = 3.2; window.map2d.view.scale = 40")
        page.wait_for_timeout(1500)  # six status frames: the page asks /api/rti and hears there is no frame
        assert page.locator("#map2d").get_attribute("data-rti") in (None, "")
        expect(page.locator("#rti")).to_be_hidden()
        empty = pixel(page, *TARGET)

        station.station.rti.targets = [list(TARGET)]
        station.station.live.radio.append(sweep_rows(0.0, 30.0))
        expect(page.locator("#map2d")).to_have_attribute("data-rti", "29", timeout=120_000)
        frame = station.http.get("/api/rti").json()["frame"]
        peaks = frame["peaks"]
        assert math.dist((peaks[0]["x"], peaks[0]["y"]), TARGET) < 0.5
        expect(page.locator("#map2d")).to_have_attribute("data-rti-peaks", str(len(peaks)))
        expect(page.locator("#map2d")).to_have_attribute("data-rti-bar", f"{frame['max']:.3f}")
        expect(page.locator("#rti")).to_be_visible()
        expect(page.locator("#rti-peaks li").first).to_have_text(
            f"x {peaks[0]['x']:.2f} m, y {peaks[0]['y']:.2f} m ({peaks[0]['value']:.3f})")
        expect(page.locator("#rti-coverage")).to_have_text(f"{frame['coverage'] * 100:.0f} %")
        page.evaluate("window.dispatchEvent(new Event('resize'))")  # draw again, then read the canvas
        assert pixel(page, peaks[0]["x"], peaks[0]["y"]) != empty  # the peak's cross over the image
        corner = pixel(page, 6.3, 0.1)  # inside the image, away from the peaks: a viridis colour, not the ground
        assert corner != empty
        page.screenshot(path=str(station.station.record_dir / "rti-map2d.png"))
    assert not failed, failed
