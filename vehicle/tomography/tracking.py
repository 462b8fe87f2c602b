"""A constant-velocity Kalman filter on the strongest peak of each window: a person's track across frames.

The track is reported beside the peaks, never instead of them: the peaks stay the image's own.
State (x, y, vx, vy); white-acceleration process noise of ACCEL (a walking person turns and stops at about
1 m/s^2); measurement noise PEAK_SIGMA (the scatter of an image maximum around the person, about a cell or a
person's width). A peak outside the 99 % gate is not used; after MISSES such windows in a row the track
restarts at the peak (the person was lost, or it was another one).
"""

from __future__ import annotations

import numpy as np

ACCEL = 1.0  # m/s^2
PEAK_SIGMA = 0.5  # m
GATE = 9.21  # chi-square, 2 degrees of freedom, 99 %
MISSES = 3


class Tracker:
    def __init__(self, accel: float = ACCEL, peak_sigma: float = PEAK_SIGMA):
        self.accel, self.r = accel, peak_sigma ** 2
        self.x: np.ndarray | None = None
        self.P = np.eye(4)
        self.misses = 0

    def _predict(self, dt: float) -> None:
        F = np.eye(4)
        F[0, 2] = F[1, 3] = dt
        q = self.accel ** 2
        block = np.array([[dt ** 4 / 4, dt ** 3 / 2], [dt ** 3 / 2, dt ** 2]]) * q
        Q = np.zeros((4, 4))
        Q[np.ix_([0, 2], [0, 2])] = block
        Q[np.ix_([1, 3], [1, 3])] = block
        self.x = F @ self.x
        self.P = F @ self.P @ F.T + Q

    def step(self, dt: float, peak: tuple[float, float] | None) -> dict | None:
        """Advance by ``dt`` seconds and take the window's strongest peak (or None); the estimate after it."""
        if self.x is None:
            if peak is None:
                return None
            self._start(peak)
            return self.estimate()
        self._predict(dt)
        if peak is not None:
            H = np.zeros((2, 4))
            H[0, 0] = H[1, 1] = 1.0
            innovation = np.asarray(peak) - H @ self.x
            S = H @ self.P @ H.T + np.eye(2) * self.r
            if innovation @ np.linalg.solve(S, innovation) <= GATE:
                K = self.P @ H.T @ np.linalg.inv(S)
                self.x = self.x + K @ innovation
                self.P = (np.eye(4) - K @ H) @ self.P
                self.misses = 0
            else:
                self.misses += 1
                if self.misses >= MISSES:
                    self._start(peak)
        return self.estimate()

    def _start(self, peak: tuple[float, float]) -> None:
        self.x = np.array([peak[0], peak[1], 0.0, 0.0])
        self.P = np.diag([self.r, self.r, 1.0, 1.0])  # a walker's speed is about 1 m/s
        self.misses = 0

    def estimate(self) -> dict:
        x, y, vx, vy = (round(float(v), 3) for v in self.x)
        return {"x": x, "y": y, "vx": vx, "vy": vy, "sigma": round(float(np.sqrt(self.P[0, 0] + self.P[1, 1])), 3)}
