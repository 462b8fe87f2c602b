"""Live radio tomography at the station: frames per second and the latency from a link record's arrival to
the image on the page.

1. The solve: ``groundstation.rti_live.frame_at`` on the synthetic square (vehicle.tomography.synthetic) with 60 s
   of records, for a few network sizes; the frames a second one core makes, and the 3D view's cost of showing a
   frame (``rti_view.draw``: once per frame, never per 3D frame).
2. End to end: a station (uvicorn on loopback) with the page open in headless Chromium; the records of the
   16-radio square arrive in real time, a batch every 0.25 s; for each window the time from the arrival of the
   batch that closed it to the page showing its frame (the 2D map's ``data-rti``), and the station's own part
   (``latency_s``: arrival to frame made).
Run: python bench/rti_live.py   (BLAS on one thread, as the station would run it beside its other work)
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy loads
os.environ.setdefault("OMP_NUM_THREADS", "1")

import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
from common import ROOT, code_state, table  # noqa: E402

sys.path.insert(0, str(ROOT / "tests"))

from groundstation import rti_view  # noqa: E402
from groundstation.rti_live import frame_at  # noqa: E402
from vehicle.protocol.radiostream import LinkRecord  # noqa: E402
from vehicle.tomography import synthetic  # noqa: E402
from vehicle.tomography.links import records_of  # noqa: E402

TARGET = (2.0, 4.0)
BATCH = 0.25  # s between two arrivals in the end-to-end run
WINDOWS = 20  # windows timed end to end


def rows(radios: int, channels: int, seconds: float, period: float = 0.5) -> list[LinkRecord]:
    net = synthetic.Network(synthetic.square(radios, 6.4), channels=channels, seed=3)
    recs = net.sweeps(np.arange(0, seconds, period), people=lambda t: [TARGET] if t >= seconds * 0.7 else [])
    return [LinkRecord(float(recs.t[i]), 2, 1, *recs.tx[i], *recs.rx[i], float(recs.rssi[i]), int(recs.channel[i]))
            for i in range(len(recs))]


def solve_speed() -> list[list[object]]:
    import viser

    server = viser.ViserServer(port=0, verbose=False)
    out = []
    try:
        for radios, channels in ((8, 1), (16, 1), (16, 4), (28, 4)):
            records = records_of(rows(radios, channels, 60.0))
            times, draws = [], []
            for end in (58.0, 59.0, 60.0):
                started = time.perf_counter()
                frame = frame_at(records, end)
                times.append(time.perf_counter() - started)
                started = time.perf_counter()
                rti_view.draw(server.scene, frame)
                draws.append(time.perf_counter() - started)
            best = frame.peaks[0]
            error = float(np.hypot(best["x"] - TARGET[0], best["y"] - TARGET[1]))
            out.append([radios, channels, len(records), frame.paths, f"{np.median(times) * 1000:.0f}",
                        f"{1 / np.median(times):.1f}", f"{np.median(draws) * 1000:.1f}", f"{error:.2f}"])
    finally:
        server.stop()
    return out


def end_to_end() -> dict:
    from harness import RunningStation, launch_chromium
    from playwright.sync_api import expect, sync_playwright

    from vehicle.protocol.radiostream import LinkLog

    records = rows(16, 1, 60.0 + WINDOWS + 2, period=0.25)
    lags, station_lags = [], []
    with tempfile.TemporaryDirectory() as folder, RunningStation(None, folder, "bench-token") as running, \
            sync_playwright() as playwright:
        live = running.station.live
        if getattr(live, "radio", None) is None:
            live.radio = LinkLog()
        live.radio.append([r for r in records if r.t < 60.0])
        browser = launch_chromium(playwright)
        page = browser.new_page(viewport={"width": 1400, "height": 900})
        page.route("**/viz/**", lambda route: route.fulfill(body="<!doctype html>", content_type="text/html"))
        page.goto(f"{running.base}/#token=bench-token")
        shown = expect(page.locator("#map2d"))  # (the page's policy allows no eval: wait_for_function cannot)
        shown.to_have_attribute("data-rti", "59", timeout=120_000)
        t = 60.0
        while t < 60.0 + WINDOWS:
            arrived = time.perf_counter()
            live.radio.append([r for r in records if t <= r.t < t + BATCH])
            closed = round(t) if abs(t - round(t)) < 1e-9 else None  # its first record closed that window
            t += BATCH
            if closed is not None:
                shown.to_have_attribute("data-rti", str(closed), timeout=60_000)
                lags.append(time.perf_counter() - arrived)
                station_lags.append(running.station.rti.latest().latency_s)
            else:
                time.sleep(max(0.0, BATCH - (time.perf_counter() - arrived)))
        skipped = running.station.rti.skipped
        browser.close()
    return {"lags": lags, "station": station_lags, "skipped": skipped}


def main() -> None:
    print(f"# Live radio tomography ({code_state()})\n")
    print("Solve per frame (60 s of records, cell 0.25 m, 6.4 m square), and the 3D view's draw of a frame:\n")
    print(table(["radios", "channels", "records", "paths", "ms/frame", "frames/s", "3D draw ms", "peak error m"],
                solve_speed()))
    found = end_to_end()
    lags, station = np.array(found["lags"]), np.array([s for s in found["station"] if s is not None])
    print(f"\nEnd to end, 16 radios, a batch every {BATCH} s, {len(lags)} windows of 1 s:\n")
    print(table(["", "median s", "90th percentile s", "max s"],
                [["arrival -> page shows the frame", f"{np.median(lags):.3f}", f"{np.percentile(lags, 90):.3f}",
                  f"{lags.max():.3f}"],
                 ["arrival -> frame made (station)", f"{np.median(station):.3f}",
                  f"{np.percentile(station, 90):.3f}", f"{station.max():.3f}"]]))
    print(f"\nwindows skipped by a slow solve: {found['skipped']}")


if __name__ == "__main__":
    main()
