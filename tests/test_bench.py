"""The benchmark suite (``usdbtf bench``): its smallest configuration end to end, and the
pieces whose mistakes would make its numbers wrong (held-out split and interpolation,
Pareto fronts, slope fits, configuration handling).

The end-to-end run really times subprocesses (``usdbtf compress``, the JPEG / per-view PCA /
video baselines), reads their outputs back and evaluates them against the synthetic truth;
the assertions are on properties every correct run has (error falls and bytes grow with k,
PSNR agrees with RMSE, the renderer reproduces equation 2 at measured directions, ...) and,
at this tiny sampling where predicting a missing light dominates, held-out error at least the
fitted error -- not on timings.
"""
from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest

from usdbtf.bench.baselines import ffmpeg_x265
from usdbtf.bench.heldout import blend_rows, neighbour_weights, split_lights
from usdbtf.bench.report import affine_fit, loglog_slope, pareto_mask, pooled_loglog_slope
from usdbtf.bench.sections import PLANNED, discover, missing_modules
from usdbtf.bench.suite import CONFIGS
from usdbtf.cli import main
from usdbtf.compress.format import cross_layout
from usdbtf.sampling import Sampling, preset, to_vectors


def read_csv(path) -> list:
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    for r in rows:
        for key, v in r.items():
            try:
                r[key] = float(v) if v not in ("", "True", "False") else {"": None, "True": True, "False": False}[v]
            except ValueError:
                pass
    return rows


@pytest.fixture(scope="module")
def smoke(tmp_path_factory):
    """One `usdbtf bench --smoke` run (in-process CLI, real subprocesses underneath)."""
    root = tmp_path_factory.mktemp("bench")
    out = root / "out"
    code = main(["bench", "--smoke", "-o", str(out), "--workdir", str(root / "data")])
    return code, out


# ------------------------------------------------------------------ end to end


def test_smoke_run_writes_report_tables_and_plots(smoke):
    code, out = smoke
    assert code == 0
    doc = json.loads((out / "results.json").read_text())
    assert doc["status"] == "ok"
    ready = {name for name, section in discover().items() if not missing_modules(section)}
    assert {"compress", "scaling"} <= ready and set(doc["sections"]) == ready
    report = (out / "report.md").read_text()
    assert "## machine" in report and "CPU:" in report and "BLAS" in report
    assert "usdbtf bench --smoke" in report
    # Sections whose stage has not landed are listed as pending, not silently dropped.
    for name, (module, _) in PLANNED.items():
        if name not in discover():
            assert f"`{name}`: pending: module {module} not present" in report
    for name in ("compress/pebbles-tiny-32.png", "scaling/scaling.png"):
        data = (out / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000, name
    # Each measured output is deleted once evaluated (only the quilt/render sources remain).
    assert not (out / "stored" / "pebbles-tiny-32").exists() or not any((out / "stored" / "pebbles-tiny-32").iterdir())
    assert not (out / "stored" / "scaling").exists() or not any((out / "stored" / "scaling").iterdir())


def test_smoke_modes_table_puts_every_mode_against_the_floor_and_the_paper(smoke):
    """Issue 27: the modes section times each way of asking compress, against the floor and
    the paper baseline measured in the same run, and the budget modes get the paper's requests."""
    _, out = smoke
    rows = {r["method"]: r for r in read_csv(out / "modes.csv")}
    paper = rows.pop("paper/jpeg")
    assert paper["status"] == "ok" and paper["vs_paper"] == 1.0
    assert [m.split()[1] for m in rows] == ["--k", "--k", "--max-bytes", "--target-error"]
    for label, r in rows.items():
        assert r["status"] == "ok", label
        assert r["floor_s"] > 0 and abs(r["x_floor"] - r["wall_s"] / r["floor_s"]) < 1e-6 * r["x_floor"]
        assert abs(r["vs_paper"] - r["fit_percent"] / paper["fit_percent"]) < 1e-6
        # Issue 42: each mode's own floor (decode + a GEMM as wide as its k + one encode of what it wrote).
        assert r["encode_s"] > 0 and r["gemm_k_s"] > 0 and r["cpu_s"] > 0
        assert r["own_floor_s"] > r["encode_s"] + r["gemm_k_s"]      # plus the decode pass
        assert abs(r["x_own_floor"] - r["wall_s"] / r["own_floor_s"]) < 1e-6 * r["x_own_floor"]
        # The same floor in CPU seconds (decode workers, GEMM threads, codec workers), beside the mode's CPU.
        assert r["own_floor_cpu_s"] > 0 and abs(r["x_own_floor_cpu"] - r["cpu_s"] / r["own_floor_cpu_s"]) \
            < 1e-6 * r["x_own_floor_cpu"]
    budget = next(r for m, r in rows.items() if "--max-bytes" in m)
    assert f"--max-bytes {int(paper['stored_bytes'])}" in budget["method"]
    # The asset's budget (the default) where the paper's bytes hold what packaging adds; at this
    # tiny sampling and size they do not, and the row budgets the folder, saying so.
    assert budget["method"].endswith("--budget-for folder") and budget["asset_bytes"] is None
    assert budget["stored_bytes"] <= paper["stored_bytes"]
    # --target-error leaves the asset's count to `usdbtf package` (issue 42): the bench packages it.
    target = next(r for m, r in rows.items() if "--target-error" in m)
    assert target["asset_bytes"] > target["stored_bytes"] > 0
    # Quick entropy coding (the default for a plain k) stores the same values in more bytes.
    quick, full = (r for m, r in rows.items() if m.startswith("compress --k"))
    assert quick["fit_percent"] == full["fit_percent"] and quick["stored_bytes"] > full["stored_bytes"]
    data = (out / "modes/pebbles-tiny-32.png").read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"


def test_smoke_compress_table_is_sane(smoke):
    _, out = smoke
    rows = read_csv(out / "compress.csv")
    cfg = CONFIGS["smoke"]
    ok = [r for r in rows if r["status"] == "ok"]
    ref = [r for r in rows if r["family"] == "original"]
    assert len(ref) == 1 and ref[0]["fit_percent"] == 0.0 and ref[0]["held_percent"] > 0
    # 4 views x 6 lights, 20 % of the lights held out -> one light: 20 fitted, 4 held out.
    assert {(r["n_fit"], r["n_heldout"]) for r in rows} == {(20, 4)}
    for solver, codec in cfg.solver_codecs:
        sweep = sorted((r for r in ok if r["method"] == f"{solver}/{codec}"), key=lambda r: r["param"])
        assert [r["param"] for r in sweep] == list(cfg.ks)
        assert [r["k_stored"] for r in sweep] == list(cfg.ks)
        fit = [r["fit_percent"] for r in sweep]
        size = [r["stored_bytes"] for r in sweep]
        assert all(a > b for a, b in zip(fit, fit[1:])), (solver, fit)        # error falls with k
        assert all(a < b for a, b in zip(size, size[1:])), (solver, size)     # bytes grow with k
    pca = sorted((r for r in ok if r["family"] == "pca-view"), key=lambda r: r["param"])
    assert len(pca) == 2 and pca[0]["fit_percent"] > pca[1]["fit_percent"]
    assert pca[0]["stored_bytes"] < pca[1]["stored_bytes"]
    jpeg = [r for r in ok if r["family"] == "jpeg"]
    assert len(jpeg) == 1 and 0.5 < jpeg[0]["fit_percent"] < 20          # q90: a few percent, never lossless
    video = [r for r in rows if r["family"] == "video"]
    assert len(video) == 1
    exe, why = ffmpeg_x265()
    if exe:
        assert video[0]["status"] == "ok", video[0]["status"]
    else:                                   # no ffmpeg/libx265 here: the row says why, the run goes on
        assert video[0]["status"] == f"skipped: {why}"
    for r in ok:
        assert r["held_percent"] >= r["fit_percent"], r["method"]
        assert 0 < r["fit_percent"] < 100 and r["held_percent"] < 1000
        assert math.isclose(r["fit_psnr_db"], -20 * math.log10(r["fit_rmse"]), rel_tol=1e-9)
        assert math.isclose(r["ratio"], r["raw_bytes"] / r["stored_bytes"], rel_tol=1e-9)
        assert r["raw_bytes"] == 20 * 32 * 32 * 3
        assert r["wall_s_min"] <= r["wall_s"] <= r["wall_s_max"] and r["wall_s"] > 0
        assert 20e6 < r["peak_mem_bytes"] < 4e9          # a Python process with numpy, nothing absurd
        assert r["eval_fit"] == 20 and r["eval_held"] == 4
    # At least one row is on each Pareto front, and a row both slower and worse than another is not.
    assert any(r["pareto_time"] for r in ok) and any(r["pareto_bytes"] for r in ok)
    for r in ok:
        if any(o["stored_bytes"] < r["stored_bytes"] and o["fit_percent"] < r["fit_percent"] for o in ok):
            assert not r["pareto_bytes"]


def test_smoke_scaling_table_covers_grid_and_modes(smoke):
    _, out = smoke
    rows = read_csv(out / "scaling.csv")
    cfg = CONFIGS["smoke"]
    grid = {(r["size"], r["samples"], r["mode"]) for r in rows}
    assert grid == {(s, v * 6, m) for s in cfg.scaling_sizes for v in cfg.scaling_views for m in ("auto", "streaming")}
    for r in rows:
        assert r["status"] == "ok" and r["wall_s"] > 0 and r["peak_mem_bytes"] > 20e6
        assert r["values"] == r["samples"] * r["pixels"] and r["pixels"] == r["size"] ** 2
        # A few kB of data fits the default budget; --memory-budget 0 always streams.
        assert r["source"] == ("in-memory" if r["mode"] == "auto" else "streaming")
        assert r["stored_bytes"] > 0
    fits = json.loads((out / "results.json").read_text())["sections"]["scaling"]["summary"]["fits"]
    assert set(fits) == {"auto", "streaming"}
    for mode, fit in fits.items():
        assert set(fit) == {"wall time", "CPU time", "peak memory"}
        assert np.isfinite(fit["wall time"]["vs_values"]) and np.isfinite(fit["CPU time"]["fixed_s"])
        assert fit["wall time"]["vs_samples"] is None        # one sample count: no slope against it


def test_smoke_quilt_and_render_tables_when_those_stages_exist(smoke):
    _, out = smoke
    doc = json.loads((out / "results.json").read_text())
    if "quilt" not in doc["sections"] and "render" not in doc["sections"]:
        pytest.skip("usdbtf.quilt / usdbtf.render not present: sections pending")
    if "quilt" in doc["sections"]:
        rows = read_csv(out / "quilt.csv")
        matched = [r for r in rows if r["method"] == "matched"]
        random = [r for r in rows if r["method"] == "random placement"]
        assert matched and len(random) == 1
        assert all(r["status"] == "ok" and r["wall_s"] > 0 and r["seam_error"] > 0 for r in rows)
        # Matching blocks on coefficients must beat placing them at random.
        assert min(r["seam_error"] for r in matched) < random[0]["seam_error"]
        natural = doc["sections"]["quilt"]["summary"]["natural_neighbour_error"]
        assert all(math.isclose(r["seam_relative"], r["seam_error"] / natural, rel_tol=1e-9) for r in rows)
    if "render" in doc["sections"]:
        rows = read_csv(out / "render.csv")
        for k in CONFIGS["smoke"].render_ks:
            mine = {(r["directions"], r["method"]): r for r in rows if r["k"] == k}
            swatch, exact = mine[("fitted", "render swatch")], mine[("fitted", "reconstruct (stored row)")]
            # At a measured direction the renderer's interpolation weights are one-hot: it
            # must reproduce equation 2 with the stored basis row.
            assert math.isclose(swatch["percent"], exact["percent"], rel_tol=1e-3), (k, swatch, exact)
            assert mine[("held-out", "render swatch")]["percent"] > swatch["percent"]
        fitted = sorted((r for r in rows if r["method"] == "render swatch" and r["directions"] == "fitted"),
                        key=lambda r: r["k"])
        assert fitted[0]["percent"] > fitted[-1]["percent"]        # more basis vectors, smaller error


def test_two_repeats_through_every_method_and_baseline(tmp_path, capsys):
    """Issue 29: a repeat stores again what the run before it stored.  Each repeat writes a
    folder of its own, and every baseline's output is a usdbtf output the guard recognises,
    so the smallest configuration with two repeats measures every row (x265 where ffmpeg has
    it, else skipped with the reason) and keeps only what --keep-outputs asks for."""
    from usdbtf import outputs

    out = tmp_path / "out"
    code = main(["bench", "--smoke", "--repeats", "2", "--sections", "compress", "--k", "2", "--pca-view-k", "1",
                 "--keep-outputs", "-o", str(out), "--workdir", str(tmp_path / "data")])
    rows = read_csv(out / "compress.csv")
    assert sorted(r["family"] for r in rows) == ["jpeg", "original", "paper", "pca-view", "rsvd", "video"]
    exe, why = ffmpeg_x265()
    for r in rows:
        if r["family"] == "original":
            assert r["status"] == "reference"
        elif r["family"] == "video" and exe is None:
            assert r["status"] == f"skipped: {why}" and why
        else:
            assert (r["status"], r["repeats"]) == ("ok", 2), r
            assert 0 < r["wall_s_min"] <= r["wall_s_max"] and r["fit_percent"] > 0, r
    doc = json.loads((out / "results.json").read_text())
    assert (code, doc["status"], doc["failures"]) == (0, "ok", {})
    # What each method stores is a usdbtf output of its kind (--force may replace it), and
    # only the last repeat's output is kept.
    stored = out / "stored" / "pebbles-tiny-32"
    kinds = {"rsvd-jxl-2": outputs.COMPRESSED, "paper-jpeg-2": outputs.COMPRESSED,
             "jpeg-jpeg-90": outputs.MANIFEST, "pca-view-jxl-1": outputs.BENCH_BASELINE}
    if exe is not None:
        kinds["video-x265-24"] = outputs.BENCH_BASELINE
    for slug, kind in kinds.items():
        assert sorted(p.name for p in (stored / slug).iterdir()) == ["run2"], slug
        assert outputs.identify(stored / slug / "run2") == kind, slug
    # So the baseline replaces its own previous output; one holding anything else is not
    # usdbtf's to replace, even with --force.
    from usdbtf.bench import baselines

    pca = stored / "pca-view-jxl-1" / "run2"
    argv = ["pca-view", "--k", "1", str(out / "inputs" / "pebbles-tiny-32-fitted"), str(pca)]
    assert baselines.main(argv) == 0 and outputs.identify(pca) == outputs.BENCH_BASELINE
    (pca / "notes.txt").write_text("mine")
    assert outputs.identify(pca) is None
    assert baselines.main(argv) == 2 and (pca / "notes.txt").read_text() == "mine"
    assert "not a usdbtf usdbtf-bench-baseline/1" in capsys.readouterr().err


def test_baseline_file_names_match_what_outputs_recognises():
    """usdbtf.outputs (layer 0) knows the baselines' record and file names without importing them."""
    from usdbtf import outputs
    from usdbtf.bench import baselines

    assert (outputs._BASELINE_FILE, outputs._BASELINE_VIDEO, outputs._BASELINE_VIEW) == (
        baselines.RECORD, baselines.VIDEO_FILE, baselines.VIEW_FOLDER)


def test_failed_row_is_named_in_the_summary(tmp_path):
    """A row that fails (here: the JPEG baseline asked to replace a folder usdbtf did not
    write) fails the run, and the one-line summary names its section and that row."""
    from usdbtf.atomic import output_policy
    from usdbtf.bench.suite import config_from, failure_summary, run_suite
    from usdbtf.manifest import outside_paths_allowed

    out = tmp_path / "out"
    foreign = out / "stored" / "pebbles-tiny-32" / "jpeg-jpeg-90" / "run1"
    foreign.mkdir(parents=True)
    (foreign / "notes.txt").write_text("not usdbtf's")
    cfg = config_from("smoke", solver_codecs=(("rsvd", "jxl"),), ks=(2,), pca_view_ks=(), video_crfs=())
    with outside_paths_allowed(), output_policy(force=True):          # as `usdbtf bench` runs it
        doc = run_suite(cfg, sections=["compress"], out=out, workdir=tmp_path / "data", say=lambda text: None)
    assert doc["status"] == "failed" and list(doc["failures"]) == ["compress"]
    line = failure_summary(doc)
    assert "\n" not in line and line.startswith(f"{out}/report.md: section(s) compress failed; first: compress: ")
    assert "method jpeg/jpeg, quality 90: failed: " in line and "is not a usdbtf btf-manifest/1" in line
    assert (foreign / "notes.txt").read_text() == "not usdbtf's"
    assert "## failures" in (out / "report.md").read_text()


def test_video_baseline_without_ffmpeg_says_why(monkeypatch, tmp_path):
    import usdbtf.bench.baselines as baselines
    from usdbtf.errors import BTFError

    monkeypatch.setattr(baselines.shutil, "which", lambda name: None)
    exe, why = baselines.ffmpeg_x265()
    assert exe is None and why.startswith("ffmpeg not found on PATH")
    with pytest.raises(BTFError, match="ffmpeg not found"):
        baselines.encode_video(None, tmp_path / "v")
    assert not (tmp_path / "v").exists()


def test_unknown_section_is_one_line_error(capsys, tmp_path):
    code = main(["bench", "--smoke", "--sections", "compress,nonsense", "-o", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "nonsense" in err[0]


# ------------------------------------------------------------------ pieces


def test_preset_split_covers_every_preset_once():
    from usdbtf import synth
    from usdbtf.bench.datasets import HELDOUT_PRESETS, TUNING_PRESETS, preset_split, split_presets

    assert set(TUNING_PRESETS) | set(HELDOUT_PRESETS) == set(synth.PRESETS)
    assert not set(TUNING_PRESETS) & set(HELDOUT_PRESETS)
    assert len(HELDOUT_PRESETS) >= 2 and len(TUNING_PRESETS) >= len(HELDOUT_PRESETS)
    assert split_presets(["velvet", "pebbles", "crevice_stones"]) == (["pebbles"], ["velvet", "crevice_stones"])
    with pytest.raises(ValueError, match="granite"):
        preset_split("granite")


def test_bench_compress_reports_held_out_presets_apart():
    import importlib.util
    import sys
    from pathlib import Path

    folder = Path(__file__).resolve().parents[1] / "benchmarks"
    sys.path.insert(0, str(folder))
    try:
        spec = importlib.util.spec_from_file_location("bench_compress_under_test", folder / "bench_compress.py")
        bench = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(bench)
    finally:
        sys.path.remove(str(folder))

    def solver(k, payload, lin, enc):
        return {"k": k, "codec": "jxl", "bytes": {"payload": payload}, "wall_s_median": 2.0, "max_rss_bytes": 1e9,
                "peak_tree_pss_bytes": 1e9, "peak_memory_bytes": 1e9,
                "full_error": {"linear": {"percent": lin, "rmse": 0.01, "psnr_db": 40.0},
                               "encoded": {"percent": enc, "rmse": 0.01, "psnr_db": 30.0}}}

    results = {}
    for preset, ratio in (("velvet", 0.9), ("pebbles", 0.5), ("crevice_stones", 0.6)):
        results[preset] = {"input": {"raw_bytes": 10**6}, "gemm": {"median_s": 1.0},
                           "paper": solver(150, 1000, 10.0, 10.0), "default": solver(200, 990, 10 * ratio, 5.0),
                           "quality_ratio_linear": ratio, "quality_ratio_encoded": 0.5, "speed_ratio": 2.0}
    table = bench.markdown_table(results, {"median_s": 1.0})
    lines = table.splitlines()
    assert sum(line.startswith("| preset") for line in lines) == 1       # one table, one header
    names = [line.split("|")[1].strip() for line in lines[2:]]
    assert names == ["pebbles", "pebbles", "**targets, tuning presets**", "velvet (held out)", "velvet (held out)",
                     "crevice_stones (held out)", "crevice_stones (held out)", "**targets, held-out presets**"]
    assert "**PASS** (worst 0.50)" in lines[4] and "**FAIL** (worst 0.90)" in lines[-1]
    summary = bench.target_summary(results)
    assert summary["quality_ratio_linear_tuning"]["pass"] and not summary["quality_ratio_linear_heldout"]["pass"]
    assert summary["quality_ratio_encoded_heldout"]["worst"] == 0.5


def test_split_lights_keeps_a_view_by_light_grid():
    s = preset("small")                                   # 13 views x 13 lights
    fit, held = split_lights(s, 0.15, seed=3)
    assert len(held) == 13 * 2 and len(fit) == 169 - 26
    assert np.array_equal(np.sort(np.r_[fit, held]), np.arange(169))
    assert cross_layout(s.subset(fit)) == (13, 11)        # the fitted samples are still a full grid
    held_lights = {tuple(x) for x in s.light[held]}
    assert len(held_lights) == 2 and not held_lights & {tuple(x) for x in s.light[fit]}
    again, _ = split_lights(s, 0.15, seed=3)
    assert np.array_equal(fit, again)                     # seeded
    assert len(split_lights(s, 0.0)[1]) == 0


def test_neighbour_weights_interpolate_between_nearest_directions():
    view = np.zeros((3, 2))
    fitted = Sampling(view, np.array([[30.0, 0.0], [30.0, 40.0], [60.0, 200.0]]))
    query = Sampling(np.zeros((2, 2)), np.array([[30.0, 20.0], [30.0, 40.0]]))
    idx, w = neighbour_weights(fitted, query, neighbours=2)
    # Halfway between the first two lights (equal angles): equal weights on them.
    assert set(idx[0]) == {0, 1} and np.allclose(w[0], 0.5)
    # Exactly a fitted direction: all weight on it.
    assert idx[1, 0] == 1 and w[1, 0] == 1.0 and w[1, 1] == 0.0
    rows = np.array([[1.0, 0.0], [3.0, 2.0], [9.0, 9.0]])
    assert np.allclose(blend_rows(rows, idx, w), [[2.0, 1.0], [3.0, 2.0]])
    # Inverse-distance-squared: a query at 1/4 of the way weighs the near light 9x the far one.
    q = Sampling(np.zeros((1, 2)), np.array([[30.0, 10.0]]))
    i, w = neighbour_weights(fitted, q, neighbours=2)
    d = [np.arccos(np.clip(to_vectors(q.light) @ to_vectors(fitted.light[[j]]).T, -1, 1))[0, 0] for j in i[0]]
    assert i[0, 0] == 0 and np.isclose(w[0, 0] / w[0, 1], (d[1] / d[0]) ** 2) and np.isclose(w[0].sum(), 1)
    # A lower light than its neighbours: the images carry cos(theta_l), so the blend is scaled
    # by cos 60 / cos 30 (a sample lit at 60 deg is ~0.58 as bright as one at 30 deg).
    low = Sampling(np.zeros((1, 2)), np.array([[60.0, 20.0]]))
    i, w = neighbour_weights(fitted, low, neighbours=2)
    assert set(i[0]) == {0, 1} and np.isclose(w[0].sum(), np.cos(np.radians(60)) / np.cos(np.radians(30)))
    assert np.isclose(neighbour_weights(fitted, low, neighbours=2, foreshortening=False)[1][0].sum(), 1)


def test_pareto_mask_and_slopes():
    x = [1, 2, 3, 4, 2.5]
    y = [5, 3, 4, 1, 3]
    assert pareto_mask(x, y).tolist() == [True, True, False, True, False]
    assert pareto_mask([1, np.nan], [1, 0]).tolist() == [True, False]
    px = np.array([1e3, 4e3, 1.6e4])
    assert np.isclose(loglog_slope(px, 7 * px ** 1.5), 1.5)
    # Two series with different constants, same exponent: the pooled slope recovers it.
    assert np.isclose(pooled_loglog_slope([(px, 2 * px), (px, 50 * px)]), 1.0)
    assert pooled_loglog_slope([([5, 5], [1, 2])]) is None
    a, b = affine_fit(px, 0.5 + 2e-6 * px)
    assert np.isclose(a, 0.5) and np.isclose(b, 2e-6)
