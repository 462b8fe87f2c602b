"""MAVLink links that hold against broken and hostile peers: one factory for every transport.

``connect(url)`` gives a link with pymavlink's face (``recv_msg()``,
``write(bytes)``, ``mav.send(message)``, ``close()``) for the URLs of
``mavutil.mavlink_connection``, with two differences that matter when peers
cannot be trusted:

- UDP (``udpin:`` listens, ``udpout:`` sends to one address; ``udp:`` is
  ``udpin:``) parses every datagram on its own and keeps one parser per sender.
  pymavlink feeds all senders' datagrams into one byte stream, so a stray
  two-byte datagram from anyone desynchronises everyone; here it spoils only
  itself. Each message carries ``_peer``, the address it came from, so a reply
  goes back there; senders are forgotten when idle (and the oldest when there
  are too many), so a flood of one-packet senders neither grows without bound
  nor is sent our traffic.
- Streams (``tcp:``, serial ports) never block and never give up: a peer that
  is not up yet, or that drops, is retried with a growing pause while the link
  reports itself down (``up``, ``error``). A serial port is ``PATH[,BAUD]``
  and opened as one whatever its name: pymavlink takes a name with a colon
  for a UDP address, and Linux's stable names for a USB autopilot
  (``/dev/serial/by-path/pci-0000:00:14.0-usb-0:2:1.0``) have them.

With a signing key (``vehicle.protocol.signing``) a link signs what it sends
and checks what it receives, one table of stream timestamps for all its
senders: what the key's policy refuses (unsigned or wrongly signed messages
where signing is required, replays always) is dropped here and counted per
system id (``refused``); what passes carries ``_verified`` (True: signed with
the key).

No maintained library does either (pymavlink's own UDP links are shared-stream
by design), hence this module.
"""

from __future__ import annotations

import os
import re
import socket
import time
from collections import Counter, OrderedDict, deque

from vehicle.protocol import signing
from vehicle.protocol.mav import mavlink, mavutil

MAX_SENDERS = 64  # UDP peers remembered (parsers, and where broadcasts go)
SENDER_IDLE = 30.0  # s after which a silent UDP peer gets no more broadcasts and is forgotten
MAX_DATAGRAMS = 2000  # read at most this many per call, so one flood cannot stall the caller's loop
MAX_READY = 2000  # parsed messages waiting, at most, before another datagram is read: a datagram of 64 KB
# holds thousands of small messages, and a flood of them would fill memory faster than they are handled
RETRY = (0.5, 10.0)  # s: first and longest pause between attempts to open a stream
UDP_KINDS = frozenset({"udpin", "udp", "udpout"})  # parsed here per datagram and per sender
TCP_KINDS = frozenset({"tcp", "tcpin"})
OTHER_KINDS = frozenset({"udpbcast", "mcast", "ws", "wss", "wsserver"})  # pymavlink's other links, as it opens them
_SCHEME = re.compile(r"[A-Za-z][A-Za-z0-9+.-]*")  # a word before a colon: a kind of link, not a serial port's path
DEFAULT_BAUD = 115200  # pymavlink's
FASTEST_BAUD = 20_000_000  # bits/s: faster than any serial port a MAVLink device has (a larger one overflowed)


def connect(url: str, source_system: int = 255, source_component: int = 0, key: bytes | None = None,
            require_signed: bool = True) -> UdpLink | StreamLink:
    """A link for a pymavlink-style URL (see the module's docstring); with ``key``, signed both ways
    (``require_signed``: refuse what is not signed with it, as a vehicle does)."""
    kind = check_url(url)
    if kind in UDP_KINDS:
        host, _, port = url.partition(":")[2].rpartition(":")
        link = UdpLink(url, host, int(port), listen=kind != "udpout", source_system=source_system,
                       source_component=source_component)
    else:
        link = StreamLink(url, source_system, source_component)
    if key is not None:
        link.verifier = signing.Verifier(key, require_signed)
        signing.sign_outgoing(link.mav, key)
    return link


def check_url(url: str) -> str:
    """The kind of link ``url`` names (``udpin``, ``tcp``, ... or ``serial``) if ``connect`` can open it (now or,
    for a stream, once its peer is up); ValueError saying why not: a UDP or TCP URL without a host and a port
    from 1 to 65535, a serial port without a path or a baud rate, or a kind of link pymavlink does not know."""
    kind, colon, rest = url.partition(":")
    if kind in UDP_KINDS | TCP_KINDS:
        host, _, port = rest.rpartition(":")
        if not host or not port.isdigit() or not 0 < int(port) < 65536:
            transport = "a TCP" if kind in TCP_KINDS else "a UDP"
            raise ValueError(f"{transport} link is {kind}:HOST:PORT with a port from 1 to 65535, not {url!r}")
        return kind
    if kind in OTHER_KINDS:
        return kind
    if colon and _SCHEME.fullmatch(kind):
        raise ValueError(f"not a MAVLink link: {url!r} (udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT, "
                         "tcpin:HOST:PORT or a serial port such as /dev/ttyUSB0,57600)")
    serial_port(url)
    return "serial"


def serial_port(url: str) -> tuple[str, int]:
    """(device, baud) of a serial port's URL, ``PATH[,BAUD]`` (a path that exists with its comma is a path);
    ValueError if there is no path, or the baud rate is not a whole number from 1 to FASTEST_BAUD."""
    device, comma, baud = url.rpartition(",")
    if not comma or os.path.exists(url):
        device, baud = url, str(DEFAULT_BAUD)
    if not device or not baud.isdigit() or not 0 < int(baud) <= FASTEST_BAUD:
        raise ValueError(f"a serial port is PATH or PATH,BAUD with a baud rate such as 57600, not {url!r}")
    return device, int(baud)


class LinkWatch:
    """Says when a link goes down or comes back (a serial port unplugged, a TCP peer gone). A link retries in
    silence, so a program that did not say so would look to its user as if all were well."""

    def __init__(self, links: list):
        self.links = links
        self._down: dict[str, str] = {}  # url -> why, for the links down when last looked at

    def changes(self) -> list[str]:
        """A line for each link that went down or came back since the last call (a link down from the start
        counts as going down)."""
        lines = []
        for link in self.links:
            why = "" if link.up else link.error
            if why != self._down.get(link.url, ""):
                lines.append(f"link {link.url} down ({why}); retrying" if why else f"link {link.url} up again")
                self._down[link.url] = why
        return lines


class _Signed:
    """What both kinds of link do with a signing key: check each message received, drop what may not pass."""

    verifier: signing.Verifier | None = None
    refused: Counter  # system id -> messages dropped for their signature

    def _admit(self, message) -> bool:
        if self.verifier is None or message.get_type() == "BAD_DATA":
            return True
        verdict = self.verifier.check(message)
        message._verified = verdict == signing.SIGNED
        if self.verifier.admits(message, verdict):
            return True
        self.refused[message.get_srcSystem()] += 1
        return False


def _interface_towards(host: str, port: int) -> str:
    """The address of the interface that reaches ``host`` (loopback for a peer on this machine): a ``udpout``
    port answers on that one interface, not on every one (0.0.0.0 only where no route is known)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        try:
            probe.connect((host, port))
            return probe.getsockname()[0]
        except OSError:
            return "0.0.0.0"


def _parser() -> mavlink.MAVLink:
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    return parser


def _restart(parser: mavlink.MAVLink) -> None:
    """Forget any partial packet: a datagram holds whole packets, never the rest of an earlier one."""
    parser.buf = bytearray()
    parser.buf_index = 0
    parser.expected_length = mavlink.HEADER_LEN_V1 + 2
    parser.have_prefix_error = False


class UdpLink(_Signed):
    """A UDP socket, parsed per datagram and per sender (see the module's docstring)."""

    def __init__(self, url: str, host: str, port: int, listen: bool, source_system: int = 255,
                 source_component: int = 0):
        self.url = url
        self.listen = listen
        self.port = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        if listen:  # alone on its port: with SO_REUSEADDR (pymavlink's habit) a second program took the traffic
            try:
                self.port.bind((host, port))
            except OSError as error:
                self.port.close()
                raise OSError(error.errno, f"cannot listen on {url}: {error.strerror}") from None
            self.destination = None
        else:
            self.port.bind((_interface_towards(host, port), 0))
            self.destination = (host, port)
        self.port.setblocking(False)
        self.mav = mavlink.MAVLink(self, srcSystem=source_system, srcComponent=source_component)  # writes here
        self.senders: OrderedDict[tuple, list] = OrderedDict()  # address -> [parser, last heard (monotonic)]
        self.stats = {"datagrams": 0, "bad": 0, "senders forgotten": 0}
        self.refused = Counter()
        self._ready: deque = deque()
        self.up = True
        self.error = ""

    def recv_msg(self):
        """The next message from any sender (``_peer`` set to its address), or None if none is waiting."""
        if not self._ready:
            self._read()
        return self._ready.popleft() if self._ready else None

    def _read(self) -> None:
        now = time.monotonic()
        for _ in range(MAX_DATAGRAMS):
            if len(self._ready) >= MAX_READY:
                return  # the rest wait in the socket's buffer, where the kernel drops what does not fit
            try:
                data, address = self.port.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as error:  # e.g. an ICMP port-unreachable for an earlier send
                self.error = str(error)
                return
            self.stats["datagrams"] += 1
            entry = self.senders.pop(address, None) or [_parser(), now]
            entry[1] = now
            self.senders[address] = entry  # most recently heard last
            parser = entry[0]
            _restart(parser)
            try:
                messages = parser.parse_buffer(data) or []
            except Exception:  # noqa: BLE001 - pymavlink raises many kinds on hostile bytes
                messages = []
                self.stats["bad"] += 1
            for message in messages:
                if message.get_type() == "BAD_DATA":
                    self.stats["bad"] += 1
                elif not self._admit(message):
                    continue
                message._peer = address
                self._ready.append(message)
            self._forget(now)

    def _forget(self, now: float) -> None:
        while self.senders:
            address, (_, heard) = next(iter(self.senders.items()))
            if len(self.senders) <= MAX_SENDERS and now - heard <= SENDER_IDLE:
                return
            del self.senders[address]
            self.stats["senders forgotten"] += 1

    def peers(self) -> list[tuple]:
        """Where a message for everyone goes: the one address of ``udpout``, or every sender heard lately."""
        if self.destination is not None:
            return [self.destination]
        now = time.monotonic()
        return [address for address, (_, heard) in self.senders.items() if now - heard <= SENDER_IDLE]

    def write(self, buf: bytes, peer: tuple | None = None) -> None:
        for address in [peer] if peer is not None else self.peers():
            try:
                self.port.sendto(bytes(buf), address)
            except OSError as error:
                self.error = str(error)

    def close(self) -> None:
        self.port.close()


class StreamLink(_Signed):
    """pymavlink's TCP or serial link, opened without blocking and reopened whenever it drops."""

    def __init__(self, url: str, source_system: int = 255, source_component: int = 0):
        self.url = url
        self.source = (source_system, source_component)
        self.mav = mavlink.MAVLink(self, srcSystem=source_system, srcComponent=source_component)  # writes here
        self.connection = None
        self.refused = Counter()
        self.up = False
        self.error = "not connected yet"
        self.failures = 0
        self._retry_at = 0.0
        self._open()

    def _open(self) -> None:
        if time.monotonic() < self._retry_at:
            return
        source_system, source_component = self.source
        try:
            if check_url(self.url) != "serial":
                self.connection = mavutil.mavlink_connection(self.url, source_system=source_system,
                                                             source_component=source_component, autoreconnect=True,
                                                             retries=0)
            else:  # by name: pymavlink's factory would take a path with a colon for a UDP address
                device, baud = serial_port(self.url)
                self.connection = mavutil.mavserial(device, baud=baud, source_system=source_system,
                                                    source_component=source_component, autoreconnect=True)
        except (OSError, ValueError) as error:
            self._down(error)
            return
        self.connection.mav.robust_parsing = True
        self.up, self.error, self.failures = True, "", 0

    def _down(self, error: BaseException) -> None:
        if self.connection is not None:
            try:
                self.connection.close()
            except Exception:  # noqa: BLE001 - pymavlink's close fails on the socket a failed reconnect dropped
                pass
        self.connection, self.up, self.error = None, False, f"{type(error).__name__}: {error}"
        self.failures += 1
        self._retry_at = time.monotonic() + min(RETRY[1], RETRY[0] * 2 ** min(self.failures - 1, 8))

    def recv_msg(self):
        if self.connection is None:
            self._open()
            if self.connection is None:
                return None
        try:
            for _ in range(MAX_DATAGRAMS):
                message = self.connection.recv_msg()
                if message is None or self._admit(message):
                    return message
            return None
        except Exception as error:  # noqa: BLE001 - a dropped peer shows as many kinds; retry it later
            self._down(error)
            return None

    def write(self, buf: bytes, peer=None) -> None:
        if self.connection is None:
            return
        try:
            self.connection.write(bytes(buf))
        except Exception as error:  # noqa: BLE001 - as above
            self._down(error)

    def close(self) -> None:
        if self.connection is not None:
            self.connection.close()
