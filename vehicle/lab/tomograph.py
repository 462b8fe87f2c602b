"""Scoring a radio tomography run: the links the team measured while it dwelt, imaged as the run goes, and how far
each target lies from the image's nearest peak over time.

Only the records measured while every radio stood at its spot are imaged (a record from a moving radio is a
link of its own, seen once: it says little and every one of them would grow the solve). The empty-area levels
come from a calibration capture of the same links with the targets away (``empty``): the plan does not depend
on what the radios read, so a team that flies it once over the empty area stops at the same spots, and the
simulation measures that capture beside the real one, at the same instants, with its own noise. The image is
``vehicle.tomography.reconstruct`` over everything so far, by the method for people standing still (``STANDING``,
as the station's live image), at most one per ``every`` seconds, with as many peaks as there are targets: a target
is found when a peak lies within ``FOUND_M`` of it. Not ``calibrated``: no capture, each link's empty level from
a path-loss model fitted across the links, as the station's live image has it (``empty_from="brief"``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from vehicle.tomography.imaging import STANDING, reconstruct
from vehicle.tomography.links import records_of

FOUND_M = 0.5  # m: a target this close to a peak is found
EVERY = 10.0  # s of simulated time between two images
CELL = 0.25  # m: the image's pixel, half the distance a target must be found within (finer costs more per image)


@dataclass
class Tomograph:
    targets: list[tuple[float, float]]
    bounds: tuple[float, float, float, float]
    every: float = EVERY
    calibrated: bool = True
    records: list = field(default_factory=list)
    empty: list = field(default_factory=list)
    heard: int = 0  # every record received, moving or not
    frames: list[dict] = field(default_factory=list)  # {"t", "distances", "peaks"}
    found_s: float | None = None
    _last: float = -math.inf
    _new: bool = False

    def note(self, t: float, received: list, empty: list, still: bool) -> None:
        """The records received in the step ending at ``t`` and their empty-area twins; ``still``: every radio
        stood at its spot through it."""
        self.heard += len(received)
        if still and received:
            self.records.extend(received)
            self.empty.extend(empty)
            self._new = True
        if self._new and t - self._last >= self.every:
            self.image(t)

    def image(self, t: float) -> dict | None:
        """Image what was kept so far; note each target's distance to the nearest peak."""
        self._last, self._new = t, False
        if len(self.records) < 2:
            return None
        empty = {"calibration": records_of(self.empty, "empty")} if self.calibrated else {"empty_from": "brief"}
        result = reconstruct(records_of(self.records, "run"), bounds=self.bounds, cell=CELL, peaks=len(self.targets),
                             **empty, **STANDING)
        peaks = result.frames[0]["peaks"]
        distances = [min((math.dist(target, (p["x"], p["y"])) for p in peaks), default=math.inf)
                     for target in self.targets]
        frame = {"t": round(t, 2), "distances": [round(d, 3) if math.isfinite(d) else None for d in distances],
                 "peaks": peaks, "paths": result.info["links"]["paths"]}
        self.frames.append(frame)
        if self.found_s is None and all(d <= FOUND_M for d in distances):
            self.found_s = round(t, 2)
        return frame

    def result(self, t: float) -> dict:
        """The run's figures: the last image's peaks and distances, when all were first found, the links."""
        if self._new or not self.frames:
            self.image(t)
        last = self.frames[-1] if self.frames else {"distances": [None] * len(self.targets), "peaks": [], "paths": 0}
        found = all(d is not None and d <= FOUND_M for d in last["distances"])
        return {"targets": [list(p) for p in self.targets], "bounds": list(self.bounds),
                "links_heard": self.heard, "links_imaged": len(self.records), "paths": last["paths"],
                "peaks": last["peaks"], "distances_m": last["distances"], "found": found,
                "found_s": self.found_s, "found_within_m": FOUND_M,
                "over_time": [[f["t"], *f["distances"]] for f in self.frames]}


RADIO_PERIOD = 0.1  # s of simulated time measured at once (a round of the radios' slots is shorter)


class RadioRun:
    """The radios of a team's vehicles (and fixed nodes) measured beside its flight, and the tomograph fed: an
    ``on_step`` for ``run_team``. Two channels with one model and scene: the targets' and the empty area's
    (its own noise), measured at the same instants from the same positions."""

    def __init__(self, scene, targets: list[tuple[float, float]], bounds, seed: int = 0,
                 nodes: list[tuple[float, ...]] | None = None, model=None):
        from vehicle.world.radio import NODE_IDS, RadioChannel, RadioModel

        model = model or RadioModel()
        self.channel = RadioChannel(scene, model, seed)
        self.empty = RadioChannel(scene, model, seed + 7919)
        self.targets = [tuple(t) for t in targets]
        self.nodes = {NODE_IDS + k: (*p[:2], p[2] if len(p) > 2 else 1.0) for k, p in enumerate(nodes or [])}
        self.tomograph = Tomograph(self.targets, tuple(bounds))
        self.until_mission_end = False  # end the run when every mission has (a benchmark needs no landing)
        self._since = 0.0

    def __call__(self, stepper) -> bool:
        """Measure (every RADIO_PERIOD); True when the run may end: ``until_mission_end`` and every mission over."""
        now = stepper.team.time
        if now - self._since < RADIO_PERIOD - 1e-9:
            return False
        radios = {sysid: tuple(sim.body.pose.xyz()) for sysid, sim in zip(stepper.team.ids, stepper.team.simulations,
                                                                           strict=True)}
        radios.update(self.nodes)
        received = self.channel.measure(self._since, now, radios, self.targets)
        empty = self.empty.measure(self._since, now, radios, [])
        self._since = now
        self.tomograph.note(now, received, empty, all(dwelling(agent) for agent in stepper.agents))
        return self.until_mission_end and all(agent.mission_began and agent.phase not in ("preflight", "takeoff",
                                                                                          "mission")
                                              for agent in stepper.agents)


def dwelling(agent) -> bool:
    """The agent's rti mission holds at its spot while the radios measure."""
    from vehicle.agent.missions.rti import Phase

    return agent.phase == "mission" and getattr(agent.mission, "phase", None) is Phase.DWELL


def run_team_experiment(experiment, scene, count: int, targets: list[tuple[float, float]],
                        starts: list[tuple[float, ...]] | None = None, ids: list[int] | None = None,
                        nodes: list[tuple[float, ...]] | None = None, waypoints=None, model=None,
                        until_mission_end: bool = False, calibrated: bool = True) -> dict:
    """A team run (``run_team``), with radios measuring when the mission is rti or targets are given: the
    result then has ``rti`` (``Tomograph.result``). ``until_mission_end``: the run ends when every mission has
    (the vehicles then report ``timeout`` on their way home). Raises PlacementError (and ValueError) before
    anything flies."""
    from vehicle.agent.missions.rti import region
    from vehicle.lab.experiment import run_team
    from vehicle.lab.stepper import simulate_team

    settings = experiment.settings
    stepper = simulate_team(scene, experiment.mission, count, experiment.vehicle, settings, starts, ids,
                            [waypoints] * count if waypoints else None, seed=experiment.seed,
                            suite=experiment.sensors, datum=experiment.datum)
    radios = None
    if experiment.mission == "rti" or targets:
        home = stepper.team.simulations[0].home
        radios = RadioRun(scene, targets, region(settings, scene, (home[0], home[1])), experiment.seed, nodes, model)
        radios.until_mission_end = until_mission_end
        radios.tomograph.calibrated = calibrated
        for controller in stepper.controllers:
            controller.radio_nodes = [p[:2] for p in (nodes or [])]
    result = run_team(experiment, stepper, radios)
    if radios is not None:
        result["rti"] = radios.tomograph.result(stepper.team.time)
    return result
