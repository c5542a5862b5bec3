"""PTU-D46 driver against the pty simulator: round trips, limits, speed, faults (also those reported
from the field: limit messages, homing, stalls, unplugs), parser fuzz."""

from __future__ import annotations

import dataclasses
import logging
import math
import time

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxrecog.hardware.devices.pan_tilt import PanTilt, PanTiltConnectionError
from jaxrecog.hardware.devices.pan_tilt_drivers.ptu_d46 import PTU
from jaxrecog.hardware.devices.ptu_protocol import (
    PTUConnectionError,
    PTUError,
    PTUErrorReply,
    PTUGarbageError,
    PTUHomingTimeout,
    PTULimitError,
    PTUTimeoutError,
    parse_reply,
)
from jaxrecog.hardware.sim.ptu_sim import PTUSimulator

TIME_SCALE = 0.002


@pytest.fixture
def sim():
    with PTUSimulator(time_scale=TIME_SCALE, seed=3) as s:
        yield s


@pytest.fixture
def ptu(sim):
    with PTU(sim.port, timeout=0.15, await_margin=0.5) as p:
        yield p


def deg(positions: float, res: float = 185.1428) -> float:
    return positions * res / 3600.0


def test_connect_switches_unit_to_terse_no_echo_and_queries(sim, ptu):
    # the simulator powers up echoing and verbose, like the unit; the handshake fixes both
    assert not sim.echo and sim.terse
    assert ptu.resolution_arcsec == (185.1428, 185.1428)
    assert ptu.limits.pan == (-3090, 3090) and ptu.limits.tilt == (-907, 604)
    assert ptu.limits.pan_speed_max == 5833
    assert {"PR", "TR", "PN", "PX", "TN", "TX"} <= set(sim.log)


def test_resolution_is_queried_not_assumed():
    with PTUSimulator(resolution_arcsec=(92.5714, 46.2857), time_scale=TIME_SCALE) as sim:
        with PTU(sim.port, timeout=0.15) as ptu:
            ptu.move_to(10.0, -5.0)
            assert sim.axes["P"].target == round(10.0 * 3600 / 92.5714)
            assert sim.axes["T"].target == round(-5.0 * 3600 / 46.2857)


@pytest.mark.parametrize("pan,tilt", [(0.0, 0.0), (90.0, -30.0), (-158.9, 31.0), (12.345, -46.6), (-0.03, 0.02)])
def test_move_round_trip(sim, ptu, pan, tilt):
    ptu.move_to(pan, tilt)
    p_pos, t_pos = round(pan * 3600 / 185.1428), round(tilt * 3600 / 185.1428)
    assert (sim.axes["P"].target, sim.axes["T"].target) == (p_pos, t_pos)
    assert sim.position() == (p_pos, t_pos)  # A returned only once the motors arrived
    got = ptu.position()
    assert got == pytest.approx((deg(p_pos), deg(t_pos)), abs=1e-12)
    assert abs(got[0] - pan) <= deg(0.5) + 1e-12 and abs(got[1] - tilt) <= deg(0.5) + 1e-12


def test_await_takes_the_motion_time(sim, ptu):
    ptu.set_speed(pan=deg(500))  # 500 positions/s
    t0 = time.monotonic()
    ptu.move_to(pan=deg(2000))  # 2000 positions -> 4 simulated seconds
    wall = time.monotonic() - t0
    assert wall >= 4.0 * TIME_SCALE * 0.9
    assert sim.position()[0] == 2000


def test_offset_move(sim, ptu):
    ptu.move_to(10.0, 5.0)
    ptu.move_by(-3.0, 2.0)
    assert sim.axes["P"].target == round(10.0 * 3600 / 185.1428) + round(-3.0 * 3600 / 185.1428)
    assert sim.axes["T"].target == round(5.0 * 3600 / 185.1428) + round(2.0 * 3600 / 185.1428)
    assert any(c.startswith("PO") for c in sim.log) and any(c.startswith("TO") for c in sim.log)
    with pytest.raises(PTULimitError):
        ptu.move_by(pan=200.0)


def test_speed_round_trip(sim, ptu):
    ptu.set_speed(50.0, 20.0)
    assert sim.axes["P"].speed == round(50.0 * 3600 / 185.1428)
    assert sim.axes["T"].speed == round(20.0 * 3600 / 185.1428)
    assert ptu.speed() == pytest.approx((deg(sim.axes["P"].speed), deg(sim.axes["T"].speed)))
    with pytest.raises(PTULimitError, match="speed"):
        ptu.set_speed(pan=400.0)  # above PU = 5833 positions/s = 300 deg/s
    with pytest.raises(PTULimitError):
        ptu.set_speed(tilt=-1.0)


@pytest.mark.parametrize("pan,tilt", [(170.0, None), (-159.5, None), (None, 31.5), (None, -50.0), (float("nan"), None)])
def test_limits_are_checked_before_sending(sim, ptu, pan, tilt):
    before = list(sim.log)
    with pytest.raises(PTULimitError, match="limits|finite") as e:
        ptu.move_to(pan, tilt)
    assert e.value.command.startswith("PP" if pan is not None else "TP")
    assert sim.log == before  # nothing went out


def test_unit_refusal_is_an_error_reply_and_the_next_command_works(sim, ptu):
    # a driver with wrong (too wide) limits lets a bad move through; the unit says '!'
    ptu.limits = dataclasses.replace(ptu.limits, pan=(-9999, 9999))
    with pytest.raises(PTUErrorReply, match="Maximum allowable Pan") as e:
        ptu.move_to(pan=170.0)
    assert e.value.command == f"PP{round(170 * 3600 / 185.1428)}"
    ptu.move_to(pan=1.0)
    assert sim.position()[0] == round(3600 / 185.1428)


@pytest.mark.parametrize(
    "fault,exc",
    [("drop", PTUTimeoutError), ("error", PTUErrorReply), ("noise", PTUGarbageError)],
)
def test_fault_gives_its_error_naming_the_command_and_next_command_works(sim, ptu, fault, exc):
    ptu.move_to(20.0, -10.0)
    sim.inject(fault)
    with pytest.raises(exc) as e:
        ptu.query_int("PP")
    assert e.value.command == "PP" and "'PP'" in str(e.value)
    assert isinstance(e.value, PTUError)
    assert ptu.position_counts() == (round(20 * 3600 / 185.1428), round(-10 * 3600 / 185.1428))


@pytest.mark.parametrize("fault", ["drop", "error", "noise"])
def test_fault_during_a_move_then_move_again(sim, ptu, fault):
    sim.inject(fault)
    with pytest.raises(PTUError) as e:
        ptu.move_to(pan=30.0)
    assert e.value.command.startswith("PP")
    ptu.move_to(pan=-30.0, tilt=10.0)
    assert sim.position() == (round(-30 * 3600 / 185.1428), round(10 * 3600 / 185.1428))


def test_silent_unit_times_out_then_reconnect_recovers(sim, ptu):
    sim.silent = True
    t0 = time.monotonic()
    with pytest.raises(PTUTimeoutError, match="no complete reply"):
        ptu.position()
    assert time.monotonic() - t0 < 1.0  # the timeout bounds the wait
    with pytest.raises(PTUTimeoutError):
        ptu.reconnect()  # the handshake itself times out while the unit is silent
    sim.silent = False
    ptu.reconnect()
    ptu.move_to(5.0, 5.0)
    assert ptu.position() == pytest.approx((5.0, 5.0), abs=deg(0.5))


def test_silent_unit_answers_again_without_reconnect(sim, ptu):
    ptu.move_to(12.0, -7.0)
    want = (round(12 * 3600 / 185.1428), round(-7 * 3600 / 185.1428))
    sim.silent = True
    with pytest.raises(PTUTimeoutError, match="'PP'"):
        ptu.position()
    sim.silent = False
    # no reconnect(): the driver drained the line, the next command just works
    assert ptu.position() == pytest.approx((deg(want[0]), deg(want[1])), abs=1e-12)
    ptu.move_by(pan=1.0)
    assert sim.position() == (want[0] + round(3600 / 185.1428), want[1])


def test_late_reply_is_drained_and_the_driver_stays_in_step(sim, ptu):
    ptu.move_to(20.0, -10.0)
    pan, tilt = round(20 * 3600 / 185.1428), round(-10 * 3600 / 185.1428)
    sim.late_s = 0.25  # the answer to PP comes 0.1 s after the driver's 0.15 s timeout
    sim.inject("late")
    with pytest.raises(PTUTimeoutError) as e:
        ptu.query_int("PP")
    assert e.value.command == "PP"
    # the late "* <pan>" was discarded, not taken for the answer to the next query
    assert ptu.query_int("TP") == tilt
    assert ptu.position_counts() == (pan, tilt)


@pytest.mark.parametrize("fault", ["error", "drop", "noise", "late"])
def test_fault_on_the_tilt_command_of_a_move_keeps_the_driver_in_step(sim, ptu, fault):
    """PP is acknowledged, TP fails: the pan target is committed, the tilt one is
    read back from the unit, and the next relative move starts from where the unit is."""
    res = 185.1428
    sim.late_s = 0.25
    sim.inject(fault, after=1)  # PP goes through, TP meets the fault
    with pytest.raises(PTUError) as e:
        ptu.move_to(150.0, 20.0)
    assert e.value.command.startswith("TP")
    pan = round(150 * 3600 / res)
    tilt = 0 if fault == "error" else round(20 * 3600 / res)  # refused, or taken with its reply lost
    assert ptu.target[0] == pan
    # 150 + 15 deg is past the 159 deg pan limit: caught before sending, from the right base
    before = len(sim.log)
    with pytest.raises(PTULimitError, match="pan"):
        ptu.move_by(pan=15.0)
    assert not any(c.startswith("PO") for c in sim.log[before:])
    assert ptu.target == (pan, tilt)
    ptu.move_by(pan=-10.0, tilt=5.0)
    want = (pan + round(-10 * 3600 / res), tilt + round(5 * 3600 / res))
    assert sim.position() == want and ptu.target == want
    assert ptu.position_counts() == want


def test_inject_checks_its_arguments(sim):
    with pytest.raises(ValueError, match="unknown PTU fault"):
        sim.inject("fire")
    with pytest.raises(ValueError, match="after"):
        sim.inject("drop", after=-1)


def test_closed_port_is_a_connection_error(ptu):
    ptu.close()
    with pytest.raises(PTUConnectionError, match="not open"):
        ptu.position()
    ptu.reconnect()
    assert ptu.position() == (0.0, 0.0)


def test_slaved_mode_moves_only_at_await(sim, ptu):
    ptu.set_mode("slaved")
    ptu.move_to(40.0, wait=False)
    time.sleep(0.02)
    assert sim.position()[0] == 0  # held until A
    ptu.await_motion((0, 0))
    assert sim.position()[0] == round(40 * 3600 / 185.1428)
    ptu.set_mode("immediate")
    with pytest.raises(ValueError):
        ptu.set_mode("fast")


def test_reset_returns_home(sim, ptu):
    ptu.move_to(50.0, 20.0)
    ptu.reset(timeout=1.0)
    assert sim.position() == (0, 0)
    assert ptu.position() == (0.0, 0.0)


def test_any_pyserial_url_works(sim, capsys):
    # spy:// wraps the port and logs the traffic (to stderr by default)
    with PTU(f"spy://{sim.port}", timeout=0.15) as ptu:
        ptu.move_to(pan=15.0)
    assert f"PP{round(15 * 3600 / 185.1428)}" in capsys.readouterr().err


def test_loopback_url_is_not_a_ptu():
    # loop:// echoes the command back without a line end: a clear timeout naming ED
    with pytest.raises(PTUTimeoutError, match="'ED'"):
        PTU("loop://", timeout=0.05)


def test_unopenable_port():
    with pytest.raises(PTUConnectionError, match="cannot open"):
        PTU("/nonexistent/ttyPTU", timeout=0.05)


# ---------------------------------------------------------------- parser
@pytest.mark.parametrize(
    "line,expect,value",
    [
        (b"*\r\n", "ack", None),
        (b"*", "ack", None),
        (b"* 185.1428\r\n", "float", 185.1428),
        (b"*185\r\n", "float", 185.0),
        (b"* -3090\r\n", "int", -3090),
        (b"*\t+604\r\n", "int", 604),
        (b"!T!T!P!P*\r\n", "reset", None),
        (b"*\r\n", "reset", None),
    ],
)
def test_parse_reply_accepts(line, expect, value):
    assert parse_reply("X", line, expect) == value


@pytest.mark.parametrize(
    "line,expect,exc",
    [
        (b"! Illegal argument\r\n", "ack", PTUErrorReply),
        (b"! Maximum allowable Pan position is 3090\r\n", "int", PTUErrorReply),
        (b"!P\r\n", "reset", PTUErrorReply),  # markers without the final "*"
        (b"* 12x\r\n", "int", PTUGarbageError),
        (b"* 1e5\r\n", "float", PTUGarbageError),
        (b"* 1.5\r\n", "int", PTUGarbageError),
        (b"* nan\r\n", "float", PTUGarbageError),
        (b"**\r\n", "ack", PTUGarbageError),
        (b"* 5\r\n", "ack", PTUGarbageError),
        (b"*\r\n", "int", PTUGarbageError),
        (b"\xff\xfe\r\n", "ack", PTUGarbageError),
        (b"! bad \x80\r\n", "ack", PTUGarbageError),
        (b"", "int", PTUGarbageError),
    ],
)
def test_parse_reply_rejects(line, expect, exc):
    with pytest.raises(exc) as e:
        parse_reply("PP", line, expect)
    assert e.value.command == "PP"


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=40) | st.from_regex(rb"[*! ]{0,2}[-+0-9. A-Za-z]{0,16}(\r\n)?", fullmatch=True),
       st.sampled_from(["ack", "int", "float", "reset"]))
def test_fuzz_parse_reply_raises_only_ptu_errors(line, expect):
    try:
        value = parse_reply("PP", line, expect)
    except (PTUErrorReply, PTUGarbageError) as e:
        assert e.command == "PP"
        return
    if expect in ("ack", "reset"):
        assert value is None
    else:
        assert isinstance(value, int if expect == "int" else float)
        assert abs(value) < 1e13


# ================================================================ faults reported from the field
# Asynchronous !P / !T limit messages inside replies, a unit still homing after a
# reset or power-up, a stalled axis under A (await), and the serial device
# disappearing and coming back (ros-drivers/flir_ptu #10, #13, #20, #22, #38);
# each is a mode of the pty simulator.
def pos(deg: float) -> int:
    return round(deg * 3600 / 185.1428)


def wait_for(cond, limit: float = 2.0) -> None:
    t_end = time.monotonic() + limit
    while not cond():
        assert time.monotonic() < t_end, "the simulator did not get there in time"
        time.sleep(0.005)


def test_the_d46_driver_is_a_pan_tilt(ptu):
    assert isinstance(ptu, PanTilt)
    assert issubclass(PTUConnectionError, PanTiltConnectionError)


# ---------------------------------------------------------------- asynchronous limit messages
@pytest.mark.parametrize("fault,axis", [("pan_limit", "P"), ("tilt_limit", "T")])
def test_limit_message_inside_a_reply_is_parsed_out_counted_and_warned(sim, ptu, caplog, fault, axis):
    ptu.move_to(20.0, -10.0)
    sim.inject(fault)  # the answer to PP arrives as "* 3!P89" (for 389)
    with caplog.at_level(logging.WARNING, logger="jaxrecog.hardware.devices.pan_tilt_drivers.ptu_d46"):
        assert ptu.query_int("PP") == pos(20.0)  # never taken as (or for a part of) the answer
    assert sim.stats[fault] == 1
    assert ptu.limit_events == {axis: 1}
    assert f"'!{axis}'" in caplog.text and "reached a limit" in caplog.text
    # the axis that hit a limit is read back before the next move
    before = len(sim.log)
    ptu.move_by(pan=1.0)
    assert sim.log[before:before + 3] == ["A", "PP", "TP"]
    assert sim.position() == (pos(20.0) + pos(1.0), pos(-10.0))


def test_limit_message_inside_an_acknowledgement(sim, ptu):
    sim.inject("tilt_limit", after=1)  # PP's '*' is clean, TP's arrives as "!T*"
    ptu.move_to(30.0, 10.0)
    assert ptu.limit_events["T"] == 1
    assert sim.position() == (pos(30.0), pos(10.0))


# ---------------------------------------------------------------- homing
def test_unit_still_homing_after_a_power_up_gets_no_move_until_it_is_done(sim, ptu):
    """The unit comes back power-cycled: echoing, verbose, sweeping home while it
    already answers.  A move sent now would be acknowledged and lost; the driver
    waits (``A``) first."""
    ptu.move_to(40.0, 15.0)
    sim.unplug()
    sim.replug(homing_s=100.0)  # 0.2 s of wall time
    assert sim.homing()
    ptu.reconnect(sim.port)
    assert not sim.homing()
    ptu.move_to(30.0, 10.0)
    assert sim.position() == (pos(30.0), pos(10.0))
    assert sim.stats["lost_while_homing"] == 0
    assert not ptu.limit_events  # the sweep's markers are expected, not limit events


def test_reset_waits_for_the_end_of_the_sweep(sim, ptu):
    sim.homing_s = 100.0  # 0.2 s of wall time, markers on the way, then the reset's '*'
    ptu.move_to(50.0, 20.0)
    ptu.reset()
    assert not sim.homing() and sim.position() == (0, 0)
    assert not ptu.limit_events
    ptu.move_to(10.0, 5.0)
    assert sim.position() == (pos(10.0), pos(5.0))


def test_homing_longer_than_the_timeout_is_a_clear_error_and_no_move_is_sent(sim, ptu):
    sim.homing_s = 600.0  # 1.2 s of wall time: longer than the drain after the timeout (0.8 s)
    ptu.homing_timeout = 0.1
    with pytest.raises(PTUTimeoutError, match="'R'"):
        ptu.reset()
    before = len(sim.log)
    with pytest.raises(PTUHomingTimeout, match="still busy .homing.* no move was sent"):
        ptu.move_to(10.0, 5.0)
    assert not any(c.startswith(("PP", "TP")) for c in sim.log[before:])
    wait_for(lambda: not sim.homing(), limit=3.0)
    ptu.homing_timeout = 2.0
    ptu.move_to(10.0, 5.0)  # the reset's late '*' was drained, not read as an answer
    assert sim.position() == (pos(10.0), pos(5.0))
    assert ptu.position_counts() == (pos(10.0), pos(5.0))


# ---------------------------------------------------------------- bounded waits
def test_await_on_a_stalled_axis_is_bounded_and_the_next_move_reads_the_unit_back():
    """``A`` on an axis that stopped short never answers: the wait ends after the
    motion estimate plus the margin, and the next relative move starts from where
    the motor really stopped, not from the target it never reached."""
    with PTUSimulator(time_scale=1.0) as sim, PTU(sim.port, timeout=0.15, await_margin=0.2) as ptu:
        ptu.move_to(pan=5.0, wait=False)  # 97 positions: 0.1 s at 1000 positions/s
        sim.inject("stall")  # the A meets the stall
        t0 = time.monotonic()
        with pytest.raises(PTUTimeoutError, match="'A'"):
            ptu.await_motion()
        waited = time.monotonic() - t0
        assert waited < 0.15 + pos(5.0) / 1000 + 0.2 + 1.0  # timeout + estimate + margin, plus slack
        stopped = sim.position()[0]
        assert stopped < pos(5.0)  # it really stopped short
        ptu.move_by(pan=1.0)
        # (PO is relative in the unit, so the motor lands right either way; the
        # driver's limit checks and await estimates need its own idea to be right too)
        assert sim.position()[0] == stopped + pos(1.0) == ptu.target[0]


def test_a_position_outside_the_units_limits_is_a_clear_error_and_never_a_target(sim, ptu):
    """A unit of +/-3090 positions answering ``PP`` with ``* 99999999`` (a garbled line)
    used to be believed: after a failed move it became the target, and the next ``A``
    waited about 10^5 s for the motion back."""
    sim.answer("* 99999999")
    with pytest.raises(PTUGarbageError, match=r"^PTU command 'PP': pan position 99999999 is outside the unit's "
                                              r"limits \[-3090, 3090\]; got b'\* 99999999'$"):
        ptu.position()
    assert ptu.position() == (0.0, 0.0)  # the next query is in step
    sim.inject("drop")  # the move's PP is lost: the driver must read the axes back before the next move
    with pytest.raises(PTUTimeoutError):
        ptu.move_to(pan=5.0)
    sim.answer("* -99999999", after=1)  # the read-back's A passes, its PP is garbled
    with pytest.raises(PTUGarbageError, match="pan position -99999999 is outside"):
        ptu.move_to(pan=10.0)
    assert all(abs(t) <= 3090 for t in ptu.target)
    ptu.move_to(pan=10.0)  # read back again, properly this time, then moved
    assert sim.position()[0] == pos(10.0) == ptu.target[0]
    sim.answer("* 6000")  # a speed above the unit's own upper limit (5833)
    with pytest.raises(PTUGarbageError, match=r"pan speed 6000 is outside the unit's limits \[0, 5833\]"):
        ptu.speed()


def test_the_wait_for_a_motion_is_bounded_by_max_motion_s_whatever_the_estimate():
    """At 1 position/s a 1000-position move is estimated at 1000 s; on a stalled axis the
    driver waits max_motion_s, not the estimate."""
    with PTUSimulator(time_scale=1.0) as sim, \
            PTU(sim.port, timeout=0.15, await_margin=0.1, max_motion_s=0.5) as ptu:
        ptu.set_speed(pan=deg(1))
        ptu.move_to(pan=deg(1000), wait=False)
        sim.inject("stall")
        t0 = time.monotonic()
        with pytest.raises(PTUTimeoutError, match=r"'A'.*within 0.5 s"):
            ptu.await_motion()
        assert time.monotonic() - t0 < 0.5 + 1.5  # max_motion_s, plus the drain after a timeout
    with pytest.raises(ValueError, match="max_motion_s must be > 0 seconds"):
        PTU("loop://", max_motion_s=math.inf, connect=False)


# ---------------------------------------------------------------- the device disappears
def test_unplugged_device_is_a_connection_error_and_it_comes_back_under_a_new_path(sim, ptu):
    ptu.move_to(20.0, 5.0)
    old = sim.port
    sim.back_after_s, sim.back_new_path = 0.05, True
    sim.inject("unplug")
    with pytest.raises(PTUConnectionError, match="'PP'"):
        ptu.position()  # flir_ptu #20: "device reports readiness to read but returned no data"
    wait_for(lambda: sim.plugged)
    assert sim.port != old
    with pytest.raises(PTUConnectionError, match="cannot open"):
        ptu.reconnect()  # the old path is gone
    ptu.reconnect(sim.port)
    assert ptu.url == sim.port
    assert ptu.position_counts() == (pos(20.0), pos(5.0))  # the unit kept its power, and its place


def test_the_same_path_behind_a_symbolic_link_comes_back(tmp_path):
    link = tmp_path / "ttyPTU"
    with PTUSimulator(time_scale=TIME_SCALE, link=link) as sim, PTU(str(link), timeout=0.15) as ptu:
        ptu.move_to(-10.0)
        sim.unplug()
        assert not link.exists()
        with pytest.raises(PTUConnectionError):
            ptu.move_to(-5.0)
        sim.replug(new_path=True)
        ptu.reconnect()
        ptu.move_to(-5.0)
        assert sim.position()[0] == pos(-5.0)
