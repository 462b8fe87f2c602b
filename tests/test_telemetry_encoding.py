"""One encoder for positions, attitude, VFR_HUD and DISTANCE_SENSOR: a live vehicle's messages (one row) and an
experiment log's (thousands at once) are the same bytes, and those bytes follow ArduPilot's conventions
(integers truncated, degrees E7 rounded, heading in [0, 360), no echo as ``max_distance + 1``).

The expected values are written out with Python's scalars, message by message, as pymavlink packs them.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from vehicle.protocol.geodesy import Datum
from vehicle.protocol.mav import mavlink
from vehicle.protocol.rangefinder import Reading, distance_sensor, distance_sensors, orientation_of
from vehicle.sim.telemetry import huds, poses

DATUM = Datum()
HOME = (2.0, -3.0, 1.5)
PACKER = mavlink.MAVLink(None)
# time, x, y, z, yaw, pitch, roll, vx, vy, vz, yaw rate: edges of every field
POSES = np.array([
    [0.0, 0.0, 0.0, 1.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    [12.3456, -40.25, 17.75, 5.2, math.pi, 0.1, -0.2, -1.237, 2.555, -0.499, 0.3],
    [4294968.0, 1e4, -1e4, 0.2, 2 * math.pi - 1e-9, -0.3, 0.25, 12.0, -12.0, 3.0, -1.0],  # ms past 32 bits
    [7.0, 0.05, -0.05, 1.5 - 1e-7, 3 * math.pi / 2, 0.0, 0.0, 0.004, -0.006, 0.0049, 0.0],
])


def packed(message) -> bytes:
    """pymavlink's payload, as MAVLink 2 sends it (trailing zeros dropped, one kept)."""
    return message.pack(PACKER)[10:-2]


def sent(payloads: np.ndarray) -> bytes:
    """One encoded payload as MAVLink 2 sends it."""
    return payloads.tobytes().rstrip(b"\0") or b"\0"


def expected_pose(row) -> tuple:
    """GLOBAL_POSITION_INT, LOCAL_POSITION_NED and ATTITUDE of one pose, by hand."""
    now, x, y, z, yaw, pitch, roll, vx, vy, vz, yaw_rate = (float(v) for v in row)
    ms = int(now * 1000) & 0xFFFFFFFF
    lat, lon = DATUM.to_global(x, y)
    height = z - HOME[2]
    wrapped = yaw if yaw <= math.pi else yaw - 2 * math.pi
    return (mavlink.MAVLink_global_position_int_message(
                ms, int(round(lat * 1e7)), int(round(lon * 1e7)), int((DATUM.alt + HOME[2] + height) * 1000),
                int(height * 1000), int(vy * 100), int(vx * 100), int(-vz * 100),
                int(math.degrees(yaw) * 100) % 36000),
            mavlink.MAVLink_local_position_ned_message(ms, y - HOME[1], x - HOME[0], -height, vy, vx, -vz),
            mavlink.MAVLink_attitude_message(ms, roll, pitch, wrapped, 0.0, 0.0, yaw_rate))


@pytest.mark.parametrize("index", range(len(POSES)))
def test_a_pose_alone_and_in_a_batch_is_the_payload_written_out_by_hand(index):
    alone = poses(DATUM, HOME, POSES[index:index + 1])
    batch = poses(DATUM, HOME, POSES)
    for one, many, message in zip(alone, batch, expected_pose(POSES[index]), strict=True):
        assert one.tobytes() == many[index:index + 1].tobytes()
        assert sent(one) == packed(message), message.get_type()


def test_vfr_hud_alone_and_in_a_batch_is_the_payload_written_out_by_hand():
    rows = np.array([[0.0, 0.0, 1.5, 0.0, 0.0], [2.5, 2 * math.pi - 1e-9, 6.0, -0.7, 1.0],
                     [13.0, math.pi, 0.0, 2.0, 1.0]])
    batch = huds(DATUM, HOME, rows)
    for index, (speed, yaw, z, vz, flying) in enumerate(rows):
        message = mavlink.MAVLink_vfr_hud_message(speed, speed, int(math.degrees(yaw)) % 360, 50 if flying else 0,
                                                  DATUM.alt + HOME[2] + (z - HOME[2]), vz)
        alone = huds(DATUM, HOME, rows[index:index + 1])
        assert alone.tobytes() == batch[index:index + 1].tobytes() and sent(alone) == packed(message)


READINGS = [  # distance (None: no echo), yaw offset, pitch, max and min range, beam half-angle
    (1.234, 0.0, 0.0, 4.0, 0.02, 7.5), (None, 45.0, 0.0, 4.0, 0.02, 7.5), (0.01, 90.0, 0.0, 4.0, 0.05, 7.5),
    (3.0, 37.5, 0.0, 4.0, 0.02, 15.0), (2.0, 0.0, -20.0, 4.0, 0.02, 7.5), (900.0, 0.0, 0.0, 1000.0, 0.0, 1.0),
    (None, 315.0, 0.0, 700.0, 0.0, 1.0),
]


def test_distance_sensor_alone_and_in_a_batch_is_the_payload_written_out_by_hand():
    rows, expected = [], []
    for sensor, (distance, yaw, pitch, top_m, bottom_m, beam) in enumerate(READINGS):
        reading = Reading(1.0, sensor, np.zeros(3), np.array([0.0, 1.0, 0.0]), distance, top_m, yaw, beam, bottom_m,
                          pitch)
        ms = 4294968123 + sensor
        top, bottom = min(int(top_m * 100), 65534), int(bottom_m * 100)
        value = top + 1 if distance is None else max(bottom, int(distance * 100))
        orientation, quaternion = orientation_of(yaw, pitch)
        fov = math.radians(2 * beam)
        message = mavlink.MAVLink_distance_sensor_message(ms & 0xFFFFFFFF, bottom, top, min(value, 65535),
                                                          mavlink.MAV_DISTANCE_SENSOR_ULTRASOUND, sensor, orientation,
                                                          0, fov, fov, quaternion, 0)
        assert packed(distance_sensor(reading, ms)) == packed(message), READINGS[sensor]
        expected.append(packed(message))
        rows.append([ms, sensor, math.nan if distance is None else distance, yaw, pitch, top_m, bottom_m, beam])
    batch = distance_sensors(np.array(rows))
    assert [sent(batch[i:i + 1]) for i in range(len(rows))] == expected
