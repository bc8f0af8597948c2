"""Capture against the simulator, as real processes over real links.

Every run is compared with one uninterrupted reference capture of the same plan: the
simulator seeds each frame's noise by its tag, so a correct resume reproduces the
reference byte for byte (0 lost, 0 duplicated, nothing shot at the wrong position).
"""
from __future__ import annotations

import json
import signal
import subprocess

import numpy as np
import pytest
from rig_helpers import (ENV, FakeController, Sim, capture_cmd, free_port, garbage, journal_shots, run_capture,
                         tree_bytes, wait_for)

from usdbtf.manifest import read_manifest
from usdbtf.rig.plan import make_plan
from usdbtf.sampling import preset

PLAN = make_plan(preset("tiny"))


def _result(raw):
    """Everything a capture leaves that must not depend on interruptions."""
    files = tree_bytes(raw)
    files.pop("journal.jsonl")
    return files


def _journal_shot_indices(raw) -> list:
    lines = (raw / "journal.jsonl").read_text().splitlines()
    return [json.loads(line)["shot"] for line in lines if '"shot"' in line]


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    base = tmp_path_factory.mktemp("reference")
    sim = Sim(base / "frames")
    try:
        done = run_capture(sim.url, base / "RAW", base / "frames")
    finally:
        sim.kill()
    assert done.returncode == 0, done.stderr
    return base / "RAW"


def check_same_as_reference(raw, reference):
    shots = _journal_shot_indices(raw)
    assert len(shots) == len(set(shots)) == len(PLAN.order)          # 0 duplicated
    assert sorted(shots) == sorted(PLAN.order.tolist())              # 0 lost
    got, want = _result(raw), _result(reference)
    assert sorted(got) == sorted(want)                               # no stray or missing files
    for name in want:
        assert got[name] == want[name], name


def test_reference_capture_is_a_raw_manifest(reference):
    btf = read_manifest(reference)
    doc = json.loads((reference / "btf.json").read_text())
    assert btf.n_samples == len(PLAN.order) == 24 and (btf.width, btf.height) == (160, 120)
    assert btf.bit_depth == "uint16" and btf.color_space == "sRGB Encoded Rec.709 (sRGB)"
    info = doc["raw_capture"]
    assert info["flat_field"] == "flat.exr" and info["sampling"] == "tiny" and info["rig"]["model"] == "usdbtf-sim"
    assert np.allclose(info["plan"]["view"], PLAN.sampling.view) and doc["missing"] == []
    # Samples are in plan order with their view/light; each frame was shot where asked.
    assert [s["index"] for s in doc["samples"]] == list(range(24))
    frame = btf.read_samples([5])[0]
    assert frame.shape == (120, 160, 3) and 0.0 < frame.mean() < 1.0
    # Journal order is the travel-minimising order of the plan.
    assert _journal_shot_indices(reference) == PLAN.order.tolist()


def test_kill_9_and_resume_loses_and_duplicates_nothing(reference, tmp_path):
    sim = Sim(tmp_path / "frames", "--speed", "3000")
    raw = tmp_path / "RAW"
    try:
        for stop_at in (4, 13):
            proc = subprocess.Popen(capture_cmd(sim.url, raw, tmp_path / "frames", "-q"), env=ENV,
                                    stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
            assert wait_for(lambda: journal_shots(raw) >= stop_at or proc.poll() is not None)
            proc.send_signal(signal.SIGKILL)
            proc.wait(10)
            proc.stderr.close()
            assert proc.returncode == -signal.SIGKILL
            assert not (raw / "btf.json").exists() and journal_shots(raw) < len(PLAN.order)
        done = run_capture(sim.url, raw, tmp_path / "frames")
    finally:
        sim.kill()
    assert done.returncode == 0, done.stderr
    assert "resuming" in done.stderr
    check_same_as_reference(raw, reference)
    # A finished capture re-run is a no-op that rewrites the same manifest.
    again = run_capture("socket://127.0.0.1:9", raw, tmp_path / "frames")
    assert again.returncode == 0, again.stderr
    check_same_as_reference(raw, reference)


@pytest.mark.parametrize("link", ["socket", "pty"])
def test_link_drops_reconnect_and_resume(reference, tmp_path, link):
    # The link is cut after every 11th request, after executing it and before replying, and
    # the controller forgets its positions (a power cycle): the capture must re-home them.
    args = ["--drop-every", "11", "--reset-on-drop"]
    if link == "pty":
        sim = Sim(tmp_path / "frames", *args, "--link", tmp_path / "rig0", listen=None)
        assert sim.url == str(tmp_path / "rig0")
    else:
        sim = Sim(tmp_path / "frames", *args)
    try:
        done = run_capture(sim.url, tmp_path / "RAW", tmp_path / "frames")
    finally:
        sim.kill()
    assert done.returncode == 0, done.stderr
    assert "dropped" in done.stderr and "restored" in done.stderr and "moving again" in done.stderr
    reconnects = int(done.stderr.split(" reconnects")[0].rsplit("(", 1)[1])
    assert reconnects >= 6
    check_same_as_reference(tmp_path / "RAW", reference)


def test_controller_killed_and_restarted_mid_capture(reference, tmp_path):
    port = free_port()
    listen = f"127.0.0.1:{port}"
    raw = tmp_path / "RAW"
    sim = Sim(tmp_path / "frames", "--speed", "3000", listen=listen)
    proc = subprocess.Popen(capture_cmd(sim.url, raw, tmp_path / "frames"), env=ENV, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    try:
        assert wait_for(lambda: journal_shots(raw) >= 8)
        sim.kill()                                  # the controller dies: the link is gone
        sim = Sim(tmp_path / "frames", listen=listen)
        _, err = proc.communicate(timeout=120)
    finally:
        sim.kill()
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert "restored" in err
    check_same_as_reference(raw, reference)


def test_lost_and_garbled_replies_are_resent(reference, tmp_path):
    sim = Sim(tmp_path / "frames", "--fault-rate", "0.08", "--seed", "0")
    try:
        done = run_capture(sim.url, tmp_path / "RAW", tmp_path / "frames", "--timeout", "0.3", "--move-timeout", "0.3",
                           "--retries", "8")
    finally:
        sim.kill()
    assert done.returncode == 0, done.stderr
    resends = int(done.stderr.split(" resends")[0].rsplit(", ", 1)[1])
    assert resends >= 3
    check_same_as_reference(tmp_path / "RAW", reference)


def test_opencv_camera_source(tmp_path):
    # cv2.VideoCapture reads the simulator's latest frame file after every trigger.
    sim = Sim(tmp_path / "frames")
    try:
        cmd = capture_cmd(sim.url, tmp_path / "RAW", tmp_path / "frames")
        cmd[cmd.index("--camera-cmd"):cmd.index("--camera-cmd") + 2] = ["--camera", str(tmp_path / "frames" / "latest.tif")]
        done = subprocess.run(cmd, capture_output=True, text=True, env=ENV, timeout=120)
    finally:
        sim.kill()
    assert done.returncode == 0, done.stderr
    btf = read_manifest(tmp_path / "RAW")
    assert btf.bit_depth == "uint8" and btf.n_samples == 24
    # Each stored frame is the simulator's frame for that sample (8-bit of the 16-bit one).
    from usdbtf.imageio import read_image
    for i in (0, 11, 23):
        mine, _ = read_image(btf.paths[i])
        theirs, _ = read_image(tmp_path / "frames" / f"s{i:05d}.tif")
        # OpenCV scales 16 to 8 bits by 1/256 with rounding: within 1.5 codes of /257.
        assert np.abs(mine.astype(int) - theirs.astype(int) / 257.0).max() <= 1.5


def _one_error_line(done, *needles):
    assert done.returncode == 65, (done.returncode, done.stderr)
    lines = done.stderr.strip().splitlines()
    assert lines[-1].startswith("usdbtf capture: error: "), done.stderr
    for n in needles:
        assert n in lines[-1], lines[-1]
    return lines[-1]


def test_garbage_serial_replies_exit_65(tmp_path):
    with FakeController(garbage()) as dev:
        done = run_capture(dev.path, tmp_path / "RAW", tmp_path / "frames", "-q", "--retries", "2",
                           "--timeout", "0.3")
    _one_error_line(done, dev.path, "garbled reply", "HELLO failed")
    assert len(done.stderr.strip().splitlines()) == 1


def test_bad_frames_and_hooks_exit_65(tmp_path):
    sim = Sim(tmp_path / "frames")
    try:
        bad = tmp_path / "bad.tif"
        bad.write_bytes(b"II*\x00" + b"\x00" * 40)
        cmd = capture_cmd(sim.url, tmp_path / "RAW", tmp_path / "frames", "-q")
        at = cmd.index("--camera-cmd") + 1
        cmd[at] = f"cp {bad} {{out}}"
        line = _one_error_line(subprocess.run(cmd, capture_output=True, text=True, env=ENV, timeout=60), "flat00")
        assert "cannot read image" in line or "corrupt" in line
        cmd[at] = "false {out}"
        _one_error_line(subprocess.run(cmd, capture_output=True, text=True, env=ENV, timeout=60),
                        "camera command false failed for flat00 (exit 1)")
        cmd[at] = "true {out}"
        _one_error_line(subprocess.run(cmd, capture_output=True, text=True, env=ENV, timeout=60),
                        "did not write")
    finally:
        sim.kill()
    assert not (tmp_path / "RAW" / "btf.json").exists()
