"""Protocol sessions (versions 2 to 4): bound to the client's address, refused to strangers while
live, taken over only after an idle timeout (the displaced client is told and
re-handshakes), an optional shared key (HMAC-SHA256), versions 1 and 2 still spoken.

The bug this guards: one HELLO from any address used to open a new session and
retire the client's; the stranger's MOVE ran and the client then only timed out."""

from __future__ import annotations

import math
import socket
import threading
import time

import pytest

from jaxrecog.hardware.sim.controller_sim import ControllerSimulator
from jaxrecog.hardware.devices.datagram import (
    Datagram,
    DatagramError,
    Hello,
    Move,
    MsgType,
    RejectCode,
    SharedKey,
    decode,
    encode,
)
from jaxrecog.hardware.geometry.positions import default_table
from jaxrecog.hardware.devices.udp_link import (
    ControllerLink,
    ControllerRestarted,
    LinkError,
    LinkTimeoutError,
    SessionClosed,
    SessionRefused,
)

TABLE = default_table()
KEY = SharedKey(b"a shared key of the rig, 32 byte")


def move_of(i: int) -> Move:
    v1, v2 = TABLE.views[0][(i * 7) % 32], TABLE.views[1][(i * 3) % 7]
    return Move(((v1.pan, v1.tilt), (v2.pan, v2.tilt)), (i % 4) * math.pi / 2)


class Stranger:
    """Another socket on 127.0.0.1: sends what it likes, collects what comes back."""

    def __init__(self, address):
        self.address = address
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))

    def send(self, dg: Datagram, key: SharedKey | None = None) -> None:
        self.sock.sendto(encode(dg, key), self.address)

    def replies(self, wait_s: float = 0.15, key: SharedKey | None = None) -> list[Datagram]:
        out, end = [], time.monotonic() + wait_s
        while (left := end - time.monotonic()) > 0:
            self.sock.settimeout(left)
            try:
                data = self.sock.recv(2048)
            except socket.timeout:
                break
            try:
                out.append(decode(data, key))
            except DatagramError:
                out.append(None)
        return out

    def close(self) -> None:
        self.sock.close()


def test_datagrams_from_a_second_socket_move_nothing_and_the_client_is_unaffected():
    with ControllerSimulator(time_scale=0.001, session_idle_s=30.0) as sim, \
            ControllerLink(sim.address, timeout=0.1, retries=3) as link:
        link.move(move_of(0))
        session = link.session
        evil = Stranger(sim.address)
        try:
            # a HELLO of its own is refused: the client's session is live
            evil.send(Datagram(MsgType.HELLO, 0, 0, Hello(1234)))
            (refused,) = evil.replies()
            assert refused.type == MsgType.REFUSED and refused.payload.nonce == 1234
            assert refused.payload.code == RejectCode.SESSION_BUSY and "another client" in refused.payload.reason
            # the client's own session id and the next seqs, sniffed: ignored, unanswered
            for seq in (link._seq + 1, link._seq + 50):
                evil.send(Datagram(MsgType.MOVE, session, seq, move_of(7)))
            evil.send(Datagram(MsgType.PING, session, link._seq + 51))
            assert evil.replies() == []
            # a made-up session: rejected, not run
            evil.send(Datagram(MsgType.MOVE, session ^ 0xFFFF, 1, move_of(7)))
            (rej,) = evil.replies()
            assert rej.type == MsgType.REJECTED and rej.payload.code == RejectCode.UNKNOWN_SESSION
        finally:
            evil.close()
        for i in (1, 2, 3):  # the client goes on as if nothing happened
            res = link.move(move_of(i))
            assert res.seq == i + 1
        assert link.session == session and link.stats["handshake"] == 1
        assert link.stats["session_closed"] == link.stats["controller_restart"] == 0
        assert link.ping() >= 0
    assert [e.move for e in sim.executed] == [move_of(i) for i in range(4)]  # the stranger's move never ran
    assert sim.stats["hello_refused"] == 1 and sim.stats["wrong_address"] == 3 and sim.stats["takeover"] == 0


def test_after_the_idle_timeout_another_client_takes_over_and_the_first_is_told(caplog):
    idle = 1.0  # long enough that a loaded machine does not let a live session go idle mid-test
    with ControllerSimulator(time_scale=0.001, session_idle_s=idle) as sim, \
            ControllerLink(sim.address, timeout=0.05, retries=3) as a, \
            ControllerLink(sim.address, timeout=0.05, retries=3) as b:
        a.move(move_of(0))
        with pytest.raises(SessionRefused, match=r"refused a session \(code 6\): another client's session is live"):
            b.move(move_of(1))  # a's session is live: b is refused, nothing moved
        time.sleep(idle + 0.1)
        b.move(move_of(2))  # a went idle: b takes over
        # a is told its session is gone; it re-handshakes (refused now: b is live) and does not resend
        with pytest.raises(SessionClosed, match=r"closed this link's session .* not resent .*\(re-handshake failed: "
                                                r".*refused a session"):
            a.move(move_of(3))
        assert a.stats["session_closed"] == 1 and a.session is None and "closed session" in caplog.text
        time.sleep(idle + 0.1)
        res = a.move(move_of(4))  # b idle: a opens a new session and moves
        assert res.seq == 1 and a.stats["handshake"] == 2
        with pytest.raises(SessionClosed):
            b.move(move_of(5))
    assert [e.move for e in sim.executed] == [move_of(0), move_of(2), move_of(4)]
    assert sim.stats["takeover"] == 2 and sim.stats["retired"] == 2


def test_a_ping_of_a_closed_session_says_so_and_the_next_request_opens_a_new_one():
    with ControllerSimulator(time_scale=0.001, session_idle_s=0.0) as sim, \
            ControllerLink(sim.address, timeout=0.05, retries=3) as a, \
            ControllerLink(sim.address, timeout=0.05, retries=3) as b:
        a.ping()
        b.ping()  # idle timeout 0: b takes over at once
        with pytest.raises(LinkError, match="no longer knows this link's session .*code 5"):
            a.ping()
        assert a.session is None
        a.move(move_of(0))
        assert a.stats["handshake"] == 2


@pytest.mark.parametrize("who", ["no key", "another key", "version 1"])
def test_with_a_shared_key_nobody_without_it_gets_an_answer_or_the_session(who):
    """Idle timeout 0, so without the key a HELLO would take the session at once."""
    other = {"no key": None, "another key": SharedKey(b"not the rig's key, but long")}.get(who)
    with ControllerSimulator(time_scale=0.001, key=KEY, session_idle_s=0.0) as sim, \
            ControllerLink(sim.address, timeout=0.1, retries=3, key=KEY) as link:
        link.move(move_of(0))
        session = link.session
        evil = Stranger(sim.address)
        try:
            v = 1 if who == "version 1" else 2
            sniffed = session & 0xFFFFFFFF  # (what of it a version-1/2 header can carry)
            evil.send(Datagram(MsgType.HELLO, 0, 0, Hello(99), version=v), other)
            evil.send(Datagram(MsgType.MOVE, sniffed, link._seq + 1, move_of(5).for_version(v), version=v), other)
            evil.send(Datagram(MsgType.MOVE, 12345, 1, move_of(5).for_version(v), version=v), other)
            assert evil.replies() == []
        finally:
            evil.close()
        assert sim.stats["unauthenticated"] == 3 and sim.stats["hello"] == 1
        assert link.move(move_of(1)).seq == 2 and link.session == session
    assert [e.move for e in sim.executed] == [move_of(0), move_of(1)]


@pytest.mark.parametrize("key", [None, SharedKey(b"not the rig's key, but long")], ids=["no key", "another key"])
def test_a_client_without_the_key_times_out_and_moves_nothing(key):
    with ControllerSimulator(time_scale=0.001, key=KEY) as sim, \
            ControllerLink(sim.address, timeout=0.03, retries=1, key=key) as link:
        with pytest.raises(LinkTimeoutError, match="no valid WELCOME"):
            link.move(move_of(0))
    assert sim.executed == [] and sim.stats["unauthenticated"] == 2


def test_the_key_is_never_in_a_message_or_a_repr():
    secret = b"a shared key of the rig, 32 byte"
    with ControllerSimulator(time_scale=0.001, key=secret) as sim, \
            ControllerLink(sim.address, timeout=0.25, retries=0, key=secret) as link:
        link.move(move_of(0))  # (a timeout that a loaded machine's scheduler cannot beat)
        texts = [repr(link.key), repr(sim.key), str(link.__dict__), str(sim.__dict__)]
    with ControllerLink(sim.address, timeout=0.02, retries=0, key=secret) as link:
        with pytest.raises(LinkTimeoutError) as e:
            link.move(move_of(0))  # (the simulator is closed)
        texts.append(str(e.value))
    assert not any(secret.decode() in t for t in texts)


def test_a_version_1_client_is_answered_in_version_1():
    with ControllerSimulator(time_scale=0.001, session_idle_s=30.0) as sim:
        with ControllerLink(sim.address, timeout=0.1, retries=3, version=1) as old:
            res = old.move(move_of(0))
            assert res.seq == 1 and old.stats["version"] == 0 and old.ping() >= 0
            raw = Stranger(sim.address)
            try:
                raw.send(Datagram(MsgType.HELLO, 0, 0, Hello(5), version=1))
                assert raw.replies() == []  # refused (old's session is live), and version 1 has no REFUSED
                raw.send(Datagram(MsgType.MOVE, 777, 1, move_of(1).for_version(1), version=1))
                (rej,) = raw.replies()
                assert rej.version == 1 and rej.type == MsgType.REJECTED
            finally:
                raw.close()
    assert [e.move for e in sim.executed] == [move_of(0).for_version(1)] == [res.move]
    with pytest.raises(ValueError, match="needs protocol version 2 or later"):
        ControllerLink(("127.0.0.1", 9), key=KEY, version=1)


def test_a_version_3_client_moves_with_a_u32_session():
    """A version-4 controller answers a version-3 client in version 3: a u32 session id
    (no boot in it), u32 nonces, the n-camera moves."""
    with ControllerSimulator(time_scale=0.001, key=KEY) as sim, \
            ControllerLink(sim.address, timeout=0.1, retries=3, key=KEY, version=3) as link:
        res = link.move(move_of(3))
        assert res.version == 3 and 0 < link.session < 2**32 and link.boot == sim.boot
        sim.restart()
        with pytest.raises(ControllerRestarted):  # its old session is unknown to the new boot: unrun
            link.move(move_of(4))
        assert link.move(move_of(5)).seq == 1
    assert [e.move for e in sim.executed] == [move_of(3), move_of(5)]


def test_a_version_2_client_moves_the_thesis_rig_as_before():
    """A version-2 link sends camera-1 pan, tilt and camera-2 pan (camera 2's tilt is not
    on the wire); the controller answers in version 2 with the gantry's x, y and the track's
    y, which the link completes into eyes with the carriers' fixed coordinates."""
    with ControllerSimulator(time_scale=0.001, key=KEY) as sim, \
            ControllerLink(sim.address, timeout=0.1, retries=3, key=KEY, version=2) as link:
        res = link.move(move_of(2))
        assert res.move == move_of(2).for_version(2) and res.move.cameras[1] == (move_of(2).cameras[1][0], 0.0)
        assert res.version == 2 and [len(r) for r in res.reached] == [2, 1]
        carriers = TABLE.workspace.carriers
        for eye, c, (pan, tilt) in zip(res.eyes(carriers), carriers, move_of(2).cameras, strict=True):
            assert eye == pytest.approx(c.place(TABLE.workspace.object_xyz, pan, tilt)[0], abs=1e-5)
        with pytest.raises(ValueError, match="protocol version 2 moves at most 2 cameras"):
            link.move(Move(move_of(2).cameras * 2, 0.0))
    assert [e.move for e in sim.executed] == [res.move] and sim.executed[0].reply.reached == res.reached


# ---------------------------------------------------------------- replays
class Recorder:
    """A UDP relay between one client and the controller that keeps every datagram the
    client sent: what anyone on the network path could record."""

    def __init__(self, controller):
        self.controller, self.sent = controller, []
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        self.address, self.client = self.sock.getsockname(), None
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.relay, daemon=True)
        self.thread.start()

    def relay(self):
        while not self.stop.is_set():
            try:
                data, peer = self.sock.recvfrom(2048)
            except (socket.timeout, OSError):
                continue
            if peer == self.controller:
                self.sock.sendto(data, self.client)
            else:
                self.client = peer
                self.sent.append(data)
                self.sock.sendto(data, self.controller)

    def close(self):
        self.stop.set()
        self.thread.join(timeout=2.0)
        self.sock.close()


def replay(address, recorded):
    """Send recorded datagrams from a new address, one at a time; the answers to each."""
    other = Stranger(address)
    try:
        answers = []
        for data in recorded:
            other.sock.sendto(data, address)
            answers.append(other.replies(0.1, KEY))
        return answers
    finally:
        other.close()


def test_a_recorded_keyed_session_replayed_after_a_restart_moves_nothing_and_is_refused_with_the_reason():
    """A keyed client's HELLO and two MOVEs, recorded, then replayed from another address to
    the controller restarted (a new process, same seed, same key).  The session ids repeated
    across restarts and the tag covered no boot: WELCOME, then both moves ran again."""
    with ControllerSimulator(time_scale=0.001, key=KEY, seed=5) as sim:
        relay = Recorder(sim.address)
        try:
            with ControllerLink(relay.address, timeout=0.1, retries=3, key=KEY) as link:
                link.move(move_of(1))
                link.move(move_of(2))
                session, boot = link.session, link.boot
        finally:
            relay.close()
        recorded = list(relay.sent)
    assert len(recorded) == 3 and [e.move for e in sim.executed] == [move_of(1), move_of(2)]
    with ControllerSimulator(time_scale=0.001, key=KEY, seed=5) as again:
        (welcome,), *moves = replay(again.address, recorded)
        assert welcome.type == MsgType.WELCOME and welcome.session != session  # ids are never issued again
        for (rejected,) in moves:
            assert rejected.type == MsgType.REJECTED and rejected.payload.code == RejectCode.UNKNOWN_SESSION
            assert rejected.payload.reason == (
                f"session {session:016x} is of boot {boot:08x}; this controller booted as {again.boot:08x} "
                f"(it restarted since, or the request is a replay): not executed")
        assert again.executed == [] and again.stats["other_boot"] == 2
        # restarted in place, too: the old session's requests are refused the same way
        again.restart()
        for (rejected,) in replay(again.address, recorded[1:]):
            assert rejected.payload.code == RejectCode.UNKNOWN_SESSION and "replay" in rejected.payload.reason
        assert again.executed == []


def test_a_replayed_hello_within_a_boot_is_dropped_and_takes_no_session():
    """Within a boot a recorded version-4 HELLO is a used nonce: from another address it is
    dropped, unanswered, though the client's session is idle (idle timeout 0); from the
    client's own address it is the retransmission of the last HELLO and gets the same
    WELCOME (the same session: nothing changes).  The recorded MOVE from another address
    is ignored (the session is bound to the client's)."""
    with ControllerSimulator(time_scale=0.001, key=KEY, session_idle_s=0.0) as sim:
        relay = Recorder(sim.address)
        try:
            with ControllerLink(relay.address, timeout=0.1, retries=3, key=KEY) as link:
                link.move(move_of(1))
                hello, move = relay.sent
                assert replay(sim.address, [hello, move]) == [[], []]
                relay.sock.sendto(hello, sim.address)  # from the client's own address (the relay's)
                time.sleep(0.1)
                assert link.move(move_of(2)).seq == 2 and link.stats["session_closed"] == 0
        finally:
            relay.close()
    assert [e.move for e in sim.executed] == [move_of(1), move_of(2)]
    assert sim.stats["hello_replay"] == 1 and sim.stats["hello_repeat"] == 1 and sim.stats["hello"] == 1
    assert sim.stats["wrong_address"] == 1
