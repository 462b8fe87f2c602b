"""Links that hold against hostile peers (vehicle.protocol.links), on real sockets: UDP parsed per datagram and per
sender, bounded in senders and in datagrams per call; streams that report themselves down and come back."""

from __future__ import annotations

import socket

import pytest
from harness import free_tcp_port, free_udp_port, wait_wall

from vehicle.protocol import links, signing
from vehicle.protocol.mav import mavlink


class Sender:
    """A peer on its own UDP socket, sending MAVLink as ``sysid``: raw bytes (half packets, garbage before a
    packet) to the link layer, which these tests check; not a vehicle (``mavlink_peer.FakeVehicle`` is one)."""

    def __init__(self, port: int, sysid: int):
        self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.socket.bind(("127.0.0.1", 0))
        self.socket.settimeout(5)
        self.address = self.socket.getsockname()
        self.target = ("127.0.0.1", port)
        self.mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=1)

    def packet(self, text: str = "hello") -> bytes:
        return self.mav.statustext_encode(6, text.encode()).pack(self.mav)

    def send(self, data: bytes) -> None:
        self.socket.sendto(data, self.target)

    def close(self) -> None:
        self.socket.close()


@pytest.fixture
def listening():
    port = free_udp_port()
    link = links.connect(f"udpin:127.0.0.1:{port}", 255, 190)
    yield link, port
    link.close()


def receive(link, count: int, what: str = "messages") -> list:
    got = []

    def enough():
        while (message := link.recv_msg()) is not None:
            got.append(message)
        return len(got) >= count

    wait_wall(enough, 5, what)
    return got


KEY = bytes(range(32))


class Clock:
    """``links.time`` stand-in: monotonic() is what the test says it is."""

    def __init__(self, now: float = 1000.0):
        self.now = now

    def monotonic(self) -> float:
        return self.now


def heard_as(socket_: socket.socket) -> tuple[int, int]:
    """(system, component) of the first packet the socket receives."""
    data, _ = socket_.recvfrom(65535)
    message = mavlink.MAVLink(None).parse_buffer(data)[0]
    return message.get_srcSystem(), message.get_srcComponent()


# ---- UDP: each datagram on its own, senders bounded ------------------------------------------
def test_a_stray_partial_datagram_spoils_neither_another_sender_nor_the_next_datagram(listening):
    """pymavlink runs every sender's bytes into one stream: half a packet from anyone swallowed the next
    packet from everyone. Here each datagram is parsed on its own, per sender."""
    link, port = listening
    a, b = Sender(port, 1), Sender(port, 2)
    try:
        a.send(a.packet("first")[:7])  # half a packet, then nothing more of it
        b.send(b.packet("from b"))
        a.send(a.packet("second"))
        got = receive(link, 2)
    finally:
        a.close()
        b.close()
    texts = sorted((m.get_srcSystem(), m.text) for m in got if m.get_type() == "STATUSTEXT")
    assert texts == [(1, "second"), (2, "from b")]
    assert {m._peer for m in got if m.get_type() == "STATUSTEXT"} == {a.address, b.address}


def test_garbage_is_counted_and_the_good_packets_beside_it_still_arrive(listening):
    link, port = listening
    a = Sender(port, 1)
    try:
        a.send(b"\xfd\x09" + b"\xff" * 40)  # a MAVLink 2 start followed by nonsense
        a.send(b"\x00\x01\x02")
        a.send(a.packet("after the garbage"))
        got = receive(link, 1)
    finally:
        a.close()
    assert [m.text for m in got if m.get_type() == "STATUSTEXT"] == ["after the garbage"]
    assert link.stats["datagrams"] == 3
    assert link.stats["bad"] >= 1


def test_every_garbage_datagram_is_counted_once_and_a_packet_behind_garbage_still_arrives(listening):
    """Each datagram starts parsing afresh (no prefix error carried over to hide the next one's garbage), and
    the parser is robust: bytes that are no packet are skipped, the packet after them in the datagram read."""
    link, port = listening
    a = Sender(port, 1)
    try:
        for _ in range(3):
            a.send(b"\x00\x01\x02\x03")
        a.send(b"\x00\x01" + a.packet("behind garbage"))
        got = []
        wait_wall(lambda: got.extend(iter(link.recv_msg, None)) or any(m.get_type() == "STATUSTEXT" for m in got), 5)
        assert [m.text for m in got if m.get_type() != "BAD_DATA"] == ["behind garbage"]
        assert link.stats == {"datagrams": 4, "bad": 4, "senders forgotten": 0}
        assert sum(m.get_type() == "BAD_DATA" for m in got) == 4  # handed on too, with where they came from
        assert all(m._peer == a.address for m in got)
    finally:
        a.close()


def test_a_datagram_the_parser_chokes_on_counts_as_bad_and_spoils_nothing_else(listening, monkeypatch):
    link, port = listening
    choking = links._parser

    def parser():
        made = choking()
        real = made.parse_buffer
        made.parse_buffer = lambda data: real(data) if data != b"boom" else 1 / 0
        return made

    monkeypatch.setattr(links, "_parser", parser)
    a = Sender(port, 1)
    try:
        a.send(b"boom")
        a.send(a.packet("after"))
        a.send(b"boom")
        a.send(a.packet("again"))
        got = receive(link, 2)
        assert [m.text for m in got] == ["after", "again"]
        assert link.stats["bad"] == 2 and link.stats["datagrams"] == 4  # each choke counted
    finally:
        a.close()


def test_a_datagram_too_short_for_a_header_is_neither_a_message_nor_bad_data(listening):
    """Two bytes that begin like a packet: nothing to parse yet, and since a datagram holds whole packets,
    nothing carried into the next one either."""
    link, port = listening
    a = Sender(port, 1)
    try:
        a.send(bytes([mavlink.PROTOCOL_MARKER_V2, 9]))
        a.send(a.packet("next"))
        got = receive(link, 1)
        assert [m.text for m in got] == ["next"] and link.stats["bad"] == 0 and link.stats["datagrams"] == 2
    finally:
        a.close()


def test_replies_go_to_their_sender_and_broadcasts_to_every_sender_heard(listening):
    link, port = listening
    a, b = Sender(port, 1), Sender(port, 2)
    try:
        a.send(a.packet())
        b.send(b.packet())
        got = receive(link, 2)
        assert sorted(link.peers()) == sorted([a.address, b.address])
        from_a = next(m for m in got if m.get_srcSystem() == 1)
        link.write(b"to a", from_a._peer)
        link.write(b"to all")
        assert a.socket.recvfrom(100)[0] == b"to a"
        assert a.socket.recvfrom(100)[0] == b"to all"
        assert b.socket.recvfrom(100)[0] == b"to all"
    finally:
        a.close()
        b.close()


def test_a_flood_of_senders_is_bounded_and_the_oldest_are_forgotten(listening):
    link, port = listening
    senders = [Sender(port, 1 + i % 250) for i in range(links.MAX_SENDERS + 6)]
    try:
        for sender in senders:
            sender.send(sender.packet())
        receive(link, len(senders))
        assert len(link.senders) == links.MAX_SENDERS
        assert link.stats["senders forgotten"] == 6
        assert set(link.peers()) == {s.address for s in senders[6:]}  # the six heard first are gone
    finally:
        for sender in senders:
            sender.close()


def test_the_sender_forgotten_first_is_the_one_heard_least_recently(listening, monkeypatch):
    link, port = listening
    monkeypatch.setattr(links, "MAX_SENDERS", 2)
    a, b, c = Sender(port, 1), Sender(port, 2), Sender(port, 3)
    try:
        for sender in (a, b, a):
            sender.send(sender.packet())
            receive(link, 1)
        c.send(c.packet())
        receive(link, 1)
        assert list(link.senders) == [a.address, c.address]  # b was heard before a's second packet
    finally:
        for sender in (a, b, c):
            sender.close()


def test_idle_senders_get_no_broadcasts_and_are_forgotten(listening, monkeypatch):
    link, port = listening
    monkeypatch.setattr(links, "SENDER_IDLE", 0.3)
    a, b = Sender(port, 1), Sender(port, 2)
    try:
        a.send(a.packet())
        receive(link, 1)
        wait_wall(lambda: not link.peers(), 5, "a idle")  # nothing from a for SENDER_IDLE
        assert a.address in link.senders  # not forgotten yet: that happens when the link next reads
        b.send(b.packet())
        receive(link, 1)
        assert list(link.senders) == [b.address] and link.peers() == [b.address]
        assert link.stats["senders forgotten"] == 1
    finally:
        a.close()
        b.close()


def test_a_sender_is_a_peer_until_exactly_sender_idle_seconds_of_silence(listening, monkeypatch):
    link, port = listening
    clock = Clock()
    monkeypatch.setattr(links, "time", clock)
    a = Sender(port, 1)
    try:
        a.send(a.packet())
        receive(link, 1)
        clock.now += links.SENDER_IDLE
        assert link.peers() == [a.address]
        link._forget(clock.now)
        assert a.address in link.senders
        clock.now += 1e-6
        assert link.peers() == []
        link._forget(clock.now)
        assert link.senders == {} and link.stats["senders forgotten"] == 1
    finally:
        a.close()


def test_one_call_reads_a_bounded_number_of_datagrams(listening, monkeypatch):
    """A flood cannot keep the caller's loop in one recv_msg(): it reads at most MAX_DATAGRAMS per call."""
    link, port = listening
    monkeypatch.setattr(links, "MAX_DATAGRAMS", 10)
    a = Sender(port, 1)
    try:
        for i in range(25):
            a.send(a.packet(f"number {i}"))
        wait_wall(lambda: link.recv_msg() is not None, 5, "the first datagram")
        assert link.stats["datagrams"] == 10
        got = receive(link, 24, "the rest")
    finally:
        a.close()
    assert link.stats["datagrams"] == 25
    assert [m.text for m in got] == [f"number {i}" for i in range(1, 25)]  # in order, none lost


def test_datagrams_packed_with_messages_wait_in_the_socket_while_many_are_parsed(listening, monkeypatch):
    """A 64 KB datagram holds thousands of small messages: read by the thousand they filled hundreds of MB at
    the station. No datagram is read while MAX_READY parsed messages wait; none is lost meanwhile."""
    link, port = listening
    monkeypatch.setattr(links, "MAX_READY", 50)
    a = Sender(port, 1)
    try:
        for i in range(4):
            a.send(b"".join(a.packet(f"datagram {i} message {k}") for k in range(40)))
        wait_wall(lambda: link.recv_msg() is not None, 5, "the first datagram")
        assert link.stats["datagrams"] == 2  # 80 parsed: the third waits
        got = receive(link, 159, "the rest")
    finally:
        a.close()
    assert link.stats["datagrams"] == 4
    assert [m.text for m in got] == [f"datagram {i} message {k}" for i in range(4) for k in range(40)][1:]


def test_socket_errors_are_reported_not_raised(listening):
    link, _port = listening
    link.port.close()
    assert link.recv_msg() is None
    assert "Bad file descriptor" in link.error
    link.error = ""
    link.write(b"x", ("127.0.0.1", 9))
    assert "Bad file descriptor" in link.error


# ---- link URLs, and what each kind opens -----------------------------------------------------
@pytest.mark.parametrize("url", ["udpin:127.0.0.1", "udpout::14550", "udp:host:port",
                                 "udpin:127.0.0.1:70000", "udpout:127.0.0.1:0",  # a socket's OverflowError before
                                 "tcp:127.0.0.1", "tcpin::5760", "tcp:host:port"])  # retried for ever before
def test_a_udp_or_tcp_url_without_host_and_port_is_refused(url):
    with pytest.raises(ValueError, match="HOST:PORT"):
        links.connect(url)


@pytest.mark.parametrize("url", ["bogus://", "http://127.0.0.1:14550", "udp-in:127.0.0.1:14550"])
def test_a_url_that_names_no_kind_of_link_is_refused_saying_which_are(url):
    """Anything not UDP or TCP went to pymavlink as a serial port that never opened: retried for ever (the
    station showed the link down) or, for an agent, an error only once its connect timeout ran out."""
    with pytest.raises(ValueError, match="not a MAVLink link: .* or a serial port such as /dev/ttyUSB0,57600"):
        links.connect(url)


@pytest.mark.parametrize("url", ["/dev/ttyUSB0,fast", "/dev/ttyUSB0,0", "/dev/ttyUSB0,", "COM3,-9600",
                                 "/dev/ttyUSB0,4294967296", ",57600", ""])  # an OverflowError, no path
def test_a_serial_port_with_a_baud_rate_that_is_no_number_is_refused(url):
    with pytest.raises(ValueError, match="a serial port is PATH or PATH,BAUD with a baud rate such as 57600"):
        links.connect(url)


@pytest.mark.parametrize("url", ["/dev/ttyNOPE0,57600", "COM9", "tcpin:127.0.0.1:{port}"])
def test_a_serial_port_or_a_tcp_listener_is_a_link_even_before_it_opens(url):
    link = links.connect(url.format(port=free_tcp_port()))
    try:
        assert isinstance(link, links.StreamLink)
    finally:
        link.close()


@pytest.mark.parametrize(("ids", "expected"), [((), (255, 0)), ((42, 191), (42, 191))])
def test_a_udpout_link_sends_to_its_one_address_as_the_system_and_component_it_is_given(ids, expected):
    receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    receiver.bind(("127.0.0.1", 0))
    receiver.settimeout(5)
    port = receiver.getsockname()[1]
    link = links.connect(f"udpout:127.0.0.1:{port}", *ids)
    try:
        assert (link.listen, link.destination, link.url) == (False, ("127.0.0.1", port), f"udpout:127.0.0.1:{port}")
        assert link.peers() == [("127.0.0.1", port)]  # before hearing anyone
        assert link.port.getsockname()[0] == "127.0.0.1"  # the interface towards the peer, not every one
        link.mav.heartbeat_send(6, 8, 0, 0, 0)
        assert heard_as(receiver) == expected
    finally:
        link.close()
        receiver.close()


@pytest.mark.parametrize("kind", ["udpin", "udp"])
def test_udpin_and_udp_listen_on_the_address_they_name(kind):
    port = free_udp_port()
    link = links.connect(f"{kind}:127.0.0.1:{port}")
    try:
        assert (link.listen, link.destination) == (True, None)
        assert link.port.getsockname() == ("127.0.0.1", port)
        assert link.peers() == [] and link.up and link.error == ""
    finally:
        link.close()


def test_a_second_listener_on_a_udp_port_is_refused_and_the_first_keeps_hearing():
    """With SO_REUSEADDR (pymavlink's habit) a second station on udpin:14550 bound too, and took every datagram
    from the first, which went on showing its vehicles as lost."""
    port = free_udp_port()
    first = links.connect(f"udpin:127.0.0.1:{port}")
    sender = links.connect(f"udpout:127.0.0.1:{port}", source_system=4, source_component=1)
    try:
        with pytest.raises(OSError, match=f"cannot listen on udpin:127.0.0.1:{port}"):
            links.connect(f"udpin:127.0.0.1:{port}")
        sender.mav.statustext_send(6, b"still here")
        assert receive(first, 1)[0].text == "still here"
    finally:
        first.close()
        sender.close()


@pytest.mark.parametrize("name", ["its own", "a stable name with colons"])
def test_a_serial_port_carries_mavlink_both_ways_at_its_baud_rate(name, tmp_path):
    """A telemetry radio or a USB autopilot is a serial port: here a pseudo-terminal, the same to pyserial (the
    link crashed with ModuleNotFoundError while pyserial was not a dependency). Linux's stable names for a USB
    port have colons, and pymavlink's factory took such a name for a UDP address ("invalid literal for int()")."""
    import os
    import termios
    import tty

    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    termios.tcflush(slave, termios.TCIOFLUSH)
    os.set_blocking(master, False)
    device = os.ttyname(slave)
    if name != "its own":
        device = tmp_path / "pci-0000:00:14.0-usb-0:2:1.0-port0"
        device.symlink_to(os.ttyname(slave))
    link = links.connect(f"{device},57600", source_system=9, source_component=1)
    try:
        assert link.up, link.error
        assert termios.tcgetattr(slave)[4:6] == [termios.B57600] * 2  # input and output speed
        link.mav.statustext_send(6, b"out of the port")
        parser = mavlink.MAVLink(None)

        def arrived():
            try:
                return parser.parse_buffer(os.read(master, 4096))
            except BlockingIOError:
                return None

        got = wait_wall(arrived, 5, "bytes on the other end")
        assert got[0].text == "out of the port" and got[0].get_srcSystem() == 9
        peer = mavlink.MAVLink(None, srcSystem=3, srcComponent=1)
        os.write(master, peer.statustext_encode(6, b"into the port").pack(peer))
        assert receive(link, 1)[0].text == "into the port"
    finally:
        link.close()
        os.close(master)
        os.close(slave)


# ---- signed links ----------------------------------------------------------------------------
def test_a_signed_link_drops_an_unsigned_packet_and_keeps_the_signed_one_behind_it():
    port = free_udp_port()
    link = links.connect(f"udpin:127.0.0.1:{port}", key=KEY)
    a = Sender(port, 4)
    signer = mavlink.MAVLink(None, srcSystem=4, srcComponent=1)
    signing.sign_outgoing(signer, KEY)
    try:
        a.send(a.packet("unsigned") + signer.statustext_encode(6, b"signed").pack(signer))
        got = receive(link, 1)
        assert [(m.text, m._verified) for m in got] == [("signed", True)]
        assert link.refused == {4: 1}
    finally:
        a.close()
        link.close()


def test_a_link_with_a_key_signs_what_it_sends_and_by_default_requires_signatures():
    receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    receiver.bind(("127.0.0.1", 0))
    receiver.settimeout(5)
    link = links.connect(f"udpout:127.0.0.1:{receiver.getsockname()[1]}", 9, 1, key=KEY)
    try:
        assert link.verifier.key == KEY and link.verifier.require is True
        link.mav.heartbeat_send(6, 8, 0, 0, 0)
        data, _ = receiver.recvfrom(65535)
        assert signing.Verifier(KEY).check(mavlink.MAVLink(None).parse_buffer(data)[0]) == signing.SIGNED
    finally:
        link.close()
        receiver.close()
    lax = links.connect(f"udpin:127.0.0.1:{free_udp_port()}", key=KEY, require_signed=False)
    try:
        assert lax.verifier.require is False
    finally:
        lax.close()


# ---- streams ---------------------------------------------------------------------------------
@pytest.fixture
def clock(monkeypatch):
    clock = Clock()
    monkeypatch.setattr(links, "time", clock)
    return clock


def test_a_stream_retries_after_0_5_1_2_4_8_then_every_10_seconds(clock):
    port = free_tcp_port()  # nobody listens
    link = links.connect(f"tcp:127.0.0.1:{port}")
    try:
        pauses = []
        for failures in range(1, 8):
            assert link.failures == failures and not link.up and link.connection is None
            assert link.error.startswith("ConnectionRefusedError: ")
            pauses.append(link._retry_at - clock.now)
            clock.now = link._retry_at - 1e-6
            link._open()
            assert link.failures == failures  # not yet
            clock.now = link._retry_at  # exactly when it is due
            link._open()
        assert pauses == [0.5, 1.0, 2.0, 4.0, 8.0, 10.0, 10.0]
    finally:
        link.close()


def test_opening_a_stream_never_waits(clock):
    import time

    started = time.monotonic()
    link = links.connect(f"tcp:127.0.0.1:{free_tcp_port()}")
    assert time.monotonic() - started < 0.5 and link.failures == 1
    link.close()


def test_a_stream_that_is_not_up_yet_reports_itself_down_then_comes_up(monkeypatch):
    monkeypatch.setattr(links, "RETRY", (0.05, 0.2))
    port = free_tcp_port()
    link = links.connect(f"tcp:127.0.0.1:{port}")
    watch = links.LinkWatch([link])
    server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    try:
        assert not link.up and link.error and link.failures == 1
        assert watch.changes() == [f"link tcp:127.0.0.1:{port} down ({link.error}); retrying"]
        assert link.recv_msg() is None
        assert watch.changes() == []  # said once
        link.write(b"dropped while down")  # no exception either
        server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        server.bind(("127.0.0.1", port))
        server.listen(1)
        wait_wall(lambda: link.recv_msg() is None and link.up, 5, "the stream up")
        assert link.error == "" and link.failures == 0
        assert watch.changes() == [f"link tcp:127.0.0.1:{port} up again"]
        peer, _ = server.accept()
        with peer:
            mav = mavlink.MAVLink(None, srcSystem=7, srcComponent=1)
            peer.sendall(mav.statustext_encode(6, b"over tcp").pack(mav))
            got = receive(link, 1)
            assert got[0].text == "over tcp" and got[0].get_srcSystem() == 7
    finally:
        link.close()
        server.close()


@pytest.mark.parametrize(("ids", "expected"), [((), (255, 0)), ((17, 191), (17, 191))])
def test_a_stream_sends_what_it_is_given_as_its_system_and_component_and_closes(ids, expected):
    server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    link = links.connect(f"tcp:127.0.0.1:{server.getsockname()[1]}", *ids)
    try:
        assert link.up and link.error == "" and link.connection.mav.robust_parsing is True
        peer, _ = server.accept()
        peer.settimeout(5)
        with peer:
            link.mav.heartbeat_send(6, 8, 0, 0, 0)
            message = mavlink.MAVLink(None).parse_buffer(peer.recv(1000))[0]
            assert (message.get_srcSystem(), message.get_srcComponent()) == expected
            link.close()
            assert peer.recv(1000) == b""  # the stream was closed
    finally:
        server.close()


def test_a_signed_stream_passes_only_signed_messages(monkeypatch):
    server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    link = links.connect(f"tcp:127.0.0.1:{server.getsockname()[1]}", key=KEY)
    try:
        peer, _ = server.accept()
        with peer:
            plain = mavlink.MAVLink(None, srcSystem=5, srcComponent=1)
            signer = mavlink.MAVLink(None, srcSystem=5, srcComponent=1)
            signing.sign_outgoing(signer, KEY)
            peer.sendall(
                plain.statustext_encode(6, b"unsigned").pack(plain)
                + signer.statustext_encode(6, b"signed").pack(signer)
            )
            got = receive(link, 1)
            assert [(m.text, m._verified) for m in got] == [("signed", True)]
            assert link.refused == {5: 1} and link.up
    finally:
        link.close()
        server.close()


def test_a_stream_whose_write_fails_goes_down_and_says_why(clock):
    server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    link = links.connect(f"tcp:127.0.0.1:{server.getsockname()[1]}")
    try:
        assert link.up

        class Broken:
            closed = False

            def write(self, data):
                raise BrokenPipeError(32, "Broken pipe")

            def close(self):
                self.closed = True

        link.connection = broken = Broken()
        link.write(b"x")
        assert (link.up, link.connection, link.failures) == (False, None, 1)
        assert broken.closed  # what is left of the dropped connection is closed
        assert link.error == "BrokenPipeError: [Errno 32] Broken pipe"

        class Failing(Broken):
            def recv_msg(self):
                raise ConnectionResetError(104, "Connection reset by peer")

        link.connection = Failing()
        link.up = True
        assert link.recv_msg() is None
        assert (link.up, link.connection, link.failures) == (False, None, 2)
        assert link.error == "ConnectionResetError: [Errno 104] Connection reset by peer"
    finally:
        link.close()
        server.close()


def test_a_stream_whose_peer_goes_away_reports_itself_down(clock):
    """An end of stream is not taken for silence: the link tries the peer again at once and, refused, is down."""
    server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    link = links.connect(f"tcp:127.0.0.1:{server.getsockname()[1]}")
    try:
        peer, _ = server.accept()
        assert link.up
        server.close()
        peer.close()
        wait_wall(lambda: link.recv_msg() is None and not link.up, 5, "the link down")
        assert link.error.startswith("ConnectionRefusedError: ") and link.failures == 1
    finally:
        link.close()
        server.close()


@pytest.mark.parametrize("require", [True, False])
def test_garbage_on_a_signed_stream_reaches_the_caller_as_bad_data_and_is_no_refused_signature(require):
    """Bytes that are no packet are BAD_DATA, which the caller counts as such: a link that requires signatures
    does not take them for an unsigned message (dropped and counted as refused, under system 0), nor does a
    lax one mark them as checked; the signed message behind them still arrives."""
    server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    link = links.connect(f"tcp:127.0.0.1:{server.getsockname()[1]}", key=KEY, require_signed=require)
    got = []

    def signed_arrived():
        while (message := link.recv_msg()) is not None:
            got.append(message)
        return any(m.get_type() == "STATUSTEXT" for m in got)

    try:
        peer, _ = server.accept()
        with peer:
            signer = mavlink.MAVLink(None, srcSystem=5, srcComponent=1)
            signing.sign_outgoing(signer, KEY)
            peer.sendall(b"\x00garbage" + signer.statustext_encode(6, b"signed").pack(signer))
            wait_wall(signed_arrived, 5, "the signed message")
        bad = [m for m in got if m.get_type() == "BAD_DATA"]
        assert b"".join(m.data for m in bad) == b"\x00garbage"
        assert not any(hasattr(m, "_verified") for m in bad)
        assert [(m.text, m._verified) for m in got if m not in bad] == [("signed", True)]
        assert link.refused == {} and link.up
    finally:
        link.close()
        server.close()
