"""The rig line protocol and the pyserial driver, over real links: pyserial's loop://
handler, pseudo-terminals served by fake controllers, and the simulator's logic."""
from __future__ import annotations

import pytest
from rig_helpers import FakeController, garbage

from usdbtf.errors import BTFError
from usdbtf.rig import protocol as P
from usdbtf.rig.driver import RigDriver, RigRefused
from usdbtf.rig.sim import RigSimulator


# -- framing -------------------------------------------------------------------------------
def test_checksum_is_nmea_xor():
    # NMEA's own example sentence body and checksum.
    assert P.checksum(b"GPGLL,5300.97914,N,00259.98174,E,125926,A") == "28"
    assert P.frame("12 OK") == b"12 OK*" + P.checksum(b"12 OK").encode() + b"\n"


def test_request_and_reply_round_trip():
    line = P.encode_request(7, "ARM", P.format_angle(45.0), P.format_angle(-0.0004))
    assert line.startswith(b"7 ARM 45 0*")
    req = P.parse_request(line)
    assert (req.seq, req.command, req.args) == (7, "ARM", ("45", "0"))
    ok = P.parse_reply(P.encode_reply(7, True, {"arm": "45,0"}))
    assert ok.ok and ok.seq == 7 and ok.fields == {"arm": "45,0"}
    err = P.parse_reply(P.encode_reply(9, False, code="RANGE", message="ARM 190 outside 0..180 deg"))
    assert not err.ok and err.code == "RANGE" and err.message == "ARM 190 outside 0..180 deg"


@pytest.mark.parametrize("line", [
    b"7 OK arm=45,0*00\n",              # wrong checksum
    b"7 OK arm=45,0\n",                 # no checksum
    b"\xff\xfe garbage\n",
    P.frame("7 MAYBE"),                 # valid frame, unknown status
    P.frame("x7 OK"),                   # bad seq
    P.frame("7 OK arm"),                # field without '='
    P.frame("7 ERR NOPE message"),      # unknown error code
])
def test_garbled_replies_are_detected(line):
    with pytest.raises(P.Garbled):
        P.parse_reply(line)


def test_a_flipped_bit_never_passes():
    line = P.encode_reply(123, True, {"frame": "17", "tag": "s00001", "arm": "30,60", "head": "45,330"})
    for pos in range(len(line) - 1):
        for bit in range(7):
            bad = bytearray(line)
            bad[pos] ^= 1 << bit
            if bad[pos] == 0x0A:
                continue
            with pytest.raises(P.Garbled):
                P.parse_reply(bytes(bad))


def test_format_angle():
    assert [P.format_angle(x) for x in (0, 12.5, 12.34567, -0.0001, 359.9999)] == ["0", "12.5", "12.346", "0", "360"]


# -- simulator logic -------------------------------------------------------------------------
def ask(sim, seq, *words):
    return P.parse_reply(sim.handle(P.encode_request(seq, *words)))


def test_simulator_commands_and_errors():
    shots = []
    sim = RigSimulator(lambda tag, head, arm, flat: shots.append((tag, head, arm, flat)))
    assert ask(sim, 1, "HELLO").fields["proto"] == P.PROTOCOL
    assert ask(sim, 2, "HEAD", "45", "-30").fields == {"head": "45,330"}
    assert ask(sim, 3, "ARM", "120.5", "10").fields == {"arm": "120.5,10"}
    r = ask(sim, 4, "TRIG", "s00001")
    assert r.fields["frame"] == "1" and r.fields["head"] == "45,330" and r.fields["arm"] == "120.5,10"
    assert shots == [("s00001", (45.0, 330.0), (120.5, 10.0), False)]
    assert ask(sim, 5, "ARM", "190", "0").code == "RANGE"
    assert ask(sim, 6, "HEAD", "95", "0").code == "RANGE"
    assert ask(sim, 7, "HEAD", "x", "0").code == "SYNTAX"
    assert ask(sim, 8, "TRIG", "bad/tag").code == "SYNTAX"
    unknown = P.parse_reply(sim.handle(P.frame("9 FIRE")))
    assert unknown.code == "UNKNOWN" and unknown.seq == 9
    garbled = P.parse_reply(sim.handle(b"10 HEAD 45 0*00\n"))
    assert (garbled.seq, garbled.code) == (0, "CHECKSUM")
    assert ask(sim, 11, "STATUS").fields == {"arm": "120.5,10", "head": "45,330", "flat": "0", "frames": "1"}


def test_simulator_faults_are_seeded():
    def outcomes(seed):
        sim = RigSimulator(fault_rate=0.5, seed=seed)
        return [sim.handle(P.encode_request(i, "STATUS")) for i in range(1, 60)]
    a, b = outcomes(3), outcomes(3)
    assert a == b
    lost = sum(r is None for r in a)
    garbled = 0
    for r in a:
        if r is not None:
            try:
                P.parse_reply(r)
            except P.Garbled:
                garbled += 1
    assert lost > 5 and garbled > 5 and lost + garbled < 50


# -- the driver on real links ------------------------------------------------------------------
def test_driver_over_a_pty_with_a_flaky_controller():
    sim = RigSimulator(fault_rate=0.3, seed=1)
    with FakeController(sim.handle) as dev:
        with RigDriver(dev.path, timeout=0.2, move_timeout=0.2, retries=8, reconnect_timeout=2) as rig:
            assert rig.identity["model"] == "usdbtf-sim"
            for k in range(15):
                assert rig.move_arm(10 + k, 20) == (10 + k, 20.0)
            assert rig.move_head(30, 400) == (30.0, 40.0)
            shot = rig.trigger("s00042")
            assert shot["head"] == (30.0, 40.0) and shot["arm"] == (24.0, 20.0)
            assert rig.resends > 0           # faults happened and were absorbed


def test_refusals_are_final_and_name_the_command():
    with FakeController(RigSimulator().handle) as dev:
        with RigDriver(dev.path, timeout=0.5) as rig:
            with pytest.raises(RigRefused, match=r"'ARM 200 0' refused: RANGE") as exc:
                rig.move_arm(200, 0)
            assert exc.value.code == "RANGE" and rig.resends == 0


def test_garbage_device_is_a_clear_error():
    with FakeController(garbage()) as dev:
        with pytest.raises(BTFError, match=r"HELLO failed after 3 tries \(garbled reply.*usdbtf-rig/1 controller"):
            RigDriver(dev.path, timeout=0.5, retries=2).open()


def test_echoing_loopback_is_garbage_not_a_hang():
    # pyserial's loop:// hands back what was written: a request is not a reply.
    with pytest.raises(BTFError, match="garbled reply"):
        RigDriver("loop://", timeout=0.3, retries=1).open()


def test_silent_device_times_out():
    with FakeController(lambda line: None) as dev:
        with pytest.raises(BTFError, match=r"no reply within 0.2 s"):
            RigDriver(dev.path, timeout=0.2, retries=1).open()


def test_garbage_mid_run_after_a_good_greeting():
    sim = RigSimulator()
    junk = garbage(1)
    with FakeController(lambda line: sim.handle(line) if b"HELLO" in line else junk(line)) as dev:
        with RigDriver(dev.path, timeout=0.3, retries=2) as rig:
            with pytest.raises(BTFError, match=r"'HEAD 10 20' failed after 3 tries; last: garbled reply"):
                rig.move_head(10, 20)


def test_stale_replies_are_skipped():
    sim = RigSimulator()
    state = {"n": 0}

    def respond(line):
        # Answer every request twice, the first time with an old seq (a late reply).
        req = P.parse_request(line)
        state["n"] += 1
        return P.encode_reply(max(req.seq - 1, 1) if req.seq > 1 else 65535, True, {"arm": "99,99"}) + sim.handle(line)

    with FakeController(respond) as dev:
        with RigDriver(dev.path, timeout=0.5) as rig:
            assert rig.move_arm(12, 34) == (12.0, 34.0)


def test_unreachable_port():
    with pytest.raises(BTFError, match=r"/nonexistent/tty: cannot open"):
        RigDriver("/nonexistent/tty", reconnect_timeout=0).open()
    with pytest.raises(BTFError, match="rig port"):
        RigDriver("bogus://x", reconnect_timeout=0).open()
