"""The REST area of the live radio tomography: an empty answer until a frame is imaged, the frame's figures,
peaks, links and image once link records arrive, the targets as ground truth, and bad requests refused."""

from __future__ import annotations

import base64
import io
import math

import pytest
from harness import RunningStation, wait_wall
from PIL import Image
from test_rti_live import TARGET, sweep_rows

TOKEN = "rti-api-token"


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    """A station with no scene and no vehicle: the tests put link records in its fleet's log themselves."""
    with RunningStation(None, tmp_path_factory.mktemp("recordings"), TOKEN) as running:
        yield running


def test_no_records_is_an_empty_answer_not_a_404(station):
    answer = station.http.get("/api/rti")
    assert answer.status_code == 200
    assert answer.json() == {"frame": None, "targets": None, "frames": 0, "skipped": 0, "records": 0, "error": None}
    image = station.http.get("/api/rti/image")
    assert image.status_code == 200 and image.json() == {"image": None, "bounds": None, "t": None, "scale": None}
    assert station.http.get("/api/rti/image?format=png").status_code == 204


@pytest.mark.parametrize("query", ["/api/rti/image?format=gif", "/api/rti?links=maybe", "/api/rti/image?format="])
def test_bad_requests_are_refused_with_what_was_wrong(station, query):
    answer = station.http.get(query)
    assert answer.status_code == 422
    assert answer.json()["detail"][0]["loc"][0] == "query"


def test_records_give_a_frame_its_image_and_the_targets(station):
    imager = station.station.rti
    imager.targets = [list(TARGET)]
    station.station.live.radio.append(sweep_rows(0.0, 30.0))
    wait_wall(lambda: station.http.get("/api/rti").json()["frame"] is not None, 120, "a frame imaged")
    answer = station.http.get("/api/rti").json()
    frame = answer["frame"]
    assert frame["t"] == 29.0 and frame["bounds"] == [0.0, 0.0, 6.4, 6.4]
    assert math.dist((frame["peaks"][0]["x"], frame["peaks"][0]["y"]), TARGET) < 0.5
    assert frame["links_per_s"] > 0 and 0.9 < frame["coverage"] <= 1 and len(frame["links"]) == 120
    assert frame["latency_s"] >= 0 and answer["targets"] == [list(TARGET)] and answer["records"] > 0
    assert "links" not in station.http.get("/api/rti?links=false").json()["frame"]
    drawn = station.http.get("/api/rti/image").json()
    assert drawn["bounds"] == [0.0, 0.0, 6.4, 6.4] and drawn["t"] == 29.0
    assert drawn["scale"]["max"] == pytest.approx(frame["max"]) and len(drawn["scale"]["colours"]) == 5
    png = Image.open(io.BytesIO(base64.b64decode(drawn["image"].split(",", 1)[1])))
    assert png.size == (26, 26) and png.mode == "RGBA"  # 6.4 m in 0.25 m pixels
    nodes = station.station.view.server.scene._handle_from_node_name  # the 3D view's ground shows it too
    assert {"/layers/rti/image", "/layers/rti/peaks", "/layers/rti/peak0"} <= set(nodes)
    raw = station.http.get("/api/rti/image?format=png")
    assert raw.headers["content-type"] == "image/png" and Image.open(io.BytesIO(raw.content)).size == (26, 26)
