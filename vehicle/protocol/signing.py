"""MAVLink 2 message signing, as ArduPilot, QGroundControl and MAVProxy do it: one 32-byte key per vehicle.

A signed packet sets incompat flag 0x01 and ends with 13 bytes: a link id, a
48-bit timestamp (units of 10 microseconds since 2015-01-01T00:00:00Z) and the
first 6 bytes of SHA-256(key + the packet up to and including the timestamp).
A receiver keeps, per stream (link id, system id, component id), the newest
timestamp it accepted and refuses anything not newer (a replay); a stream it
has not heard yet is accepted if it is at most a minute behind the receiver's
own clock. Only RADIO_STATUS passes unsigned, as the MAVLink signing guide
recommends (radios do not sign).

Sending uses pymavlink's own signing (``sign_outgoing`` sets up a packer, with
a timestamp that follows the wall clock and always increases, so that a
receiver that joins later does not take the stream for an old one). Checking
is done here, once per link for all its senders (``Verifier``), rather than in
pymavlink's parser: pymavlink records a stream's timestamp before it checks
the signature, so one forged packet with a far-future timestamp would silence
the genuine stream, and its per-parser state would let a packet replayed from
another UDP address through.
"""

from __future__ import annotations

import argparse
import base64
import binascii
import hashlib
import hmac
import itertools
import time
from collections import OrderedDict
from pathlib import Path

from vehicle.protocol.mav import mavlink

KEY_BYTES = 32
EPOCH = 1420070400  # 2015-01-01T00:00:00Z, the signing timestamp's zero
TICKS = 100_000  # timestamp units per second
NEW_STREAM_WINDOW = 60 * TICKS  # a stream first heard may be this far behind our clock
MAX_STREAMS = 256  # streams whose last timestamp is kept (only a valid signature makes one)
UNSIGNED_ALLOWED = frozenset({mavlink.MAVLINK_MSG_ID_RADIO_STATUS})
SIGNED, UNSIGNED, BAD, REPLAYED = "signed", "unsigned", "bad signature", "replayed"
_link_ids = itertools.count()


class SigningKeyError(ValueError):
    """A --signing-key that names no usable key."""


def load_key(value: str) -> bytes:
    """The 32-byte key that ``--signing-key`` names: a file holding 32 raw bytes, or one line of 64 hex digits or
    of base64 of 32 bytes; otherwise a passphrase, hashed with SHA-256 (as QGroundControl and MAVProxy's
    ``signing setup`` make a key of one). A value with a '/' that names no file is a mistyped path, not a
    passphrase."""
    path = Path(value)
    if path.is_file():
        data = path.read_bytes()
        if len(data) == KEY_BYTES:
            return data
        text = data.decode("ascii", "replace").strip()
        for decode in (bytes.fromhex, base64.b64decode):
            try:
                key = decode(text)
            except (ValueError, binascii.Error):
                continue
            if len(key) == KEY_BYTES:
                return key
        raise SigningKeyError(f"{value}: a key file holds {KEY_BYTES} bytes, or one line of 64 hex digits or of "
                              f"base64 of {KEY_BYTES} bytes")
    if "/" in value:
        raise SigningKeyError(f"no key file {value} (a passphrase has no '/')")
    if not value:
        raise SigningKeyError("an empty passphrase is no key")
    return hashlib.sha256(value.encode("utf-8")).digest()


def key_option(value: str) -> bytes:
    """``load_key`` for argparse: a bad key is a usage error that says why."""
    try:
        return load_key(value)
    except (SigningKeyError, OSError) as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def now_stamp() -> int:
    """The signing clock now: 10 microsecond units since 2015-01-01."""
    return int((time.time() - EPOCH) * TICKS)


class _WallClockSigning(mavlink.MAVLinkSigning):
    """pymavlink's signing state with a timestamp that never falls behind the wall clock and never repeats
    (pymavlink counts it up by one per packet from where it was set)."""

    @property
    def timestamp(self) -> int:
        self._timestamp = max(self._timestamp, now_stamp())
        return self._timestamp

    @timestamp.setter
    def timestamp(self, value: int) -> None:
        self._timestamp = value


def sign_outgoing(packer: mavlink.MAVLink, key: bytes) -> None:
    """Make ``packer`` sign every packet it makes, on a link id of its own (each packer is its own stream)."""
    state = _WallClockSigning()
    state.secret_key = key
    state.sign_outgoing = True
    state.link_id = next(_link_ids) % 256
    packer.signing = state


class Verifier:
    """Checks the signatures of what one link receives, from all its senders, and says what may pass.

    ``require``: only signed messages (and RADIO_STATUS) pass, as on a vehicle with a key; without it, unsigned
    and wrongly signed messages pass as unsigned (a station that shows which links are signed). Replays never
    pass."""

    def __init__(self, key: bytes, require: bool = True):
        self.key = key
        self.require = require
        self._streams: OrderedDict[tuple[int, int, int], int] = OrderedDict()

    def check(self, message) -> str:
        """SIGNED, UNSIGNED, BAD or REPLAYED."""
        packet = bytes(message.get_msgbuf())
        if len(packet) < 25 or packet[0] != mavlink.PROTOCOL_MARKER_V2 or not packet[2] & mavlink.MAVLINK_IFLAG_SIGNED:
            return UNSIGNED
        digest = hashlib.sha256(self.key + packet[:-6]).digest()[:6]
        if not hmac.compare_digest(digest, packet[-6:]):
            return BAD
        stamp = int.from_bytes(packet[-12:-6], "little")
        stream = (packet[-13], message.get_srcSystem(), message.get_srcComponent())
        last = self._streams.get(stream)
        if stamp <= (last if last is not None else now_stamp() - NEW_STREAM_WINDOW):
            return REPLAYED
        self._streams[stream] = stamp
        self._streams.move_to_end(stream)
        while len(self._streams) > MAX_STREAMS:
            self._streams.popitem(last=False)
        return SIGNED

    def admits(self, message, verdict: str) -> bool:
        if verdict == SIGNED:
            return True
        if verdict == REPLAYED:
            return False
        return not self.require or message.get_msgId() in UNSIGNED_ALLOWED
