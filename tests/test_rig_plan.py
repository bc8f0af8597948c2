"""Capture plans: kinematics, the arm obstruction model, travel-minimising order, the
journal's crash rules, and the paper preset the capture defaults to."""
from __future__ import annotations

import json

import numpy as np
import pytest

from usdbtf.errors import BTFError
from usdbtf.rig import kinematics as K
from usdbtf.rig.journal import Journal
from usdbtf.rig.plan import ArmGeometry, arm_travel, make_plan, obstructed
from usdbtf.sampling import preset, to_vectors


def test_paper_preset_is_90_views_at_20_deg_and_120_lights_at_15_deg():
    s = preset("paper")
    views, lights = np.unique(s.view, axis=0), np.unique(s.light, axis=0)
    assert len(s) == 90 * 120 and len(views) == 90 and len(lights) == 120
    for dirs, step in ((views, 20.0), (lights, 15.0)):
        for theta in np.unique(dirs[:, 0]):
            phis = np.sort(dirs[dirs[:, 0] == theta, 1])
            assert np.allclose(np.diff(phis), step) and len(phis) == 360 / step


def test_kinematics_put_the_view_on_the_camera_axis_and_invert():
    s = preset("paper")
    head = K.head_for_view(s.view)
    cam = np.einsum("nij,nj->ni", K.rotation(head), to_vectors(s.view))
    assert np.allclose(cam, [0, 0, 1], atol=1e-12)
    assert np.allclose(K.view_for_head(head), s.view, atol=1e-9)
    arm = K.arm_for_light(head, s.light)
    back = K.light_for_arm(head, arm)
    d = np.abs(back - s.light)
    d[:, 1] = np.minimum(d[:, 1], 360 - d[:, 1])
    assert d.max() < 1e-9
    # Rotations preserve angles: light-to-view angle = arm angle from the camera axis.
    assert np.allclose(arm[:, 0], K.angle_between(to_vectors(s.view), to_vectors(s.light)))


def test_obstruction_geometry():
    g = ArmGeometry()
    head = np.zeros((4, 2))
    # LED on the camera axis, 3 deg off it, 40 deg off it (on the side away from the
    # shoulder), and straight behind the sample: only the first two block the view.
    arm = np.array([[0.0, 0.0], [3.0, 180.0], [40.0, 180.0], [170.0, 0.0]])
    assert obstructed(head, arm, g).tolist() == [True, True, False, False]
    # The link to the shoulder (camera's right, behind) crosses the view when the LED is
    # on the far left in front of the sample.
    assert obstructed(np.zeros((1, 2)), np.array([[60.0, 180.0]]), ArmGeometry(shoulder_m=(0.9, 0.0, 0.0)))[0]


def test_paper_plan_obstructs_a_small_part_and_orders_for_less_travel():
    s = preset("paper")
    plan = make_plan(s)
    naive = make_plan(s, ordering="sampling")
    frac = plan.obstructed.mean()
    assert 0.01 < frac < 0.08
    assert sorted(plan.order.tolist()) == np.flatnonzero(~plan.obstructed).tolist()
    assert plan.arm_travel_deg() < 0.95 * naive.arm_travel_deg()
    assert plan.head_travel_deg() < 0.9 * naive.head_travel_deg()
    # One head move per view: views are never revisited.
    heads = np.round(plan.head[plan.order], 6)
    changes = 1 + np.count_nonzero(np.any(heads[1:] != heads[:-1], axis=1))
    assert changes == len(np.unique(heads, axis=0)) == 90
    assert plan.fingerprint() == make_plan(s).fingerprint() != naive.fingerprint()


def test_arm_travel_of_a_known_path():
    # Along the equator in 15 deg steps, then up to the pole.
    path = np.array([[90.0, 0.0], [90.0, 15.0], [90.0, 30.0], [0.0, 0.0]])
    assert arm_travel(path) == pytest.approx(120.0)


def test_no_obstruction_model_shoots_everything():
    plan = make_plan(preset("small"), geometry=None)
    assert not plan.obstructed.any() and len(plan.order) == 169


# -- journal ----------------------------------------------------------------------------------
def test_journal_resumes_and_cuts_a_torn_tail(tmp_path):
    path = tmp_path / "journal.jsonl"
    j = Journal(path, "abc")
    j.append({"shot": 3, "image": "frames/a.tif", "frame": 1})
    j.append({"shot": 5, "image": "frames/b.tif", "frame": 2})
    j.close()
    with open(path, "ab") as fh:
        fh.write(b'{"shot": 7, "ima')            # killed mid-append
    j = Journal(path, "abc")
    assert j.resumed and sorted(j.shots) == [3, 5]
    assert path.read_bytes().endswith(b"}\n")
    j.append({"shot": 7, "image": "frames/c.tif", "frame": 3})
    j.close()
    assert sorted(Journal(path, "abc").shots) == [3, 5, 7]


def test_journal_refuses_another_plan_damage_and_duplicates(tmp_path):
    path = tmp_path / "journal.jsonl"
    Journal(path, "abc").close()
    with pytest.raises(BTFError, match="different capture plan"):
        Journal(path, "xyz")
    lines = [json.dumps({"journal": "usdbtf-capture/1", "plan": "abc"}), "{broken", json.dumps({"shot": 1, "image": "x"})]
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(BTFError, match="line 2 is damaged"):
        Journal(path, "abc")
    lines[1] = json.dumps({"shot": 1, "image": "x"})
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(BTFError, match="sample 1 is recorded twice"):
        Journal(path, "abc")


def test_simulator_draws_the_arm_exactly_where_the_plan_says_it_hides_the_sample():
    import cv2

    from usdbtf.fiducials import make_board
    from usdbtf.camera import Camera
    from usdbtf.rig.scene import frame_homography, render_frame, texture_homography

    board = make_board()
    cam = Camera.framing(board, 320, 240)
    plan = make_plan(preset("small"))
    texture = np.full((8, 8, 3), 0.5, np.float32)
    for i in sorted(set(np.flatnonzero(plan.obstructed)) | set(plan.order[::4])):
        head, arm, light = plan.head[i], plan.arm[i], plan.sampling.light[i]
        clean = render_frame(board, texture, head, light, cam, supersample=1)
        with_arm = render_frame(board, texture, head, light, cam, supersample=1, arm=(arm, ArmGeometry()))
        # The fraction of the sample window the drawn arm covers.
        h = frame_homography(board, head, cam) @ texture_homography(board, 8)
        quad = np.array([[0, 0], [8, 0], [8, 8], [0, 8]], float)
        q = h @ np.c_[quad, np.ones(4)].T
        mask = np.zeros((240, 320), np.uint8)
        cv2.fillConvexPoly(mask, np.round((q[:2] / q[2]).T - 0.5).astype(np.int32), 1)
        covered = (np.abs(with_arm - clean).max(axis=2)[mask > 0] > 0.1).mean()
        # The model casts 9 rays to the window, so it can miss an arm that only grazes an edge.
        if plan.obstructed[i]:
            assert covered > 0.02, (i, covered)
        else:
            assert covered < 0.05, (i, covered)
