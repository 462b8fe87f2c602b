"""The plan view's station side (groundstation.plan, groundstation/api/plan.py): plans to mission items and back,
QGC WPL and QGroundControl .plan files both ways, hostile files refused with a reason, and legs through a building
marked. The page that uses them is tested in test_browser_plan."""

from __future__ import annotations

import json

import pytest
from harness import RunningStation

from groundstation.plan import Plan, PlanError, PlanItem, check_legs, read_file, to_mission, write_file
from vehicle.protocol.geodesy import Datum
from vehicle.protocol.mav import mavlink
from vehicle.world.raycast import RayCaster

DATUM = Datum(-35.363261, 149.165230, 584.0)
TOKEN = "plan-test-token"

PLAN = Plan(home=(1.0, -2.0), items=[
    PlanItem(action="takeoff", x=1.0, y=-2.0, alt=5.0),
    PlanItem(action="waypoint", x=10.0, y=0.0, alt=6.0, speed=3.0, hold=2.0),
    PlanItem(action="loiter", x=10.0, y=12.5, alt=6.0, hold=7.0),
    PlanItem(action="waypoint", x=-4.25, y=12.5, alt=4.0, speed=1.5),
    PlanItem(action="land", x=-4.25, y=0.0),
    PlanItem(action="rtl", x=1.0, y=-2.0),
])


def same(a: Plan, b: Plan) -> None:
    assert a.home == pytest.approx(b.home, abs=1e-3)
    assert len(a.items) == len(b.items)
    for mine, theirs in zip(a.items, b.items, strict=True):
        assert (mine.action, mine.speed, mine.hold) == (theirs.action, theirs.speed, theirs.hold)
        assert (mine.x, mine.y, mine.alt) == pytest.approx((theirs.x, theirs.y, theirs.alt), abs=1e-3)


def test_a_plan_is_mission_items_with_home_first_and_speeds_before_their_items():
    items = to_mission(PLAN, DATUM)
    commands = [i.command for i in items]
    assert commands == [mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_CMD_NAV_TAKEOFF, mavlink.MAV_CMD_DO_CHANGE_SPEED,
                        mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_CMD_NAV_LOITER_TIME,
                        mavlink.MAV_CMD_DO_CHANGE_SPEED, mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_CMD_NAV_LAND,
                        mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH]
    assert items[2].param2 == 3.0 and items[4].param1 == 7.0 and items[3].param1 == 2.0
    assert DATUM.to_local(items[0].lat, items[0].lon) == pytest.approx((1.0, -2.0), abs=1e-3)


@pytest.mark.parametrize("kind", ["wpl", "plan"])
def test_files_round_trip(kind):
    text = write_file(PLAN, DATUM, kind)
    if kind == "plan":
        document = json.loads(text)
        assert document["fileType"] == "Plan" and document["mission"]["version"] == 2
        assert len(document["mission"]["items"]) == 8
    else:
        assert text.startswith("QGC WPL 110\n")
    same(read_file(text, DATUM), PLAN)


def test_a_qgroundcontrol_plan_with_nulls_reads():
    """QGroundControl writes a NaN parameter (yaw: keep the heading) as null."""
    document = json.loads(write_file(PLAN, DATUM, "plan"))
    document["mission"]["items"][1]["params"][3] = None
    same(read_file(json.dumps(document), DATUM), PLAN)


def hostile_plans() -> list[tuple[str, str]]:
    good = json.loads(write_file(PLAN, DATUM, "plan"))

    def changed(change) -> str:
        document = json.loads(json.dumps(good))
        change(document)
        return json.dumps(document)

    def item(key, value):
        return lambda d: d["mission"]["items"][1].__setitem__(key, value)

    return [
        ("", "neither a QGC WPL mission"),
        ("hello", "neither a QGC WPL mission"),
        ("{\"fileType\": ", "not valid JSON (line 1, column"),
        ("[" * 100_000 + "]" * 100_000, "neither"),
        ("{" + "\"a\":{" * 100_000 + "}" * 100_001, "not valid JSON"),
        ("{\"fileType\": \"Survey\"}", "fileType is not \"Plan\""),
        ("{\"fileType\": \"Plan\", \"mission\": 5}", "no mission with a list of items"),
        (changed(lambda d: d["mission"].__setitem__("plannedHomePosition", [1, 2])), "plannedHomePosition"),
        (changed(lambda d: d["mission"].__setitem__("items", [{}] * 701)), "701 items; at most 700"),
        (changed(lambda d: d["mission"]["items"].append({"type": "ComplexItem", "complexItemType": "survey"})),
         "item 9 is a survey pattern; turn it into waypoints"),
        (changed(item("params", [0, 0, 0, 0, 1e999, 0, 0])), "item 2: params must be numbers"),
        (changed(item("params", [0, 0, 0, 0, 91.0, 0, 5])), "item 2: latitude 91.0 or longitude 0.0 is not on Earth"),
        (changed(item("params", [0, 0, 0])), "item 2: params must be a list of 7 numbers"),
        (changed(item("params", ["1", 0, 0, 0, 1, 1, 1])), "item 2: params must be numbers"),
        (changed(item("command", True)), "item 2: command and frame must be whole numbers"),
        (changed(item("command", 183)), "item 2: command 183 (MAV_CMD_DO_SET_SERVO) is not one the plan view edits"),
        (changed(lambda d: d["mission"]["items"][2].__setitem__("frame", 0)),
         "item 3: frame 0 (MAV_FRAME_GLOBAL); the plan view plans altitudes above home"),
        (changed(item("type", "Other")), "item 2: its type is not \"SimpleItem\""),
        (changed(lambda d: d["mission"]["items"].__setitem__(0, 7)), "item 1 is not an object"),
        ("QGC WPL 110\n0\t1\t0\t16\t0\t0\t0\t0\t-35.36\t149.16\t584\t1\n1\t0\t3\t16\t0\t0\t0\t0\t1_0\t149\t5\t1\n",
         "line 3: field 9 is not a decimal number"),
        ("QGC WPL 110\n0\t1\t0\t16\t0\t0\t0\t0\t-35.36\t149.16\t584\t1\n1\t0\t3\t16\t0\t0\t0\t0\t-35\t149\t5\n",
         "line 3 has 11 fields, not 12"),
        ("QGC WPL 110\n0\t1\t0\t16\t0\t0\t0\t0\t-35.36\t149.16\t584\t1\n1\t0\t3\t22\t0\t0\t0\t0\t95\t149\t5\t1\n",
         "is not on Earth"),
        ("QGC WPL 110\n0\t1\t0\t16\t0\t0\t0\t0\t-35.36\t149.16\t584\t1\n1\t0\t3\t16\t-1\t0\t0\t0\t-35\t149\t5\t1\n",
         "item 1: a hold of -1.0 s"),
    ]


@pytest.mark.parametrize(("text", "reason"), hostile_plans(), ids=range(len(hostile_plans())))
def test_hostile_files_are_refused_with_a_reason(text, reason):
    with pytest.raises(PlanError) as refused:
        read_file(text, DATUM)
    assert reason in str(refused.value)
    assert len(str(refused.value)) < 300  # a reason, never the file quoted back


def test_a_leg_through_a_building_is_marked(wall_scene):
    """The wall's south face is at y = 9.9 for -10 < x < 10, up to 5 m: a leg across it at 3 m is blocked, one
    past its end or above it is not."""
    plan = Plan(home=(0.0, 0.0), items=[
        PlanItem(action="takeoff", x=0, y=0, alt=3), PlanItem(action="waypoint", x=0, y=20, alt=3),
        PlanItem(action="waypoint", x=15, y=20, alt=3), PlanItem(action="waypoint", x=15, y=0, alt=3),
        PlanItem(action="waypoint", x=0, y=0, alt=8), PlanItem(action="waypoint", x=0, y=20, alt=8),
    ])
    legs = check_legs(plan, wall_scene, RayCaster(wall_scene), 0.0)
    assert [leg["blocked"] for leg in legs] == [False, True, False, False, False, False]
    assert legs[1]["hit"][1] == pytest.approx(9.9, abs=0.05) and legs[1]["length"] == 20.0
    # grazing: a leg 0.2 m past the wall's end still touches a 0.3 m body
    graze = Plan(home=(10.2, 0.0), items=[PlanItem(action="waypoint", x=10.2, y=0, alt=3),
                                          PlanItem(action="waypoint", x=10.2, y=20, alt=3)])
    assert [leg["blocked"] for leg in check_legs(graze, wall_scene, RayCaster(wall_scene), 0.0)] == [False, True]


def test_the_api_checks_imports_and_exports(wall_scene, tmp_path):
    with RunningStation(wall_scene, tmp_path, TOKEN) as running:
        http = running.http
        body = json.loads(PLAN.model_dump_json())
        body["items"][1] = {"action": "waypoint", "x": 0, "y": 20, "alt": 3}
        checked = http.post("/api/plan/check", json=body, headers=http.operator).json()
        assert checked["scene"] and [leg["blocked"] for leg in checked["legs"]][:3] == [False, True, False]
        assert checked["legs"][1]["object"] == "shape 1"  # the wall (the scene's second shape, unnamed)
        for kind in ("wpl", "plan"):
            exported = http.post("/api/plan/export", params={"format": kind}, json=json.loads(PLAN.model_dump_json()),
                                 headers=http.operator)
            assert exported.status_code == 200 and "attachment" in exported.headers["content-disposition"]
            imported = http.post("/api/plan/import", content=exported.text, headers=http.operator)
            assert imported.status_code == 200, imported.text
            same(Plan.model_validate(imported.json()), PLAN)
        refused = http.post("/api/plan/import", content=b"{\"fileType\": \"Plan\", \"mission\": []}",
                            headers=http.operator)
        assert refused.status_code == 422 and "no mission with a list of items" in refused.json()["detail"]
        for bad in ('{"items": [{"action": "fly", "x": 0, "y": 0}]}', '{"items": [{"action": "waypoint", "x": 1e9, '
                    '"y": 0}]}', '{"home": [NaN, 0], "items": []}', '{"items": [{"action": "land", "x": 0, "y": '
                    'Infinity}]}', '{"items": [{"action": "loiter", "x": 0, "y": 0, "hold": -1}]}'):
            refused = http.post("/api/plan/check", content=bad, headers={**http.operator,
                                                                         "Content-Type": "application/json"})
            assert refused.status_code == 422, (bad, refused.text)
        assert http.get("/api/vehicles/7/mission/progress").status_code == 404
