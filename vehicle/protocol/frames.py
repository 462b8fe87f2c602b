"""The scene frame and the body frame: a pose, and the rotations between them.

Everything on both ends of a link speaks the scene frame: metres, x east, y
north, z up. Attitudes follow MAVLink's ATTITUDE: ``yaw`` a compass heading (0
= north, clockwise), ``pitch`` nose up and ``roll`` right side down, positive.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass
class Pose:
    """Body centre in scene metres and attitude in radians (see the module's conventions)."""

    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    yaw: float = 0.0
    pitch: float = 0.0
    roll: float = 0.0

    def xyz(self) -> tuple[float, float, float]:
        return self.x, self.y, self.z


@dataclass(slots=True)
class Navigation:
    """Where a flight controller's navigation is taking the vehicle now."""

    heading: float | None  # compass radians it wants to move along; None while it holds or turns in place
    reach: float  # m to where it is going (inf when it is going nowhere in particular)


def body_to_world(pose: Pose) -> np.ndarray:
    """Rotation from the body frame (x forward, y left, z up) to the scene frame (x east, y north, z up).

    Applies roll, then pitch, then yaw (the aerospace order the thesis uses), with
    MAVLink's signs: yaw a compass heading, pitch nose up, roll right side down.
    """
    heading = math.pi / 2 - pose.yaw  # counter-clockwise angle from east: forward maps to (sin yaw, cos yaw)
    ch, sh = math.cos(heading), math.sin(heading)
    cp, sp = math.cos(pose.pitch), math.sin(pose.pitch)
    cr, sr = math.cos(pose.roll), math.sin(pose.roll)
    # Rz(heading) @ R(pitch nose up) @ Rx(roll, left side up), multiplied out
    return np.array([
        [ch * cp, -ch * sp * sr - sh * cr, sh * sr - ch * sp * cr],
        [sh * cp, ch * cr - sh * sp * sr, -sh * sp * cr - ch * sr],
        [sp, cp * sr, cp * cr],
    ])


def rotation_zy(yaw_left: float, pitch_up: float) -> np.ndarray:
    """Rotation by ``pitch_up`` about -y (nose up) then ``yaw_left`` about z, in a frame with x forward, z up."""
    cy, sy = math.cos(yaw_left), math.sin(yaw_left)
    cp, sp = math.cos(pitch_up), math.sin(pitch_up)
    yaw = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    pitch = np.array([[cp, 0.0, -sp], [0.0, 1.0, 0.0], [sp, 0.0, cp]])
    return yaw @ pitch


def mount_rotation(yaw_offset: float, pitch: float) -> np.ndarray:
    """Rotation from a sensor's frame to the body frame, for a mount ``yaw_offset`` degrees clockwise of the
    nose and ``pitch`` degrees up."""
    return rotation_zy(-math.radians(yaw_offset), math.radians(pitch))


def beam_axis(pose: Pose, yaw_offset: float, pitch: float = 0.0) -> np.ndarray:
    """Unit vector, in the scene frame, of a beam mounted ``yaw_offset`` degrees clockwise of the nose and
    ``pitch`` degrees up, on a body at ``pose``."""
    return body_to_world(pose) @ mount_rotation(yaw_offset, pitch)[:, 0]
