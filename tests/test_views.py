"""A page's requests for its own 3D view (groundstation/views.py): checked, applied to that viewer only,
refused with a fixed message that never repeats what was sent; and over a real /ws stream."""

from __future__ import annotations

import json

import pytest
from harness import RunningStation, wait_wall
from websockets.exceptions import ConnectionClosedError
from websockets.sync.client import connect as ws_connect

from groundstation.views import MAX_REQUEST, ViewRequestError, Views, parse

VIEWER = "viewer-views-test-0001"
HOSTILE = "<img src=x onerror=alert(1)>"


def test_good_requests_change_that_viewer_alone():
    views = Views()
    answer = views.apply("a" * 16, json.dumps({"type": "camera", "mode": "follow"}))
    assert answer["mode"] == "follow"
    views.apply("a" * 16, json.dumps({"type": "select", "sysid": 3}))
    views.apply("a" * 16, json.dumps({"type": "layers", "layers": {"trails": False}, "opacity": 0.3}))
    mine = views.get("a" * 16)
    assert (mine.mode, mine.sysid, mine.layers["trails"], mine.layers["map"], mine.opacity) == \
        ("follow", 3, False, True, 0.3)
    assert views.get("b" * 16) is None  # another viewer has nothing of it
    views.apply("a" * 16, json.dumps({"type": "camera", "action": "fit"}))
    assert views.get("a" * 16).mode == "orbit"  # a one-shot move leaves the camera free
    assert views.take_action("a" * 16) == "fit" and views.take_action("a" * 16) is None
    views.apply("a" * 16, json.dumps({"type": "zoom", "x": 0.5, "y": -0.25, "steps": 2}))
    (zoom,) = views.take_zooms("a" * 16)
    assert (zoom.x, zoom.y, zoom.steps) == (0.5, -0.25, 2.0)


def test_the_page_s_target_is_marked_in_its_3d_view_until_the_page_drops_it():
    """The Go here target lives in the page (picked on the 2D map or in the 3D view); the 3D view marks
    what the page holds, and a click in the 3D view is marked before the page has heard of it."""
    views = Views()
    answer = views.apply("a" * 16, json.dumps({"type": "target", "x": 3.5, "y": -2}))
    assert answer["target"] == [3.5, -2.0] and views.get("a" * 16).target == (3.5, -2.0)
    version = views.get("a" * 16).version
    views.set_target("a" * 16, (1.0, 1.0))  # a click in this viewer's 3D view
    assert views.get("a" * 16).target == (1.0, 1.0) and views.get("a" * 16).version > version
    views.apply("a" * 16, json.dumps({"type": "target", "x": None, "y": None}))  # reached, or dropped
    assert views.get("a" * 16).target is None


def test_the_part_of_the_view_under_the_2d_map_is_that_viewer_s():
    views = Views()
    views.apply("a" * 16, json.dumps({"type": "covered", "box": [-1, -1, -0.2, 0.1]}))
    assert views.get("a" * 16).covered == (-1.0, -1.0, -0.2, 0.1)
    views.apply("a" * 16, json.dumps({"type": "covered", "box": None}))  # map folded or swapped
    assert views.get("a" * 16).covered is None


@pytest.mark.parametrize("text", [
    "", "not json", "[]", "null", json.dumps({"type": HOSTILE}),
    json.dumps({"type": "camera", "mode": HOSTILE}), json.dumps({"type": "camera", "action": HOSTILE}),
    json.dumps({"type": "camera"}), json.dumps({"type": "camera", "mode": "orbit", HOSTILE: 1}),
    json.dumps({"type": "select", "sysid": 0}), json.dumps({"type": "select", "sysid": 256}),
    json.dumps({"type": "select", "sysid": "1"}), json.dumps({"type": "select", "sysid": True}),
    json.dumps({"type": "select", "sysid": 1.5}),
    json.dumps({"type": "layers", "layers": {HOSTILE: True}}), json.dumps({"type": "layers", "layers": {"map": 1}}),
    json.dumps({"type": "layers", "opacity": 0.5}), '{"type": "layers", "opacity": NaN}',
    json.dumps({"type": "zoom", "x": 2, "y": 0, "steps": 1}), '{"type": "zoom", "x": 0, "y": 0, "steps": Infinity}',
    json.dumps({"type": "zoom", "x": 0, "y": 0, "steps": 1e9}), json.dumps({"type": "zoom", "x": 0, "y": 0}),
    json.dumps({"type": "camera", "mode": "x" * MAX_REQUEST}),
    json.dumps({"type": "zoom", "x": 0, "y": 10**400, "steps": 1}),  # no float: math.isfinite raised OverflowError
    json.dumps({"type": "layers", "layers": {}, "opacity": -(10**400)}),
    json.dumps({"type": "target", "x": 1}), json.dumps({"type": "target", "x": None, "y": 2}),
    json.dumps({"type": "target", "x": "1", "y": 2}), '{"type": "target", "x": NaN, "y": 0}',
    json.dumps({"type": "target", "x": 1e7, "y": 0}), json.dumps({"type": "target", "x": True, "y": 0}),
    json.dumps({"type": "covered", "box": [0, 0, 1]}), json.dumps({"type": "covered", "box": [0.5, 0, 0.2, 1]}),
    json.dumps({"type": "covered", "box": [-2, 0, 0, 1]}), json.dumps({"type": "covered", "box": "all"}),
    json.dumps({"type": "covered"}),
])
def test_bad_requests_are_refused_without_echo(text):
    views = Views()
    with pytest.raises(ViewRequestError) as refused:
        views.apply("a" * 16, text)
    assert HOSTILE not in str(refused.value) and "xxxx" not in str(refused.value)
    settings = views.get("a" * 16)
    assert settings is None or (settings.mode, settings.sysid, settings.opacity, settings.target) == \
        ("orbit", None, 1.0, None)


def test_parse_keeps_only_known_keys():
    assert parse('{"type": "select", "sysid": null}') == {"type": "select", "sysid": None}
    assert parse('{"type": "layers", "layers": {"beams": false}}') == {"type": "layers", "layers": {"beams": False}}


def test_over_the_stream_a_page_is_answered_alone(tmp_path):
    with RunningStation(None, tmp_path, urls=[]) as station:
        url = f"ws://127.0.0.1:{station.http_port}"

        def answer(stream) -> dict:
            while True:
                note = json.loads(stream.recv(timeout=10))
                if note["type"] in ("view", "view-error"):
                    return note

        with ws_connect(f"{url}/ws?viewer={VIEWER}", origin=station.base) as mine, \
                ws_connect(f"{url}/ws", origin=station.base) as anonymous:
            mine.send(json.dumps({"type": "camera", "mode": "top"}))
            assert answer(mine)["mode"] == "top"
            assert station.station.view.views.get(VIEWER).mode == "top"
            mine.send(json.dumps({"type": "camera", "mode": HOSTILE}))
            refused = answer(mine)
            assert refused["type"] == "view-error" and HOSTILE not in refused["detail"]
            assert station.station.view.views.get(VIEWER).mode == "top"  # unchanged
            anonymous.send(json.dumps({"type": "camera", "mode": "top"}))
            assert answer(anonymous) == {"type": "view-error",
                                         "detail": "this stream has no viewer id: open it with ?viewer=ID"}
        views = station.station.view.views
        wait_wall(lambda: views.get(VIEWER) is None, 10, "the page went: its settings go with it")


def test_a_status_stream_that_fails_ends_saying_so_and_the_page_reconnects_to_a_working_one(tmp_path, caplog,
                                                                                           monkeypatch):
    """A status the station cannot build (a bug) must not leave the page connected to a stream that says
    nothing more: the stream ends (1011), the log says why, and a new one streams again."""
    with RunningStation(None, tmp_path, urls=[]) as station:
        url = f"ws://127.0.0.1:{station.http_port}/ws"
        status = station.station.status
        failing = {"on": True}

        def broken():
            if failing["on"]:
                raise KeyError("a status the station cannot build")
            return status()

        with ws_connect(url, origin=station.base) as stream:
            assert json.loads(stream.recv(timeout=10))["type"] == "vehicles"
            monkeypatch.setattr(station.station, "status", broken)
            with pytest.raises(ConnectionClosedError) as ended:
                while True:
                    stream.recv(timeout=10)
            assert ended.value.rcvd.code == 1011 and ended.value.rcvd.reason == "the status stream failed; reconnect"
        assert "the status stream failed: KeyError('a status the station cannot build')" in caplog.text
        failing["on"] = False
        with ws_connect(url, origin=station.base) as again:
            assert json.loads(again.recv(timeout=10))["type"] == "vehicles"
