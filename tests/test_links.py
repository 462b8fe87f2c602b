"""Links that hold against hostile peers (vehicle.protocol.links), on real sockets: UDP parsed per datagram and per
sender, bounded in senders and in datagrams per call; streams that report themselves down and come back."""

from __future__ import annotations

import socket

import pytest
from harness import free_tcp_port, free_udp_port, wait_wall

from vehicle.protocol import links
from vehicle.protocol.mav import mavlink


class Sender:
    """A peer on its own UDP socket, sending MAVLink as ``sysid``."""

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


@pytest.mark.parametrize("url", ["udpin:127.0.0.1", "udpout::14550", "udp:host:port"])
def test_a_udp_url_without_host_and_port_is_refused(url):
    with pytest.raises(ValueError, match="HOST:PORT"):
        links.connect(url)


def test_a_stream_that_is_not_up_yet_reports_itself_down_then_comes_up(monkeypatch):
    monkeypatch.setattr(links, "RETRY", (0.05, 0.2))
    port = free_tcp_port()
    link = links.connect(f"tcp:127.0.0.1:{port}")
    server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    try:
        assert not link.up and link.error and link.failures == 1
        assert link.recv_msg() is None
        link.write(b"dropped while down")  # no exception either
        server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        server.bind(("127.0.0.1", port))
        server.listen(1)
        wait_wall(lambda: link.recv_msg() is None and link.up, 5, "the stream up")
        assert link.error == "" and link.failures == 0
        peer, _ = server.accept()
        with peer:
            mav = mavlink.MAVLink(None, srcSystem=7, srcComponent=1)
            peer.sendall(mav.statustext_encode(6, b"over tcp").pack(mav))
            got = receive(link, 1)
            assert got[0].text == "over tcp" and got[0].get_srcSystem() == 7
    finally:
        link.close()
        server.close()
