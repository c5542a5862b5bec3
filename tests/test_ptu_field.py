"""PTU faults reported from the field, each a mode of the pty simulator.

Asynchronous ``!P`` / ``!T`` limit messages inside replies, a unit still
homing after a reset or power-up, a stalled axis under ``A`` (await), and the
serial device disappearing and coming back (ros-drivers/flir_ptu #10, #13,
#20, #22, #38)."""

from __future__ import annotations

import logging
import time

import pytest

from jaxrecog.hardware.pan_tilt import PanTilt, PanTiltConnectionError
from jaxrecog.hardware.ptu import PTU, PTUConnectionError, PTUHomingTimeout, PTUTimeoutError
from jaxrecog.hardware.ptu_sim import PTUSimulator

RES = 185.1428
TIME_SCALE = 0.002


def pos(deg: float) -> int:
    return round(deg * 3600 / RES)


@pytest.fixture
def sim():
    with PTUSimulator(time_scale=TIME_SCALE, seed=3) as s:
        yield s


@pytest.fixture
def ptu(sim):
    with PTU(sim.port, timeout=0.15, await_margin=0.3, homing_timeout=2.0) as p:
        yield p


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
    with caplog.at_level(logging.WARNING, logger="jaxrecog.hardware.ptu"):
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
