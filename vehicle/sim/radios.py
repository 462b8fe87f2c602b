"""The radios of one simulated world: each vehicle's and the fixed nodes', measured as the world steps.

Every ``period`` of simulated time the channel (``vehicle.world.radio``) answers which packets were heard in the
slots since the last call, from where the radios stand now; each vehicle's agent gets the ones its own radio
heard (``hear``), to send to the ground station. A fixed node has no link to a station: what it hears is not
reported, what it sends is (by the vehicles that hear it).
"""

from __future__ import annotations

from vehicle.protocol.radiostream import LinkRecord
from vehicle.world.radio import NODE_IDS, RadioChannel, RadioModel

PERIOD = 0.1  # s of simulated time measured at once


class Radios:
    def __init__(self, scene, ids: list[int], nodes: list[tuple[float, float, float]] | None = None,
                 targets: list[tuple[float, float]] | None = None, model: RadioModel | None = None, seed: int = 0,
                 home: dict[int, tuple[float, float]] | None = None):
        """``ids``: the vehicles' system ids; ``home``: each one's home (scene x, y), which its records are
        relative to, as everything a vehicle sends. ValueError if a vehicle's id is a fixed node's."""
        self.nodes = {NODE_IDS + k: tuple(p) for k, p in enumerate(nodes or [])}
        clash = sorted(set(ids) & set(self.nodes))
        if clash:
            raise ValueError(f"system id {clash[0]} is a fixed radio node's (nodes have ids {NODE_IDS} and up)")
        self.ids = list(ids)
        self.targets = [tuple(t) for t in targets or []]
        self.channel = RadioChannel(scene, model, seed)
        self.home = home or {}
        self._since: float | None = None

    def step(self, time: float, positions: dict[int, tuple[float, float, float]]) -> dict[int, list[LinkRecord]]:
        """The records each vehicle heard since the last call (none until ``PERIOD`` has passed)."""
        if self._since is None:
            self._since = time
        if time - self._since < PERIOD - 1e-9:
            return {}
        records = self.channel.measure(self._since, time, {**positions, **self.nodes}, self.targets)
        self._since = time
        heard: dict[int, list[LinkRecord]] = {}
        for r in records:
            if r.rx in positions:
                hx, hy = self.home.get(r.rx, (0.0, 0.0))
                heard.setdefault(r.rx, []).append(LinkRecord(r.t, r.tx, r.rx, r.tx_x - hx, r.tx_y - hy, r.rx_x - hx,
                                                             r.rx_y - hy, r.rssi, r.channel))
        return heard
