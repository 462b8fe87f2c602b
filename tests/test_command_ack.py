"""The ground station's command path (groundstation.link: request, command, command_int) against a scripted
vehicle on real UDP sockets: retries with confirmation + 1, which COMMAND_ACK counts, result words, giving up.

Every try waits for its reply on the station's clock that the test moves (StationClock), never on the wall clock:
however slow the machine, a try is repeated only when the test moves that clock past its timeout. The wall clock
only bounds how long the test waits for something that must happen (5 s)."""

from __future__ import annotations

import threading
import time
from concurrent.futures import Future
from contextlib import contextmanager

import pytest
from harness import StationClock, free_udp_port, wait_wall
from mavlink_peer import FakeVehicle

from groundstation.link import REPLY_LOOK, Link, LinkError
from groundstation.state import Fleet
from vehicle.protocol.mav import RESULT_WORDS, mavlink

TAKEOFF = mavlink.MAV_CMD_NAV_TAKEOFF
TIMEOUT = 0.25  # s of the station's clock per try, where a test gives one
SHORT = 1 / 1024  # s of the station's clock a try is held short of its timeout: it still waits for its reply
HELD = 1.5  # wall s the station's clock is held just short of a second, once: longer than a try on the wall clock


class ScriptedVehicle(FakeVehicle):
    """Vehicle ``sysid`` heard by the link (a heartbeat every 0.2 s); answers each COMMAND_LONG/COMMAND_INT try
    with the next of ``answers[command]`` (a result; None: silence; a callable: sends what it likes), the last
    one for later tries; unscripted commands are accepted."""

    def __init__(self, port: int, sysid: int = 1):
        self.answers: dict[int, list] = {}
        super().__init__(("127.0.0.1", port), sysid, beat=0.2, pose=False)

    def ack(self, command: int, result: int) -> None:
        self.send(self.mav.command_ack_encode(command, result, 0, 0, 255, 0))

    def handle(self, message) -> None:
        if message.get_type() not in ("COMMAND_LONG", "COMMAND_INT"):
            return
        script = self.answers.get(message.command, [mavlink.MAV_RESULT_ACCEPTED])
        answer = script.pop(0) if len(script) > 1 else script[0]
        self.received.append(message)  # once its answer is taken: a test that sees it may script the next
        if callable(answer):
            answer(self, message)
        elif answer is not None:
            self.ack(message.command, answer)

    def tries(self, command: int) -> list:
        return [m for m in list(self.received) if m.command == command]


@contextmanager
def station_and_vehicle(retry_clock: StationClock):
    port = free_udp_port()
    link = Link([f"udpin:127.0.0.1:{port}"], Fleet(), retry_clock=retry_clock).start()
    vehicle = ScriptedVehicle(port)
    try:
        wait_wall(lambda: link.fleet.get(1) is not None and 1 in link.route, 5, "the vehicle heard")
        yield link, vehicle
    finally:
        vehicle.close()
        link.close()


def in_background(call) -> Future:
    """``call()`` on a daemon thread of its own, as it waits on the station's clock that the test moves (a test
    that fails leaves it waiting: it must not keep the run from ending)."""
    future: Future = Future()

    def run() -> None:
        try:
            future.set_result(call())
        except BaseException as error:  # noqa: BLE001 - the test reads it from the future
            future.set_exception(error)

    threading.Thread(target=run, daemon=True).start()
    return future


def answered(call):
    """What ``call()`` returns (or raises) while the station's clock stands still: every try waits for its reply
    however slow the machine, so the try answered is the only one."""
    return in_background(call).result(timeout=5)


def tried_apart(
    clock: StationClock,
    vehicle: ScriptedVehicle,
    command: int,
    tries: int,
    timeout: float = TIMEOUT,
    held: float = 3 * REPLY_LOOK,
) -> None:
    """The vehicle gets ``tries`` tries of ``command``, each sent once ``timeout`` of the station's clock has passed
    since the one before, not earlier: the clock is held just short of it (``held`` wall s the first time, then
    what a try sent too early needs to arrive) before it is moved on to the timeout. It stays where the last try
    was sent (the station read its deadline before sending it)."""
    wait_wall(lambda: vehicle.tries(command), 5, f"the first try of command {command}")
    for sent in range(1, tries):
        clock.advance(timeout - SHORT)
        time.sleep(held if sent == 1 else 3 * REPLY_LOOK)
        assert len(vehicle.tries(command)) == sent, f"try {sent + 1} came before its {timeout} s had passed"
        clock.advance(SHORT)
        wait_wall(lambda sent=sent: len(vehicle.tries(command)) > sent, 5, f"try {sent + 1} of command {command}")


def noted(link: Link, ack: str) -> bool:
    """Whether vehicle 1's history notes the COMMAND_ACK ``ack`` ("NAV_LAND: accepted"): the station heard it."""
    return ("ack", ack) in [(e["kind"], e["text"]) for e in link.fleet.history.of(1).as_json()["events"]]


def tried_a_second_apart(clock: StationClock, vehicle: ScriptedVehicle, command: int, tries: int) -> None:
    """``tried_apart`` by the station's default timeout, a second: the first hold is longer than a try lasts on
    the wall clock."""
    tried_apart(clock, vehicle, command, tries, 1.0, HELD)


def test_an_answered_command_is_sent_once_and_its_result_named():
    with station_and_vehicle(StationClock()) as (link, vehicle):
        assert answered(lambda: link.command(1, TAKEOFF, 0, 0, 0, 0, 0, 0, 4.0)) == "accepted"
        (sent,) = vehicle.tries(TAKEOFF)
        assert sent.confirmation == 0 and sent.param7 == 4.0
        assert (sent.target_system, sent.target_component) == (1, mavlink.MAV_COMP_ID_AUTOPILOT1)


def test_unanswered_tries_are_repeated_with_confirmation_plus_one_until_answered():
    clock = StationClock()
    with station_and_vehicle(clock) as (link, vehicle):
        vehicle.answers[TAKEOFF] = [None, None, mavlink.MAV_RESULT_DENIED]
        denied = in_background(lambda: link.command(1, TAKEOFF, timeout=TIMEOUT))
        tried_apart(clock, vehicle, TAKEOFF, 3)
        assert denied.result(timeout=5) == "denied"
        assert [m.confirmation for m in vehicle.tries(TAKEOFF)] == [0, 1, 2]


def test_a_command_never_answered_gives_up_after_its_tries():
    clock = StationClock()
    with station_and_vehicle(clock) as (link, vehicle):
        vehicle.answers[TAKEOFF] = [None]
        unanswered = in_background(lambda: link.command(1, TAKEOFF, timeout=TIMEOUT, retries=4))
        tried_apart(clock, vehicle, TAKEOFF, 4)
        clock.advance(TIMEOUT)  # the last try's timeout: no more tries
        with pytest.raises(LinkError, match="vehicle 1 did not answer COMMAND_LONG after 4 tries"):
            unanswered.result(timeout=5)
        assert [m.confirmation for m in vehicle.tries(TAKEOFF)] == [0, 1, 2, 3]
        assert not link._waiters  # nothing left waiting for a late answer


def test_only_the_ack_of_this_command_from_this_vehicle_answers_it():
    """An ACK of another command, or of this command by another vehicle, is no answer."""

    def wrong_acks(vehicle, message):
        vehicle.ack(mavlink.MAV_CMD_NAV_LAND, mavlink.MAV_RESULT_ACCEPTED)  # another command
        other = mavlink.MAVLink(None, srcSystem=2, srcComponent=1)
        vehicle.raw(other.command_ack_encode(TAKEOFF, mavlink.MAV_RESULT_ACCEPTED, 0, 0, 255, 0).pack(other))
        # another vehicle

    clock = StationClock()
    with station_and_vehicle(clock) as (link, vehicle):
        vehicle.answers[TAKEOFF] = [wrong_acks, mavlink.MAV_RESULT_FAILED]
        failed = in_background(lambda: link.command(1, TAKEOFF, timeout=TIMEOUT))
        # the wrong ACKs reach the station while the first try waits (the other vehicle's is the last of them)
        wait_wall(lambda: 2 in link.route, 5, "the wrong ACKs heard")
        tried_apart(clock, vehicle, TAKEOFF, 2)
        assert failed.result(timeout=5) == "failed"
        assert len(vehicle.tries(TAKEOFF)) == 2


@pytest.mark.parametrize(
    ("result", "word"),
    [
        (mavlink.MAV_RESULT_TEMPORARILY_REJECTED, "temporarily rejected"),
        (mavlink.MAV_RESULT_UNSUPPORTED, "unsupported"),
        (mavlink.MAV_RESULT_IN_PROGRESS, "in progress"),
        (6, "cancelled"),  # MAV_RESULT_CANCELLED, which pymavlink 2.4.50's dialect lacks
        (mavlink.MAV_RESULT_COMMAND_LONG_ONLY, "COMMAND_LONG only"),
        (mavlink.MAV_RESULT_COMMAND_INT_ONLY, "COMMAND_INT only"),
        (9, "unsupported frame"),  # MAV_RESULT_COMMAND_UNSUPPORTED_MAV_FRAME, which it lacks too
        (99, "result 99"),
    ],
)
def test_result_words(result, word):
    with station_and_vehicle(StationClock()) as (link, vehicle):
        vehicle.answers[TAKEOFF] = [result]
        assert answered(lambda: link.command(1, TAKEOFF)) == word


def test_every_mav_result_the_dialect_defines_has_a_word():
    """No result a vehicle may send (as pymavlink's ardupilotmega dialect knows them, and MAVLink's 6 and 9
    besides) reaches the operator as a bare number."""
    defined = {value for value, entry in mavlink.enums["MAV_RESULT"].items() if not entry.name.endswith("ENUM_END")}
    assert defined | {6, 9} == set(RESULT_WORDS) == set(range(10))
    assert len(set(RESULT_WORDS.values())) == len(RESULT_WORDS)  # no two results read alike


def test_a_cancelled_command_reads_cancelled_in_the_answer_the_history_and_another_stations_ack():
    """A vehicle that answers CANCELLED (a long command stopped by COMMAND_CANCEL): the command's answer says
    "cancelled", as do the vehicle's history and, for an ACK addressed to another ground station, the note
    that another station commands it."""
    cancelled = 6

    def cancelled_for_another_station(vehicle, message):
        vehicle.send(vehicle.mav.command_ack_encode(mavlink.MAV_CMD_NAV_LAND, cancelled, 0, 0, 254, 0))
        vehicle.ack(message.command, mavlink.MAV_RESULT_ACCEPTED)

    with station_and_vehicle(StationClock()) as (link, vehicle):
        vehicle.answers[TAKEOFF] = [cancelled]
        assert answered(lambda: link.command(1, TAKEOFF)) == "cancelled"
        wait_wall(lambda: noted(link, "NAV_TAKEOFF: cancelled"), 5, "the ACK noted")
        vehicle.answers[mavlink.MAV_CMD_DO_SET_MODE] = [cancelled_for_another_station]
        assert answered(lambda: link.command(1, mavlink.MAV_CMD_DO_SET_MODE)) == "accepted"
        wait_wall(lambda: link.fleet.get(1).other_gcs is not None, 5, "the other station noted")
        assert link.fleet.get(1).other_gcs[:2] == (254, "COMMAND_ACK MAV_CMD_NAV_LAND cancelled")


def test_command_int_repeats_the_same_message_and_names_the_result():
    clock = StationClock()
    with station_and_vehicle(clock) as (link, vehicle):
        reposition = mavlink.MAV_CMD_DO_REPOSITION
        vehicle.answers[reposition] = [None, mavlink.MAV_RESULT_ACCEPTED]
        frame = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
        result = in_background(
            lambda: link.command_int(1, reposition, frame, [-1.0, 0, 0, 0], 123456789, 987654321, 5.0, timeout=TIMEOUT)
        )
        tried_apart(clock, vehicle, reposition, 2)
        assert result.result(timeout=5) == "accepted"
        tries = vehicle.tries(reposition)
        assert len(tries) == 2
        assert all((m.frame, m.x, m.y, m.z, m.param1) == (frame, 123456789, 987654321, 5.0, -1.0) for m in tries)


def test_a_request_waits_for_the_reply_it_accepts():
    """``request`` is the path of every command and of the mission protocol: the first reply that ``accepts``."""
    with station_and_vehicle(StationClock()) as (link, vehicle):

        def answer(vehicle, message):
            vehicle.send(vehicle.mav.statustext_encode(6, b"not this"))
            vehicle.send(vehicle.mav.statustext_encode(6, b"this one"))

        command = mavlink.MAV_CMD_PREFLIGHT_CALIBRATION  # one the station never sends by itself
        vehicle.answers[command] = [answer]
        message = mavlink.MAVLink_command_long_message(1, 1, command, 0, 0, 0, 0, 0, 0, 0, 0)
        reply = answered(
            lambda: link.request(1, message, lambda m: m.get_type() == "STATUSTEXT" and m.text == "this one")
        )
        assert reply.text == "this one"
        assert len(vehicle.tries(command)) == 1


def test_a_command_is_tried_three_times_a_second_apart_unless_told_with_its_missing_params_zero():
    """What the station's commands rely on (commands.py gives no timeout or retries): three tries, each
    waiting a second of the station's clock for the ACK; parameters not given are sent as 0."""
    land = mavlink.MAV_CMD_NAV_LAND
    clock = StationClock()
    with station_and_vehicle(clock) as (link, vehicle):
        vehicle.answers[TAKEOFF] = [None]
        unanswered = in_background(lambda: link.command(1, TAKEOFF))
        tried_a_second_apart(clock, vehicle, TAKEOFF, 3)
        clock.advance(1.0)  # the last try's second: no more tries
        with pytest.raises(LinkError, match="vehicle 1 did not answer COMMAND_LONG after 3 tries"):
            unanswered.result(timeout=5)
        assert [m.confirmation for m in vehicle.tries(TAKEOFF)] == [0, 1, 2]

        vehicle.answers[land] = [None, mavlink.MAV_RESULT_ACCEPTED]
        answered = in_background(lambda: link.command(1, land, 2.0))
        tried_a_second_apart(clock, vehicle, land, 2)
        assert answered.result(timeout=5) == "accepted"
        tries = vehicle.tries(land)
        assert [m.confirmation for m in tries] == [0, 1]
        assert all(
            [m.param1, m.param2, m.param3, m.param4, m.param5, m.param6, m.param7] == [2.0] + [0.0] * 6 for m in tries
        )


def test_command_int_is_tried_three_times_a_second_apart_as_current_and_without_autocontinue():
    """COMMAND_INT as commands.py sends it (a goto): three tries a second apart (of the station's clock) unless
    told, each with current and autocontinue 0 (fields MAVLink leaves unused in COMMAND_INT, to be sent as 0)."""
    reposition = mavlink.MAV_CMD_DO_REPOSITION
    frame = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    clock = StationClock()
    with station_and_vehicle(clock) as (link, vehicle):

        def goto():
            return link.command_int(1, reposition, frame, [-1.0, 0, 0, 0], 123456789, 987654321, 5.0)

        vehicle.answers[reposition] = [None]
        unanswered = in_background(goto)
        tried_a_second_apart(clock, vehicle, reposition, 3)
        clock.advance(1.0)
        with pytest.raises(LinkError, match="vehicle 1 did not answer COMMAND_INT after 3 tries"):
            unanswered.result(timeout=5)
        assert len(vehicle.tries(reposition)) == 3

        vehicle.received.clear()
        vehicle.answers[reposition] = [None, mavlink.MAV_RESULT_ACCEPTED]
        answered = in_background(goto)
        tried_a_second_apart(clock, vehicle, reposition, 2)
        assert answered.result(timeout=5) == "accepted"
        tries = vehicle.tries(reposition)
        assert len(tries) == 2
        assert all((m.current, m.autocontinue) == (0, 0) for m in tries)


def test_command_int_is_answered_only_by_the_ack_of_its_command_and_names_a_result_it_has_no_word_for():
    """An ACK of another command is no answer to a COMMAND_INT; an unknown result is given by its number."""
    reposition = mavlink.MAV_CMD_DO_REPOSITION

    def another_commands_ack(vehicle, message):
        vehicle.ack(mavlink.MAV_CMD_NAV_LAND, mavlink.MAV_RESULT_ACCEPTED)

    clock = StationClock()
    with station_and_vehicle(clock) as (link, vehicle):
        vehicle.answers[reposition] = [another_commands_ack, 99]
        result = in_background(
            lambda: link.command_int(
                1,
                reposition,
                mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                [-1.0, 0, 0, 0],
                123456789,
                987654321,
                5.0,
                timeout=TIMEOUT,
            )
        )
        # the other command's ACK reaches the station while the first try waits
        wait_wall(lambda: noted(link, "NAV_LAND: accepted"), 5, "the other command's ACK heard")
        tried_apart(clock, vehicle, reposition, 2)
        assert result.result(timeout=5) == "result 99"
        assert len(vehicle.tries(reposition)) == 2


def test_a_request_is_sent_again_unchanged_three_times_a_second_apart_unless_told():
    """``request`` (the mission protocol's path) resends the very message, waits a second of the station's clock
    per try and tries three times, unless told otherwise."""
    command = mavlink.MAV_CMD_PREFLIGHT_CALIBRATION  # one the station never sends by itself
    message = mavlink.MAVLink_command_long_message(1, 1, command, 0, 0, 0, 0, 0, 0, 0, 0)

    def accepts(m):
        return m.get_type() == "STATUSTEXT" and m.text == "calibrated"

    def answer(vehicle, message):
        vehicle.send(vehicle.mav.statustext_encode(6, b"calibrated"))

    clock = StationClock()
    with station_and_vehicle(clock) as (link, vehicle):
        vehicle.answers[command] = [None]
        unanswered = in_background(lambda: link.request(1, message, accepts))
        tried_a_second_apart(clock, vehicle, command, 3)
        clock.advance(1.0)
        with pytest.raises(LinkError, match="vehicle 1 did not answer COMMAND_LONG after 3 tries"):
            unanswered.result(timeout=5)
        assert [m.confirmation for m in vehicle.tries(command)] == [0, 0, 0]

        vehicle.received.clear()
        vehicle.answers[command] = [None, answer]
        answered = in_background(lambda: link.request(1, message, accepts))
        tried_a_second_apart(clock, vehicle, command, 2)
        assert answered.result(timeout=5).text == "calibrated"
        tries = vehicle.tries(command)
        assert [m.confirmation for m in tries] == [0, 0]


def test_a_command_goes_only_to_the_vehicle_it_is_for():
    """Two vehicles on one link: a command to one is sent to where that one was heard, not to both."""
    with station_and_vehicle(StationClock()) as (link, first):
        second = ScriptedVehicle(first.address[1], sysid=2)
        try:
            wait_wall(lambda: link.fleet.get(2) is not None and 2 in link.route, 5, "the second vehicle heard")
            assert answered(lambda: link.command(1, TAKEOFF, 0, 0, 0, 0, 0, 0, 4.0)) == "accepted"
            land = mavlink.MAV_CMD_NAV_LAND
            assert answered(lambda: link.command(2, land)) == "accepted"  # after the first, on the same path
            assert len(first.tries(TAKEOFF)) == 1 and not first.tries(land)
            assert len(second.tries(land)) == 1 and not second.tries(TAKEOFF)
        finally:
            second.close()
