"""The attacks of the hostile-inputs issue, run against a live ground station and simulated vehicle.

Starts ``groundstation serve`` and ``vehicle sim`` (a copter with its onboard
agent, on the ground in the default scene) as processes of their own on
loopback: the station listens for MAVLink on one UDP port (the attackers' way
in) and reaches the vehicle on the vehicle's own port (another way in). Then it
runs each attack in turn and prints, per attack: whether it held (refused, or
harmless: see each attack's note), whether the real vehicle stayed tracked
(heartbeat age under 3 s at every look, four looks a second), how many of the
commands sent through the REST API meanwhile (one every half second) were
answered, and the station's resident memory before and after.

Targets: every attack held, memory growth under 100 MB for any of them, and a
flood of 20,000 messages/s of mixed garbage, MAVLink 1 and 2 for 10 s with no
command lost.

    python bench/hostile.py [--only NAME ...] [--list]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import random
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import msgspec
import websockets
from common import DEFAULT_SCENE, ROOT, code_state, table
from pymavlink.dialects.v10 import ardupilotmega as mavlink1
from websockets.sync.client import connect as ws_connect

from groundstation.state import MAX_VEHICLES
from vehicle.protocol.mapstream import MAP_SNAPSHOT, PAYLOAD
from vehicle.protocol.mav import mavlink

TOKEN = "bench-hostile-token"
TICKS = os.sysconf("SC_CLK_TCK")
VIEWER = "bench-operator-viewer-0123456789"


# ---- the parts under attack --------------------------------------------------------------------------------
def free_port(kind=socket.SOCK_DGRAM) -> int:
    with socket.socket(socket.AF_INET, kind) as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@dataclass
class Target:
    station_udp: int  # where the station listens for MAVLink
    vehicle_udp: int  # where the vehicle listens
    http: int
    station: subprocess.Popen
    vehicle: subprocess.Popen
    record_dir: Path
    api: httpx.Client = field(init=False)

    def __post_init__(self):
        self.api = httpx.Client(base_url=self.base, timeout=30.0, headers={"Authorization": f"Bearer {TOKEN}"})

    @property
    def base(self) -> str:
        return f"http://127.0.0.1:{self.http}"

    @property
    def ws(self) -> str:
        return f"ws://127.0.0.1:{self.http}"

    def resident_mb(self) -> float:
        with open(f"/proc/{self.station.pid}/status") as handle:
            for line in handle:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024
        return float("nan")

    def cpu_seconds(self) -> float:
        with open(f"/proc/{self.station.pid}/stat") as handle:
            fields = handle.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / TICKS

    def vehicle_state(self) -> dict | None:
        response = self.api.get("/api/vehicles/1")
        return response.json() if response.status_code == 200 else None


def start(folder: Path) -> Target:
    station_udp, vehicle_udp, http = free_port(), free_port(), free_port(socket.SOCK_STREAM)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1"}
    vehicle = subprocess.Popen(
        [sys.executable, "-m", "vehicle.cli", "sim", "--scene", str(DEFAULT_SCENE), "--mission", "search",
         "--sysid", "1", "--mavlink", f"udpin:127.0.0.1:{vehicle_udp}"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    station = subprocess.Popen(
        [sys.executable, "-m", "groundstation.cli", "serve", "--scene", str(DEFAULT_SCENE), "--port", str(http),
         "--token", TOKEN, "--record-dir", str(folder), "--mavlink", f"udpin:127.0.0.1:{station_udp}",
         "--mavlink", f"udpout:127.0.0.1:{vehicle_udp}"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    target = Target(station_udp, vehicle_udp, http, station, vehicle, folder)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            state = target.vehicle_state()
            if state and state["link"]["state"] == "ok" and state["position"]:
                return target
        except httpx.HTTPError:
            pass
        time.sleep(0.5)
    raise SystemExit("the station never showed the vehicle")


# ---- measuring while an attack runs ----------------------------------------------------------------------
@dataclass
class Watch:
    """Looks at the vehicle four times a second and sends it a command every half second, until stopped."""

    target: Target
    worst_age: float = 0.0
    looks: int = 0
    lost_looks: int = 0
    sent: int = 0
    answered: int = 0
    mode_changed: str = ""
    _stop: threading.Event = field(default_factory=threading.Event)

    def __enter__(self) -> Watch:
        self._threads = [threading.Thread(target=self._look, daemon=True),
                         threading.Thread(target=self._command, daemon=True)]
        for thread in self._threads:
            thread.start()
        return self

    def __exit__(self, *exc) -> None:
        time.sleep(2.0)  # and a little after
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=35)

    def _look(self) -> None:
        with httpx.Client(base_url=self.target.base, timeout=5.0) as client:
            while not self._stop.is_set():
                try:
                    state = client.get("/api/vehicles/1").json()
                    age = state["link"]["heartbeat_age"]
                    self.worst_age = max(self.worst_age, age if age is not None else 99.0)
                    if state["mode"] != "GUIDED":
                        self.mode_changed = state["mode"]
                except (httpx.HTTPError, ValueError, KeyError, TypeError):
                    self.lost_looks += 1
                self.looks += 1
                self._stop.wait(0.25)

    def _command(self) -> None:
        with httpx.Client(base_url=self.target.base, timeout=30.0,
                          headers={"Authorization": f"Bearer {TOKEN}"}) as client:
            while not self._stop.is_set():
                self.sent += 1
                try:
                    response = client.post("/api/vehicles/1/commands", json={"action": "set_mode", "mode": "GUIDED"})
                    if response.status_code == 200 and response.json()["result"] == "accepted":
                        self.answered += 1
                except httpx.HTTPError:
                    pass
                self._stop.wait(0.5)

    @property
    def tracked(self) -> bool:
        return self.worst_age < 3.0 and self.lost_looks == 0


# ---- MAVLink as an attacker sends it -----------------------------------------------------------------------
def packer(sysid: int, component: int = 1, version: int = 2):
    if version == 1:
        return mavlink1.MAVLink(None, srcSystem=sysid, srcComponent=component)
    return mavlink.MAVLink(None, srcSystem=sysid, srcComponent=component)


def udp_sender() -> socket.socket:
    sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sender.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4 << 20)
    return sender


def send_at(sender: socket.socket, port: int, packets: list[bytes], rate: float, seconds: float) -> int:
    """Send ``packets`` round-robin at ``rate`` per second for ``seconds``; how many went."""
    sent, started = 0, time.monotonic()
    address = ("127.0.0.1", port)
    while True:
        elapsed = time.monotonic() - started
        if elapsed >= seconds:
            return sent
        due = int(elapsed * rate)
        while sent < due:
            try:
                sender.sendto(packets[sent % len(packets)], address)
            except OSError:
                pass  # the receiver's buffer is full: that datagram is lost, as on a radio
            sent += 1
        time.sleep(0.0005)


def vehicle_beat(sysid: int, mode: int = 4) -> bytes:
    """A copter's heartbeat in ``sysid``'s name: an attacker's own fake vehicle, whose messages the station
    hears from the attacker's address (in the real vehicle's name they come from elsewhere, and are dropped)."""
    beat = mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                             mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, mode,
                                             mavlink.MAV_STATE_ACTIVE, 3)
    return beat.pack(packer(sysid))


def dropped_from_elsewhere(target: Target, sysid: int) -> int:
    """Messages the station dropped in ``sysid``'s name for coming from elsewhere than its heartbeat."""
    counts = target.api.get("/api/health").json()["link"]["from_elsewhere"]
    return next((c["messages"] for c in counts if c["sysid"] == sysid), 0)


def tunnel(sysid: int, kind: int, payload: bytes) -> bytes:
    message = mavlink.MAVLink_tunnel_message(0, 0, kind, len(payload), list(payload.ljust(PAYLOAD, b"\0")))
    return message.pack(packer(sysid, mavlink.MAV_COMP_ID_ONBOARD_COMPUTER))


def snapshot_packets(sysid: int, ident: int, size: int, rows: int, data: bytes, resolution: float = 5.0) -> list[bytes]:
    """A map snapshot (see vehicle/protocol/mapstream.py) claiming ``size`` cells a side at ``resolution``, its
    part ``rows`` square, with ``data`` as the compressed cells."""
    blob = struct.pack("<BHfffIHHHH", 1, size, resolution, -size / 10, -size / 10, 0, 0, 0, rows, rows) + data
    room = PAYLOAD - 6
    chunks = [blob[i:i + room] for i in range(0, len(blob), room)]
    return [tunnel(sysid, MAP_SNAPSHOT, struct.pack("<HHH", ident, index, len(chunks)) + chunk)
            for index, chunk in enumerate(chunks)]


# ---- the attacks: each returns (held, note) ---------------------------------------------------------------
def view_socket_elsewhere(target: Target):
    response = httpx.get(f"{target.base}/viz/", params={"websocket": "ws://evil.example:8080"})
    policy = httpx.get(f"{target.base}/viz/").headers.get("content-security-policy", "")
    script = next((p for p in policy.split(";") if p.strip().startswith("script-src")), "")
    held = response.status_code == 400 and "connect-src 'self'" in policy and "unsafe" not in script.replace(
        "'wasm-unsafe-eval'", "")
    return held, f"?websocket= answered {response.status_code}; policy connect-src 'self', no unsafe script"


def nan_attitude(target: Target):
    sender = udp_sender()
    dropped = dropped_from_elsewhere(target, 1)
    sender.sendto(vehicle_beat(77), ("127.0.0.1", target.station_udp))
    for sysid in (1, 77):
        nan = mavlink.MAVLink_attitude_message(1000, float("nan"), float("inf"), float("-inf"), 0, 0, 0)
        for _ in range(20):
            sender.sendto(nan.pack(packer(sysid)), ("127.0.0.1", target.station_udp))
    time.sleep(0.5)
    response = httpx.get(f"{target.base}/api/vehicles")

    def refuse(constant):
        raise ValueError(constant)

    try:
        json.loads(response.text, parse_constant=refuse)
        with ws_connect(f"{target.ws}/ws") as stream:
            json.loads(stream.recv(timeout=5), parse_constant=refuse)
        strict = True
    except ValueError:
        strict = False
    dropped = dropped_from_elsewhere(target, 1) - dropped
    return response.status_code == 200 and strict and dropped == 20, \
        f"/api/vehicles {response.status_code}, JSON strict: {strict}; vehicle 1's {dropped} dropped as from elsewhere"


def spoofed_position(target: Target):
    """Positions 5 km away and LAND heartbeats in the real vehicle's name, from another address: as its autopilot
    (component 1), and as another part of it (component 250)."""
    sender = udp_sender()
    dropped = dropped_from_elsewhere(target, 1)
    far = mavlink.MAVLink_global_position_int_message(1000, int(-35.32e7), int(149.17e7), 600000, 50000, 0, 0, 0, 0)
    other = mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                              mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 9, mavlink.MAV_STATE_ACTIVE, 3)
    as_autopilot = [far.pack(packer(1)), vehicle_beat(1, mode=9)]
    packets = (as_autopilot + [far.pack(packer(1, 250)), other.pack(packer(1, 250))]) * 25
    for packet in packets:
        sender.sendto(packet, ("127.0.0.1", target.station_udp))
        time.sleep(0.01)
    time.sleep(0.5)
    vehicle = next(v for v in target.api.get("/api/vehicles").json() if v["sysid"] == 1)
    where = vehicle["position"] or {"x": 0.0, "y": 0.0}
    dropped = dropped_from_elsewhere(target, 1) - dropped
    held = abs(where["x"]) < 1000 and abs(where["y"]) < 1000 and vehicle["mode"] != "LAND" and dropped == 50
    return held, (f"vehicle 1 shown at ({where['x']:.0f}, {where['y']:.0f}) in {vehicle['mode']}; "
                  f"{dropped} of the 50 as its autopilot dropped as from elsewhere")


def zlib_bomb(target: Target):
    squeezer = zlib.compressobj(9)
    zeros = bytes(1 << 20)
    data = b"".join(squeezer.compress(zeros) for _ in range(1024)) + squeezer.flush()  # 1 GB of cells
    packets = [vehicle_beat(79)] + snapshot_packets(79, 4242, 4000, 4000, data)  # the attacker's own vehicle
    sender = udp_sender()
    send_at(sender, target.station_udp, packets, 5000, len(packets) / 5000 + 0.5)
    time.sleep(1.0)
    alive = target.station.poll() is None and httpx.get(f"{target.base}/api/vehicles").status_code == 200
    return alive, f"{len(packets)} chunks, {len(data) // 1024} kB inflating to 1 GB"


def map_claim(side: int):
    def claim(target: Target):
        packets = snapshot_packets(79, 4000 + side % 1000, side, side, zlib.compress(b""))
        sender = udp_sender()
        for packet in [vehicle_beat(79)] + packets * 5:
            sender.sendto(packet, ("127.0.0.1", target.station_udp))
        time.sleep(1.0)
        response = httpx.get(f"{target.base}/api/vehicles")
        return response.status_code == 200, f"one {len(packets[0])}-byte packet; /api/vehicles {response.status_code}"

    claim.__name__ = f"map_claim_{side}"
    return claim


def two_byte_flood(port_of):
    def flood(target: Target):
        sent = send_at(udp_sender(), port_of(target), [b"\xfd\xff"], 200, 10.0)
        return True, f"{sent} datagrams at 200/s"

    return flood


def unauthenticated_gigabyte(target: Target):
    head = (f"POST /api/vehicles/1/commands HTTP/1.1\r\nHost: 127.0.0.1:{target.http}\r\n"
            "Content-Type: application/json\r\nContent-Length: 1000000000\r\n\r\n").encode()
    pushed, answer = 0, b""
    with socket.create_connection(("127.0.0.1", target.http), timeout=5) as raw:
        raw.sendall(head)
        raw.settimeout(0.001)
        chunk = bytes(1 << 20)
        try:
            while pushed < 1 << 30:
                raw.sendall(chunk)
                pushed += len(chunk)
                try:
                    answer = raw.recv(4096)
                    if answer:
                        break
                except TimeoutError:
                    continue
        except OSError:
            pass  # it closed on us
        if not answer:
            raw.settimeout(5)
            try:
                answer = raw.recv(4096)
            except OSError:
                pass
    return answer.startswith(b"HTTP/1.1 401"), f"answered {answer[:12].decode(errors='replace')} after " \
                                                f"{pushed >> 20} MB pushed"


def viewer_race(target: Target):
    camera = msgspec.msgpack.encode({
        "type": "ViewerCameraMessage", "wxyz": [1.0, 0, 0, 0], "position": [0.0, -10, 10], "fov": 1.0, "near": 0.01,
        "far": 1000.0, "image_height": 480, "image_width": 640, "look_at": [0.0, 0, 0], "up_direction": [0.0, 0, 1]})
    click = msgspec.msgpack.encode({
        "type": "ScenePointerMessage", "event_type": "click", "ray_origin": [2.0, 2.0, 30.0],
        "ray_direction": [0.0, 0.0, -1.0], "screen_pos": [[0.5, 0.5]], "modifier": None})
    import viser

    protocol = [f"viser-v{viser.__version__}"]
    with ws_connect(f"{target.ws}/ws?viewer={VIEWER}") as stream, \
            ws_connect(f"{target.ws}/viz", subprotocols=protocol, max_size=None) as intruder, \
            ws_connect(f"{target.ws}/viz/v/{VIEWER}", subprotocols=protocol, max_size=None) as view:
        intruder.send(camera)
        view.send(camera)
        time.sleep(2.0)
        intruder.send(click)
        stolen = 0
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline:
            try:
                stolen += json.loads(stream.recv(timeout=0.5)).get("type") == "target"
            except TimeoutError:
                pass
    return stolen == 0, f"{stolen} of the intruder's clicks reached the operator's page"


def foreign_origin_and_host(target: Target):
    refused = 0
    for path in ("/ws", "/viz"):
        try:
            ws_connect(f"{target.ws}{path}", origin="http://evil.example").close()
        except Exception:  # noqa: BLE001 - any refusal will do
            refused += 1
    host = httpx.get(f"{target.base}/api/recordings", headers={"Host": "rebind.evil.example"}).status_code
    return refused == 2 and host == 421, f"foreign Origin refused on {refused} of 2 sockets; foreign Host {host}"


BAD_BODIES = ['{"action": "takeoff", "altitude": NaN}', '{"action": "takeoff", "altitude": 1e300}',
              '{"action": "speed", "speed": Infinity}', '{"action": "goto", "x": 1e7, "y": 0}',
              '{"action": "goto", "x": NaN, "y": 0}', '{"action": "kill", "confirm": "yes"}']


def bad_numbers(target: Target):
    codes = [target.api.post("/api/vehicles/1/commands", content=body.encode(),
                             headers={"Content-Type": "application/json"}).status_code for body in BAD_BODIES]
    non_ascii = "Bearer \xff\xfe-token".encode("latin-1")  # raw bytes: httpx refuses to encode such a str
    bearer = httpx.get(f"{target.base}/api/auth", headers={"Authorization": non_ascii}).status_code
    seek = target.api.post("/api/replay/control", content=b'{"seek": NaN}',
                           headers={"Content-Type": "application/json"}).status_code
    items = "".join(f"{i}\t0\t3\t16\t0\t0\t0\t0\t-35.36\t149.16\t10\t1\n" for i in range(65536))
    wpl = target.api.put("/api/vehicles/1/mission", content=f"QGC WPL 110\n{items}".encode())
    codes += [bearer, seek, wpl.status_code]
    return all(400 <= code < 500 for code in codes), f"answers {sorted(set(codes))}"


def ws_churn(target: Target):
    answered = 0
    for n in range(4000):
        with ws_connect(f"{target.ws}/ws?viewer=churn-viewer-{n:08d}") as passing:
            if n % 100 == 0:  # a status frame comes every 0.25 s: wait for one now and then, not every time
                answered += json.loads(passing.recv(timeout=5))["type"] == "vehicles"
    return answered == 40, f"4000 /ws connections with new viewer ids, opened and closed ({answered} of 40 " \
                           "looked at answered)"


def fake_vehicles(target: Target):
    sender = udp_sender()
    for sysid in range(2, 256):  # every system id but the real vehicle's and this station's
        beat = mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                                 0, 0, mavlink.MAV_STATE_ACTIVE, 3)
        sender.sendto(beat.pack(packer(sysid)), ("127.0.0.1", target.station_udp))
    time.sleep(1.0)
    count = len(httpx.get(f"{target.base}/api/vehicles").json())
    return count <= MAX_VEHICLES, f"254 fake vehicles sent; the station holds {count} (at most {MAX_VEHICLES})"


def many_senders(target: Target):
    beat = mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3)
    packet = beat.pack(packer(200))
    for _ in range(28000):
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as one:
            one.sendto(packet, ("127.0.0.1", target.station_udp))
    cpu = target.cpu_seconds()
    time.sleep(5.0)
    share = (target.cpu_seconds() - cpu) / 5.0
    return share < 0.3, f"28,000 one-packet senders; the idle station then used {share:.0%} of a core"


def non_gcs_commands(target: Target):
    sender = udp_sender()
    mav = packer(42, 1)  # a system that never said it is a ground station
    for command, params in ((mavlink.MAV_CMD_COMPONENT_ARM_DISARM, (1, 0, 0, 0, 0, 0, 0)),
                            (mavlink.MAV_CMD_NAV_TAKEOFF, (0, 0, 0, 0, 0, 0, 5))):
        message = mavlink.MAVLink_command_long_message(1, 1, command, 0, *params)
        for _ in range(3):
            sender.sendto(message.pack(mav), ("127.0.0.1", target.vehicle_udp))
    time.sleep(2.0)
    state = target.vehicle_state()
    return not state["armed"], f"vehicle armed afterwards: {state['armed']}"


def garbage_flood(target: Target):
    rng = random.Random(7)
    pool: list[bytes] = []
    for i in range(3000):
        sysid = rng.randrange(2, 250)
        kind = i % 5
        if kind == 0:
            pool.append(rng.randbytes(rng.randrange(1, 300)))
        elif kind == 1:
            pool.append(b"\xfd" + rng.randbytes(rng.randrange(1, 40)))
        elif kind == 2:
            m = mavlink1.MAVLink_attitude_message(i, rng.random(), rng.random(), rng.random(), 0, 0, 0)
            pool.append(m.pack(packer(sysid, 1, version=1)))
        elif kind == 3:
            m = mavlink.MAVLink_global_position_int_message(i, rng.randrange(-900000000, 900000000),
                                                            rng.randrange(-1800000000, 1800000000), 0, 0, 0, 0, 0,
                                                            rng.randrange(0, 36000))
            pool.append(m.pack(packer(sysid)))
        else:
            m = mavlink.MAVLink_statustext_message(4, rng.randbytes(50).hex()[:50].encode())
            pool.append(m.pack(packer(sysid)))
    sent = send_at(udp_sender(), target.station_udp, pool, 20000, 10.0)
    return True, f"{sent} datagrams in 10 s ({sent / 10:,.0f}/s)"


def beside_a_stuck_recording(target: Target):
    """A pipe named like a recording (reading it blocks until someone writes) and a 200 MB recording copied
    into the record folder: the list and the status stream must answer at once."""
    folder = target.record_dir
    pipe, big = folder / "pipe.tlog", folder / "copied-in.tlog"
    os.mkfifo(pipe)
    session = max(folder.glob("session-*.tlog"), key=lambda p: p.stat().st_size).read_bytes()
    with open(big, "wb") as handle:
        while handle.tell() < 200 << 20:
            handle.write(session)
    try:
        started = time.monotonic()
        listed = target.api.get("/api/recordings", timeout=30).json()
        listing = time.monotonic() - started
        with ws_connect(f"{target.ws}/ws") as stream:
            started = time.monotonic()
            frames = sum(json.loads(stream.recv(timeout=5)).get("type") == "vehicles" for _ in range(8))
            streamed = time.monotonic() - started
        names = [r["name"] for r in listed]
    finally:
        pipe.unlink()
        big.unlink()
    held = listing < 1.0 and frames == 8 and streamed < 4.0 and "pipe.tlog" not in names
    return held, f"list answered in {listing * 1000:.0f} ms, pipe listed: {'pipe.tlog' in names}; 8 status frames " \
                 f"in {streamed:.1f} s"


def broadcast_system(target: Target):
    """A heartbeat from system 0, MAVLink's broadcast address, then a kill sent to it through the API."""
    beat = mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                             0, 0, mavlink.MAV_STATE_ACTIVE, 3)
    sender = udp_sender()
    for _ in range(5):
        sender.sendto(beat.pack(packer(0)), ("127.0.0.1", target.station_udp))
    time.sleep(1.0)
    listed = [v["sysid"] for v in target.api.get("/api/vehicles").json()]
    kill = target.api.post("/api/vehicles/0/commands", json={"action": "kill", "confirm": True}).status_code
    armed = (target.vehicle_state() or {}).get("armed")
    return 0 not in listed and kill == 404, f"system 0 listed: {0 in listed}; a kill to it answered {kill}; " \
                                            f"vehicle 1 armed: {armed}"


def viewer_id_pileup(target: Target):
    """Ten sockets asking for one viewer id at the same moment."""
    import viser

    async def race() -> list:
        return await asyncio.gather(*(websockets.connect(f"{target.ws}/viz/v/pileup-0123456789abcdef",
                                                         subprotocols=[f"viser-v{viser.__version__}"], max_size=None)
                                      for _ in range(10)), return_exceptions=True)

    async def attempt() -> int:
        opened = [c for c in await race() if not isinstance(c, Exception)]
        for connection in opened:
            await connection.close()
        return len(opened)

    opened = asyncio.run(attempt())
    return opened == 1, f"{opened} of 10 opened"


LAX_BODIES = ['{"action": "goto", "x": "5", "y": 0}', '{"action": "goto", "x": true, "y": 0}',
              '{"action": "speed", "speed": "2"}']
HOME_LINE = "QGC WPL 110\n0\t1\t0\t16\t0\t0\t0\t0\t-35.363261\t149.165230\t584\t1\n"
LAX_MISSIONS = ["1\t0\t3\t16\t0\t0\t0\t0\t-35.36\t149.16\t1e39\t1",
                "1\t0\t3\t16\t3.5e38\t0\t0\t0\t-35.36\t149.16\t10\t1",
                "1\t0\t3\t16\t0\t0\t0\t0\t1_0\t149.16\t10\t1",
                "1\t0\t200\t16\t0\t0\t0\t0\t-35.36\t149.16\t10\t1"]


def lax_numbers(target: Target):
    """Numbers as strings or true in commands; in missions a float32 overflow, '1_0' and a frame that is none."""
    codes = [target.api.post("/api/vehicles/1/commands", content=body.encode(),
                             headers={"Content-Type": "application/json"}).status_code for body in LAX_BODIES]
    codes += [target.api.put("/api/vehicles/1/mission", content=f"{HOME_LINE}{line}\n".encode()).status_code
              for line in LAX_MISSIONS]
    return all(code == 422 for code in codes), f"answers {sorted(set(codes))}"


def tiny_map_resolution(target: Target):
    """A vehicle whose map claims 1e-30 cells/m (a space of 1e31 m), then a goto 500 km away sent to it."""
    beat = mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                             0, 0, mavlink.MAV_STATE_ACTIVE, 3)
    sender = udp_sender()
    for packet in [beat.pack(packer(78))] + snapshot_packets(78, 4078, 10, 10, zlib.compress(bytes(100)), 1e-30):
        sender.sendto(packet, ("127.0.0.1", target.station_udp))
    time.sleep(1.0)
    goto = target.api.post("/api/vehicles/78/commands", json={"action": "goto", "x": 5e5, "y": 0.0}).status_code
    return goto == 422, f"a goto 500 km away answered {goto}"


ATTACKS = [
    ("view socket elsewhere (?websocket=, CSP)", view_socket_elsewhere),
    ("NaN in ATTITUDE (the vehicle's sysid and a foreign one)", nan_attitude),
    ("positions and LAND heartbeats in the vehicle's name from elsewhere", spoofed_position),
    ("zlib bomb in a map snapshot", zlib_bomb),
    ("map claiming 30,000 cells a side", map_claim(30000)),
    ("map claiming 65,535 cells a side", map_claim(65535)),
    ("two-byte datagrams at the station, 200/s", two_byte_flood(lambda t: t.station_udp)),
    ("two-byte datagrams at the vehicle, 200/s", two_byte_flood(lambda t: t.vehicle_udp)),
    ("1 GB POST without the token", unauthenticated_gigabyte),
    ("a client racing the operator's 3D view", viewer_race),
    ("foreign Origin and Host", foreign_origin_and_host),
    ("NaN, Infinity, 1e300, 'yes', non-ASCII token, 65,536 waypoints", bad_numbers),
    ("4,000 /ws connections with new viewer ids", ws_churn),
    ("a pipe and a 200 MB recording in the record folder", beside_a_stuck_recording),
    ("a vehicle at system 0 (the broadcast address), and a kill to it", broadcast_system),
    ("ten sockets claiming one viewer id at once", viewer_id_pileup),
    ("numbers as strings or true; missions with 1e39, '1_0', frame 200", lax_numbers),
    ("a map at 1e-30 cells/m, then a goto 500 km away", tiny_map_resolution),
    ("254 fake vehicles (every other system id)", fake_vehicles),
    ("28,000 one-packet UDP senders", many_senders),
    ("arm and take-off from a system that is no GCS", non_gcs_commands),
    ("20,000 messages/s of mixed garbage, MAVLink 1 and 2, 10 s", garbage_flood),
]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", action="append", default=[], help="run the attacks whose name has this text")
    parser.add_argument("--list", action="store_true", help="list the attacks")
    args = parser.parse_args()
    chosen = [(name, attack) for name, attack in ATTACKS
              if not args.only or any(text.lower() in name.lower() for text in args.only)]
    if args.list:
        print("\n".join(name for name, _ in ATTACKS))
        return
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        target = start(Path(folder))
        try:
            for name, attack in chosen:
                before = target.resident_mb()
                with Watch(target) as watch:
                    try:
                        held, note = attack(target)
                    except Exception as error:  # noqa: BLE001 - the bench reports it and goes on
                        held, note = False, f"the attack failed to run: {type(error).__name__}: {error}"
                alive = target.station.poll() is None and target.vehicle.poll() is None
                after = target.resident_mb() if alive else float("nan")
                held = held and alive and watch.tracked and watch.answered == watch.sent and after - before < 100
                rows.append([name, "yes" if held else "NO", "yes" if watch.tracked else
                             f"NO (worst age {watch.worst_age:.1f} s)", f"{watch.answered}/{watch.sent}",
                             f"{before:.0f} -> {after:.0f}",
                             note + ("" if alive else "; a process died") +
                             (f"; the vehicle left GUIDED for {watch.mode_changed}" if watch.mode_changed else "")])
                print(f"{name}: {'held' if held else 'NOT HELD'}", file=sys.stderr, flush=True)
                if not alive:
                    break
        finally:
            for process in (target.station, target.vehicle):
                process.terminate()
                process.wait(timeout=10)
    print(table(["attack", "held", "vehicle tracked", "commands answered", "station MB before -> after", "note"],
                rows))
    print(f"\n{sum(r[1] == 'yes' for r in rows)} of {len(rows)} held; {code_state()}")


if __name__ == "__main__":
    main()
