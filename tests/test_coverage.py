"""Partial assets (issue 26): ``compress --coverage`` keeps only the listed views x lights,
``--max-texels`` box-filters the texture side, the folder and the packaged asset record what
they cover (``info``, ``inspect``), and the renderers (CPU; the shared GLSL on Mesa through
EGL, what Storm runs) are exact at covered samples and fall back to the nearest covered
directions outside them.

Real inputs: a synthesised pebbles BTF (13 x 13 directions, 16^2 texels) in memory and as a
manifest folder of PNG files; real folders and USD assets read back.
"""
from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from cli_helpers import bad_input, ok
from compress_helpers import compress_into
from usdbtf.compress import CompressOptions, compress, read_compressed
from usdbtf.compress.coverage import box_mean, shaped_input
from usdbtf.compress.format import cross_layout, reconstruct
from usdbtf.sampling import Coverage, coverage_json, read_coverage
from usdbtf.render import RenderOptions, Renderer
from usdbtf.synth import SynthOptions, synth, write_synth
from usdbtf.usd.read import load_btf

#: Three of the 13 views (the pole and two on the 30 degree ring), three of the 13 lights.
VIEWS = [[0.0, 0.0], [30.0, 0.0], [30.0, 60.0]]
LIGHTS = [[30.0, 30.0], [30.0, 90.0], [60.0, 30.0]]


@pytest.fixture(scope="module")
def pebbles_btf():
    return synth("pebbles", SynthOptions(size=16, sampling="small")).to_btf()


@pytest.fixture(scope="module")
def pebbles_folder(tmp_path_factory):
    folder = tmp_path_factory.mktemp("coverage") / "pebbles"
    write_synth(synth("pebbles", SynthOptions(size=16, sampling="small")), folder)
    return folder


@pytest.fixture(scope="module")
def full_cbtf(pebbles_btf):
    """Every sample, k = every sample, half floats: the reference a partial one must match."""
    return compress(pebbles_btf, CompressOptions(codec="exr", k=169))


@pytest.fixture(scope="module")
def partial_asset(tmp_path_factory, pebbles_btf):
    """The 3 x 3 partial compress of :data:`VIEWS` x :data:`LIGHTS`, packaged."""
    from usdbtf.cli import main

    work = tmp_path_factory.mktemp("partial")
    compress_into(pebbles_btf, work / "c", CompressOptions(codec="exr", k=9, coverage=Coverage(VIEWS, LIGHTS)))
    asset = work / "asset" / "pebbles.usda"
    assert main(["package", str(work / "c"), "-o", str(asset), "--no-thumbnail", "--physical-size", "0.05", "0.05", "-q"]) == 0
    return asset


def _cpu(cbtf):
    return Renderer(cbtf, RenderOptions(shadows=False, filter="bilinear", threads=2))


def covered_indices(sampling, views, lights) -> np.ndarray:
    """Indices of the samples whose view and light are both listed (brute force)."""
    def listed(dirs, wanted):
        return np.array([any(np.allclose(d, w) for w in wanted) for d in dirs])
    return np.flatnonzero(listed(sampling.view, views) & listed(sampling.light, lights))


def test_coverage_keeps_exactly_the_listed_samples_and_reconstructs_them(pebbles_btf, full_cbtf):
    # exr (half floats) and k = the kept samples: the basis spans them, so what is left is
    # the codec's rounding, and a full compress (k = every sample) must agree to that.
    cov = Coverage(VIEWS, LIGHTS)
    part = compress(pebbles_btf, CompressOptions(codec="exr", k=9, coverage=cov))
    idx = covered_indices(pebbles_btf.sampling, VIEWS, LIGHTS)
    assert len(idx) == 9 and part.n_samples == 9 and cross_layout(part.sampling) == (3, 3)
    np.testing.assert_array_equal(part.sampling.view, pebbles_btf.sampling.view[idx])
    np.testing.assert_array_equal(part.sampling.light, pebbles_btf.sampling.light[idx])
    full = full_cbtf
    truth = pebbles_btf.read_samples(idx)
    ours, theirs = reconstruct(part), reconstruct(full, idx)
    scale = float(truth.mean())
    assert np.abs(ours - truth).max() < 0.02 * scale
    assert np.abs(ours - theirs).max() < 0.02 * scale
    rec = part.info["coverage"]
    assert (rec["input_views"], rec["input_lights"], rec["input_samples"]) == (13, 13, 169)
    assert rec["views"] == VIEWS and rec["lights"] == LIGHTS and rec["resolution_factor"] == 1


def test_max_texels_box_filters_in_linear_and_records_the_factor(pebbles_btf):
    # 16 texels, at most 6: factor 3, 6 x 6 boxes, the last column and row one texel wide.
    shaped, rec = shaped_input(pebbles_btf, None, 6)
    assert (shaped.width, shaped.height, rec["resolution_factor"], rec["input_size"]) == (6, 6, 3, [16, 16])
    assert len(rec["views"]) == 13 and len(rec["lights"]) == 13
    src = pebbles_btf.read_samples([0, 50])
    got = shaped.read_samples([0, 50])
    np.testing.assert_allclose(got[:, 0, 0], src[:, :3, :3].mean(axis=(1, 2)), rtol=1e-5)
    np.testing.assert_allclose(got[:, 5, 5], src[:, 15, 15], rtol=1e-5)
    np.testing.assert_allclose(got, box_mean(src, 3), rtol=1e-5)
    # Rows read in pieces give the same values as the whole image.
    np.testing.assert_array_equal(shaped.read_encoded([0, 50], rows=(2, 4)), shaped.read_encoded([0, 50])[:, 2:4])
    out = compress(pebbles_btf, CompressOptions(k=4, max_texels=6))
    assert (out.width, out.height, out.info["coverage"]["resolution_factor"]) == (6, 6, 3)
    assert out.info["provenance"]["options"]["max_texels"] == 6


def test_cli_coverage_folder_records_it_and_is_deterministic(tmp_path, pebbles_folder, capsys):
    path = tmp_path / "cov.json"
    path.write_text(coverage_json(Coverage(np.array(VIEWS) + 0.001, LIGHTS)))    # within the tolerance
    assert read_coverage(path).views.shape == (3, 2)
    for name in ("a", "b"):
        ok(capsys, "compress", pebbles_folder, "-o", tmp_path / name, "--k", "6", "--coverage", path,
           "--max-texels", "8", "-q")
    assert (tmp_path / "a" / "btf-compressed.json").read_bytes() == (tmp_path / "b" / "btf-compressed.json").read_bytes()
    cbtf = read_compressed(tmp_path / "a")
    assert (cbtf.n_samples, cbtf.width, cbtf.height) == (9, 8, 8)
    doc = json.loads((tmp_path / "a" / "btf-compressed.json").read_text())
    assert doc["coverage"]["views"] == VIEWS                   # the input's own directions
    assert doc["coverage"]["resolution_factor"] == 2


def test_box_filtered_bytes_do_not_depend_on_workers_or_memory(tmp_path, pebbles_folder, capsys):
    # 169 samples: decoded by forked workers (2), in this process (1), or streamed in chunks.
    runs = {"w2": ["--workers", "2"], "w1": ["--workers", "1"], "stream": ["--memory-budget", "0.00001"]}
    for name, extra in runs.items():
        ok(capsys, "compress", pebbles_folder, "-o", tmp_path / name, "--k", "6", "--max-texels", "6", "-q", *extra)
    files = sorted(p.relative_to(tmp_path / "w2") for p in (tmp_path / "w2").rglob("*") if p.is_file())
    for name in ("w1", "stream"):
        for rel in files:
            assert (tmp_path / name / rel).read_bytes() == (tmp_path / "w2" / rel).read_bytes(), (name, rel)


def test_cli_coverage_errors_are_one_line(tmp_path, pebbles_folder, capsys):
    bad = tmp_path / "outside.json"
    bad.write_text(json.dumps({"format": "usdbtf-coverage/1", "views": [[0, 0], [45, 0]], "lights": [[30, 30]]}))
    line = bad_input(capsys, "compress", pebbles_folder, "-o", tmp_path / "x", "--coverage", bad, names="outside.json")
    assert "view [45, 0] is not one of the input's 13 view directions" in line
    wrong = tmp_path / "wrong.json"
    wrong.write_text(json.dumps({"format": "usdbtf-coverage/1", "views": [[0, "a"]], "lights": [[30, 30]]}))
    bad_input(capsys, "compress", pebbles_folder, "-o", tmp_path / "x", "--coverage", wrong, names="wrong.json")
    # A link that leads nowhere is named as such, like every JSON input (jsontext.load).
    (tmp_path / "dangling.json").symlink_to(tmp_path / "nowhere.json")
    line = bad_input(capsys, "compress", pebbles_folder, "-o", tmp_path / "x", "--coverage",
                     tmp_path / "dangling.json", names="dangling.json")
    assert "dangling symbolic link (-> " in line and "nowhere.json: no such file)" in line
    assert not (tmp_path / "x").exists()


def test_coverage_round_trips_into_the_asset_info_and_inspect(partial_asset, tmp_path, capsys):
    cbtf = load_btf(partial_asset)
    rec = cbtf.info["coverage"]
    assert rec["views"] == VIEWS and rec["lights"] == LIGHTS
    assert (rec["input_views"], rec["input_lights"], rec["input_samples"], rec["resolution_factor"]) == (13, 13, 169, 1)
    assert rec["input_size"] == [16, 16]
    text = ok(capsys, "inspect", partial_asset)
    assert "coverage     3 of 13 views x 3 of 13 lights (9 of 169 samples)" in text
    entry = json.loads(ok(capsys, "inspect", partial_asset, "--json"))["materials"][0]["coverage"]
    assert entry == {"views": 3, "input_views": 13, "lights": 3, "input_lights": 13, "samples": 9,
                     "input_samples": 169, "resolution": [16, 16], "input_resolution": [16, 16],
                     "resolution_factor": 1}
    # decompress reads the partial asset back: the kept samples only.
    ok(capsys, "decompress", partial_asset, "-o", tmp_path / "back", "-q")
    back = json.loads((tmp_path / "back" / "btf.json").read_text())
    assert len(back["samples"]) == 9
    summary = json.loads(ok(capsys, "info", partial_asset.parent.parent / "c", "--json"))
    assert summary["coverage"]["views"] == 3 and summary["coverage"]["input_samples"] == 169


@pytest.mark.parametrize("name", ["small", "ubo81"])
def test_kept_triangles_of_the_full_set_stay_triangles_of_the_partial_one(name):
    """The README's claim: inside a full-set triangle whose corners are all kept, a partial
    asset interpolates as the full one (Delaunay triangles survive removing other points)."""
    from usdbtf.compress.coverage import unique_directions
    from usdbtf.render.hemisphere import Triangulation
    from usdbtf.sampling import preset

    dirs = unique_directions(preset(name).view)[0]
    full = {tuple(sorted(t)) for t in Triangulation.from_directions(dirs).triangles}
    rng = np.random.default_rng(0)
    checked = 0
    for _ in range(10):
        keep = np.sort(rng.choice(len(dirs), size=len(dirs) // 2, replace=False))
        partial = {tuple(sorted(keep[list(t)])) for t in Triangulation.from_directions(dirs[keep]).triangles}
        wanted = [t for t in full if set(t) <= set(keep.tolist())]
        assert all(t in partial for t in wanted)
        checked += len(wanted)
    assert checked > 10


def test_stencil_names_the_directions_a_query_interpolates_from():
    from usdbtf.render.hemisphere import Triangulation, directions_to_vectors
    from usdbtf.sampling import rings

    dirs = rings((0, 30, 60), (1, 6, 6))                      # the pole, then two rings of 6
    tri = Triangulation.from_directions(dirs)
    assert np.flatnonzero(tri.stencil(directions_to_vectors([[30, 60]]))).tolist() == [2]
    # (15, 30) lies in the fan triangle of the pole, (30, 0) and (30, 60).
    assert np.flatnonzero(tri.stencil(directions_to_vectors([[15, 30]]))).tolist() == [0, 1, 2]
    # Beyond the outer ring at an azimuth of a measured direction: that direction alone.
    assert np.flatnonzero(tri.stencil(directions_to_vectors([[80, 120]]))).tolist() == [9]


def test_cpu_renderer_is_exact_inside_the_coverage_and_nearest_outside(partial_asset, full_cbtf):
    part, full = _cpu(load_btf(partial_asset)), _cpu(full_cbtf)
    scale = float(full.swatch((0, 0), (30, 30)).mean())
    for view in VIEWS:
        for light in LIGHTS:
            np.testing.assert_allclose(part.swatch(view, light), full.swatch(view, light), atol=0.02 * scale)
    # A view beyond the covered ones: its nearest covered point is the covered view (30, 0)
    # (on the disc of the azimuthal projection, module usdbtf.render.hemisphere).
    light = LIGHTS[0]
    np.testing.assert_allclose(part.swatch((60, 0), light), part.swatch((30, 0), light), rtol=1e-6)
    assert np.abs(full.swatch((60, 0), light) - part.swatch((60, 0), light)).mean() > 0.02 * scale   # a fallback
    # A light beyond the covered ones: the nearest covered light (60, 30), faded by the
    # foreshortening cos 75 / cos 60, as beyond a full asset's outermost ring.
    fade = np.cos(np.radians(75)) / np.cos(np.radians(60))
    np.testing.assert_allclose(part.swatch(VIEWS[1], (75, 30)), fade * part.swatch(VIEWS[1], (60, 30)), rtol=1e-5)


def test_glsl_path_matches_the_cpu_renderer_on_a_partial_asset(partial_asset):
    pytest.importorskip("moderngl", reason="moderngl not installed (pip install -e '.[test]')")
    from usdbtf.errors import BTFError
    from usdbtf.gpu.headless import HeadlessRenderer, create_context, psnr
    from usdbtf.usd.asset import storm

    try:
        ctx = create_context()
    except BTFError as exc:
        pytest.skip(f"no headless OpenGL here: {exc}")
    try:
        layout, wrap, _ = storm.layout_from_asset(partial_asset)
        gl = HeadlessRenderer(layout, wrap=wrap, ctx=ctx)
        cpu = _cpu(load_btf(partial_asset))
        cases = [(VIEWS[1], LIGHTS[2]), (VIEWS[0], LIGHTS[1]), ((60, 0), LIGHTS[0]), ((20, 30), (0, 0)),
                 (VIEWS[2], (75, 30)), ((80, 200), (70, 250))]
        values = [psnr(gl.swatch(v, l), cpu.swatch(v, l)) for v, l in cases]
        print("partial-asset swatch PSNR (dB):", ", ".join(f"{v:.1f}" for v in values))
        assert min(values) >= 40.0
        # Outside the coverage the GPU falls back to the same covered view as the CPU.
        assert psnr(gl.swatch((60, 0), LIGHTS[0]), gl.swatch((30, 0), LIGHTS[0])) >= 60.0
    finally:
        ctx.release()


def _scene(asset, out, view, light, distance=10.0, fov=1.0, size=32):
    """A stage referencing ``asset`` with a camera ``distance`` metres away seeing its swatch
    from the local direction ``view`` and a distant light from ``light`` ((theta, phi)
    degrees, the swatch's tangent frame).  Returns the camera's prim path."""
    from usdbtf.camera import Camera
    from usdbtf.mesh import load_prim
    from usdbtf.render import Light
    from usdbtf.usd.read import open_stage
    from usdbtf.usd.scenes.scene import write_scene
    from pxr import UsdGeom

    stage = open_stage(asset)
    mesh = next(load_prim(p) for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)).corner_frames()
    t, b, n = mesh.tangents[0, 0], mesh.bitangents[0, 0], mesh.normals[0, 0]
    centre = mesh.points.reshape(-1, 3).mean(axis=0)

    def world(direction):
        theta, phi = np.radians(direction)
        return np.sin(theta) * (np.cos(phi) * t + np.sin(phi) * b) + np.cos(theta) * n

    camera = Camera(centre + distance * world(view), centre, n, fov, size, size)
    return write_scene(asset, out, camera, [Light("directional", world(light))])


def test_validate_warns_when_the_scene_asks_for_directions_outside_the_coverage(partial_asset, tmp_path, capsys):
    from usdbtf.usd.scenes.reach import coverage_warnings
    from usdbtf.usd.read import open_stage

    # Inside: the view (15, 30) lies in the full set's triangle pole, (30, 0), (30, 60), all
    # kept; the light is the kept (30, 30) itself.
    inside = tmp_path / "inside.usda"
    _scene(partial_asset, inside, (15, 30), (30, 30))
    assert coverage_warnings(open_stage(inside)) == []
    # Outside: view (45, 180) and light (45, 200) need directions that were not kept.
    outside = tmp_path / "outside.usda"
    _scene(partial_asset, outside, (45, 180), (45, 200))
    lines = coverage_warnings(open_stage(outside))
    assert len(lines) == 2, lines
    assert "camera /World/Camera asks for view directions outside" in lines[0] and "e.g. theta 45.0, phi 1" in lines[0]
    assert "light /World/Light0 asks for light directions outside" in lines[1]
    # Through the command: a warning, not an error (exit status 0).
    report = json.loads(ok(capsys, "inspect", outside, "--validate", "--json"))["validation"]
    assert report["errors"] == [] and sum("[usdbtf:Coverage]" in w for w in report["warnings"]) == 2


def test_validate_samples_the_frames_of_a_moving_camera(partial_asset, tmp_path):
    from pxr import Usd, UsdGeom

    from usdbtf.usd.scenes.reach import coverage_warnings, sample_times
    from usdbtf.usd.read import open_stage

    moving, outside = tmp_path / "moving.usda", tmp_path / "outside.usda"
    camera = _scene(partial_asset, moving, (15, 30), (30, 30))
    _scene(partial_asset, outside, (45, 180), (30, 30))
    other = Usd.Stage.Open(str(outside))
    far = UsdGeom.Xformable(other.GetPrimAtPath(camera)).GetOrderedXformOps()[0].Get()
    stage = Usd.Stage.Open(str(moving))
    op = UsdGeom.Xformable(stage.GetPrimAtPath(camera)).GetOrderedXformOps()[0]
    op.Set(op.Get(), 1.0)              # frame 1 as before, frame 24 from the uncovered side
    op.Set(far, 24.0)
    stage.SetStartTimeCode(1.0)
    stage.SetEndTimeCode(24.0)
    stage.Save()
    reopened = open_stage(moving)
    assert [t.GetValue() for t in sample_times(reopened)][::7] == [1.0, 24.0]
    lines = coverage_warnings(reopened)
    assert len(lines) == 1 and "camera /World/Camera asks for view directions" in lines[0], lines
    assert "at frame " in lines[0] and "default time" not in lines[0]


def test_storm_renders_a_partial_asset_as_the_cpu_renderer_does(partial_asset, tmp_path):
    """Real Storm (the bpy wheel's USD, when scripts/bootstrap.sh installed it) on a stage
    whose camera and light lie outside the coverage: the same fallback as `usdbtf render`."""
    from storm_helpers import against_cpu_render
    from usdbtf.errors import BTFError
    from usdbtf.usd.preview import hydra

    pythons = hydra.storm_pythons()
    if not pythons:
        pytest.skip("no Storm environment (scripts/bootstrap.sh installs the bpy wheels)")
    scene = tmp_path / "scene.usda"
    camera = _scene(partial_asset, scene, (45, 170), (50, 200), distance=0.5, fov=8.0, size=64)
    try:
        storm = hydra.render_frames(pythons[sorted(pythons)[0]], [(scene, tmp_path / "storm.exr")], camera, (64, 64))
    except BTFError as exc:
        pytest.skip(f"Storm cannot run here: {exc}")
    assert storm.problems == [], "\n".join(storm.problems)
    value, both, _ = against_cpu_render(storm.images[0], scene, camera, 64, tmp_path)
    assert both.sum() > 0.2 * both.size
    print(f"partial asset outside its coverage: Storm vs usdbtf render {value:.2f} dB (sRGB)")
    assert value >= 35.0


@pytest.mark.parametrize("views, lights", [
    ([[0, 0]], [[30, 30], [30, 90]]),                       # one view; two lights: a segment, no triangle
    ([[0, 0], [30, 0], [60, 0]], [[60, 30]]),               # three views on a line; one light
])
def test_degenerate_coverages_render_on_cpu_and_glsl_alike(pebbles_btf, views, lights):
    pytest.importorskip("moderngl", reason="moderngl not installed (pip install -e '.[test]')")
    from usdbtf.errors import BTFError
    from usdbtf.gpu.headless import HeadlessRenderer, create_context, psnr
    from usdbtf.gpu.tables import gpu_layout

    part = compress(pebbles_btf, CompressOptions(codec="exr", k=2, domain="linear",
                                                 coverage=Coverage(views, lights)))
    cpu = _cpu(part)
    if len(lights) == 2:
        # Between the two lights: the middle of the chord joining them on the disc, half of
        # each, faded by cos 30 / cos(theta of that point) as beyond any measured boundary.
        used = 30.0 * np.cos(np.radians(30))      # the middle of a chord spanning 60 deg at theta 30
        fade = np.cos(np.radians(30)) / np.cos(np.radians(used))
        np.testing.assert_allclose(cpu.swatch((10, 0), (30, 60)), fade * 0.5 * (
            cpu.swatch((10, 0), (30, 30)) + cpu.swatch((10, 0), (30, 90))), rtol=1e-4)
    try:
        ctx = create_context()
    except BTFError as exc:
        pytest.skip(f"no headless OpenGL here: {exc}")
    try:
        gl = HeadlessRenderer(gpu_layout(part), wrap="clamp", ctx=ctx)
        cases = [((0, 0), (30, 30)), ((45, 100), (10, 200)), ((70, 300), (80, 60)), ((20, 0), (45, 60))]
        assert min(psnr(gl.swatch(v, l), cpu.swatch(v, l)) for v, l in cases) >= 40.0
    finally:
        ctx.release()


def test_coverage_for_directions_never_warns_for_them():
    """coverage_for (the library's smallest coverage for given directions) and the check's side
    (coverage_warnings' test) agree: the coverage made for some directions renders every one of
    them as the full input does.  (The plan keeps a superset: test_scene_aware.)"""
    from usdbtf.render.hemisphere import directions_to_vectors
    from usdbtf.sampling import preset
    from usdbtf.compress.coverage import unique_directions
    from usdbtf.usd.scenes.reach import CoverageCheck, coverage_for

    sampling = preset("ubo81")
    views, lights = unique_directions(sampling.view)[0], unique_directions(sampling.light)[0]
    rng = np.random.default_rng(1)
    asked_v = directions_to_vectors(np.c_[rng.uniform(0, 50, 40), rng.uniform(0, 120, 40)])
    asked_l = directions_to_vectors([[35.0, 200.0]])                  # one fixed key light
    cov = coverage_for(views, lights, asked_v, asked_l)
    assert 3 <= len(cov.views) < len(views) and 1 <= len(cov.lights) <= 3
    assert not CoverageCheck(views, cov.views.tolist()).missing(asked_v).any()
    assert not CoverageCheck(lights, cov.lights.tolist()).missing(asked_l).any()
    elsewhere = directions_to_vectors([[60.0, 300.0]])
    assert CoverageCheck(views, cov.views.tolist()).missing(elsewhere).all()
    assert coverage_for(views, lights, asked_v, np.zeros((0, 3))) is None


def test_a_shaped_compress_keeps_the_full_builds_working_domain():
    """Issue 41: with ``--domain auto`` a scene-shaped compress works in the domain a full compress
    of the input chooses (scored on the whole input), not in the one its few directions would
    pick: metal_flakes (32 texels, small sampling) chooses x^(1/3) whole (sRGB before that curve
    was a candidate), linear on three views by three lights alone."""
    from usdbtf.compress.core import full_input_domain
    from usdbtf.compress.coverage import unique_directions

    btf = synth("metal_flakes", SynthOptions(size=32, sampling="small")).to_btf()
    opts = CompressOptions(k=4, codec="png")
    views, _ = unique_directions(btf.sampling.view)
    lights, _ = unique_directions(btf.sampling.light)
    coverage = Coverage(views[:3], lights[-3:])
    alone, _ = shaped_input(btf, coverage, None)
    assert full_input_domain(btf, opts)[0].name == "gamma:3" and full_input_domain(alone, opts)[0].name == "linear"
    shaped = compress(btf, replace(opts, coverage=coverage))
    assert shaped.domain.name == "gamma:3" and shaped.info["choice"]["domain_scored_on"].startswith("the full input")
    assert compress(btf, replace(opts, coverage=coverage, domain="linear")).domain.name == "linear"   # as asked
