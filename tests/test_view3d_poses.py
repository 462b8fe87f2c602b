"""The 3D view sends a pose as it comes, not on its next frame, and a burst of poses as one update.

A real ``SceneView`` (viser on a loopback port) draws a real ``Fleet`` fed real
pymavlink messages. Its frame and slow beats are stretched to minutes, so only
the fleet's news of a pose can make it draw: a view that polled would not.
"""

from __future__ import annotations

import pytest
from harness import wait_wall
from mavlink_peer import Delivered, position, vehicle_heartbeat

import groundstation.viz as viz
from groundstation.state import Fleet
from vehicle.protocol.geodesy import Datum

DATUM = Datum()


class Vehicle(Delivered):
    """One autopilot's messages (``mavlink_peer``'s), packed and decoded as a link delivers them to the fleet."""

    def heartbeat(self):
        return self(vehicle_heartbeat())

    def at(self, x: float, y: float = 0.0):
        return self(position(*DATUM.to_global(x, y)))


@pytest.fixture
def view(monkeypatch):
    """A running view whose own beats (cameras, trails) come only every few minutes."""
    monkeypatch.setattr(viz, "RATE", 1 / 300)
    monkeypatch.setattr(viz, "SLOW_PERIOD", 300.0)
    fleet = Fleet(DATUM)
    one = Vehicle(1)
    fleet.apply(one.heartbeat(), 0.0)
    fleet.apply(one.at(0.0), 0.0)
    scene_view = viz.SceneView(fleet, None)
    drawn: list[int] = []
    draw_vehicle = scene_view._draw_vehicle
    scene_view._draw_vehicle = lambda v, colour, slow: (drawn.append(v.sysid), draw_vehicle(v, colour, slow))
    scene_view.drawn = drawn
    scene_view.start()
    try:
        wait_wall(lambda: 1 in scene_view._drawn, 10, "the first frame")  # the loop's first beat draws it
        yield scene_view, fleet, one
    finally:
        scene_view.close()


def body_x(scene_view) -> float:
    return float(scene_view._drawn[1]["body"].position[0])


def test_a_pose_is_sent_as_it_comes_not_on_the_next_frame(view):
    scene_view, fleet, one = view
    for x in (3.0, 6.0, 9.0):
        fleet.apply(one.at(x), 1.0)
        wait_wall(lambda x=x: abs(body_x(scene_view) - x) < 0.05, 10, f"the view showing x = {x}")


def test_a_burst_of_poses_is_one_update_for_each_vehicle_that_moved(view):
    scene_view, fleet, one = view
    two, three = Vehicle(2), Vehicle(3)
    fleet.apply(three.heartbeat(), 1.0)
    fleet.apply(three.at(-5.0), 1.0)
    wait_wall(lambda: 3 in scene_view._drawn, 10, "vehicle 3 drawn")
    with fleet.lock:  # the view wakes, then waits for the lock: everything below arrives as one burst
        fleet.apply(two.heartbeat(), 1.0)
        drawn_before = len(scene_view.drawn)
        for k in range(1, 51):
            fleet.apply(one.at(0.1 * k), 1.0)
            fleet.apply(two.at(0.1 * k, 5.0), 1.0)
    wait_wall(lambda: abs(body_x(scene_view) - 5.0) < 0.05 and 2 in scene_view._drawn, 10, "the burst drawn")
    assert sorted(scene_view.drawn[drawn_before:]) == [1, 2]  # one update each, not fifty; none for 3
    assert fleet.moved == set()


def test_a_pose_that_comes_while_the_slow_layers_are_drawn_waits_for_one_vehicles_layers_only(view):
    """The slow beat draws one vehicle's trails, sonar and map at a time, and sends the poses that came meanwhile
    before the next vehicle's: a pose waited for the whole fleet's layers (and the fleet's lock with them)."""
    scene_view, fleet, one = view
    two = Vehicle(2)
    fleet.apply(two.heartbeat(), 1.0)
    fleet.apply(two.at(0.0, 5.0), 1.0)
    wait_wall(lambda: 2 in scene_view._drawn, 10, "vehicle 2 drawn")
    one_when_two_drawn = []
    draw_vehicle = scene_view._draw_vehicle

    def layers(v, colour, slow):
        if slow and v.sysid == 2:
            one_when_two_drawn.append(body_x(scene_view))
        draw_vehicle(v, colour, slow)
        if slow and v.sysid == 1:
            fleet.apply(one.at(7.0), 2.0)  # comes while vehicle 1's layers are drawn

    scene_view._draw_vehicle = layers
    scene_view.draw(slow=True, frame=False)
    assert one_when_two_drawn == [pytest.approx(7.0, abs=0.05)]
