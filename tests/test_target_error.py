"""--target-error's speed-ups, checked against what they must not change.

* A lossless codec: each attempt's held-out error is measured on the quantised textures and
  only the chosen attempt is encoded (``ratecontrol._target_error``).  The error is the
  encoded one bit for bit, and the result is that of encoding every attempt.
* The projection covers what the sampled model needs (``ratecontrol.error_planes``); when
  rate control's choice reaches the plan, or the last attempt misses the target, every
  fitted component is projected and rate control runs again (``core.compress``): the result
  is then that of a run that never planned.  No plan where the model's error is not the
  target's kind (a scene-linear target in a curved working domain).

* The estimate is the paper's metric over every texel (issue 39): held-out texels for the
  unfitted ones, a sample of the fitted ones (reconstructed better) for those; and the
  search takes the cheapest attempt just under the target, not the first under it.

Real compresses of small synthetic materials (169 samples of 32 x 32), a second or two each.
"""
from __future__ import annotations

import dataclasses

import pytest

from usdbtf.compress import CompressOptions, compress, core, ratecontrol
from usdbtf.compress.encode import encode as real_encode
from usdbtf.manifest import read_manifest

from test_compress import synth_manifest

K_FIT = 169   # the small sampling's 169 samples: every fitted component


@pytest.fixture(scope="module")
def pebbles(tmp_path_factory):
    return read_manifest(synth_manifest(tmp_path_factory.mktemp("te") / "pebbles32", "small", 32))


@pytest.fixture(scope="module")
def flakes(tmp_path_factory):
    return read_manifest(synth_manifest(tmp_path_factory.mktemp("te") / "flakes32", "small", 32,
                                        material="metal_flakes"))


@dataclasses.dataclass
class Run:
    result: object
    projected: list = dataclasses.field(default_factory=list)   # planes of each projection
    encodes: list = dataclasses.field(default_factory=list)     # k of each encode by rate control
    measured: list = dataclasses.field(default_factory=list)    # k of each held-out measurement


def _run(btf, monkeypatch, **options) -> Run:
    """compress(btf, options), watching the projections, rate control's encodes and its
    held-out measurements."""
    run = Run(None)
    real_project, real_error = core.project, ratecontrol.held_out_error

    def project(source, basis, color, planes, **kw):
        run.projected.append(tuple(planes))
        return real_project(source, basis, color, planes, **kw)

    def encode(cbtf):
        run.encodes.append(cbtf.k)
        return real_encode(cbtf)

    def held_out_error(cbtf, *a, **kw):
        run.measured.append(cbtf.k)
        return real_error(cbtf, *a, **kw)

    with monkeypatch.context() as m:
        m.setattr(core, "project", project)
        m.setattr(ratecontrol, "encode", encode)
        m.setattr(ratecontrol, "held_out_error", held_out_error)
        run.result = compress(btf, CompressOptions(**options))
    return run


def _unplanned(btf, monkeypatch, **options):
    """The run without a plan (as before it): every fitted component on every plane."""
    with monkeypatch.context() as m:
        m.setattr(ratecontrol, "error_planes", lambda sampled, basis, *a: (basis.shape[1],) * 3)
        return _run(btf, monkeypatch, **options)


def _same_output(a, b):
    assert a.info["choice"] == b.info["choice"]
    assert a.info["bytes"] == b.info["bytes"]
    assert a.encoded.basis == b.encoded.basis and a.encoded.coefficients == b.encoded.coefficients
    assert a.info["estimated_error"] == b.info["estimated_error"]


LINEAR3 = dict(target_error=3.0, error_domain="linear")   # pebbles: 4 attempts, met at the 4th
ENCODED3 = dict(target_error=3.0)                          # pebbles: met at the first attempt, planned


def test_attempts_are_measured_unencoded_and_encoded_once(pebbles, monkeypatch):
    measured = []
    real_error = ratecontrol.held_out_error

    def held_out_error(cbtf, held, *a, **kw):
        e = real_error(cbtf, held, *a, **kw)
        assert cbtf.encoded is None                      # the quantised textures, not an encode
        measured.append((e.percent, real_error(real_encode(cbtf), held, *a, **kw).percent))
        return e

    with monkeypatch.context() as m:
        m.setattr(ratecontrol, "held_out_error", held_out_error)
        run = _run(pebbles, monkeypatch, **LINEAR3)
    choice = run.result.info["choice"]
    assert choice["attempts"] == 4 and len(measured) == 4
    assert all(unencoded == encoded for unencoded, encoded in measured)   # bit for bit
    assert measured[-1][1] == choice["estimated_percent"] <= 3.0
    assert all(m > 3.0 for m, _ in measured[:-1])
    assert run.encodes == [choice["k"]]                  # one encode: the chosen attempt's
    assert choice["model"]["measured_bytes"] == choice["bytes"] == run.result.info["bytes"]["payload"]

    # A codec that is not lossless encodes (and measures) every attempt: the same result.
    lossy = dataclasses.replace(ratecontrol.get_codec(run.result.codec), lossless=False)
    with monkeypatch.context() as m:
        m.setattr(ratecontrol, "get_codec", lambda name: lossy)
        every = _run(pebbles, monkeypatch, **LINEAR3)
    assert len(every.encodes) == 4 and every.encodes[-1] == choice["k"]
    _same_output(run.result, every.result)


def test_plan_projects_less_for_the_same_choice(pebbles, monkeypatch):
    planned = _run(pebbles, monkeypatch, **ENCODED3)
    unplanned = _unplanned(pebbles, monkeypatch, **ENCODED3)
    assert unplanned.projected == [(K_FIT,) * 3]
    assert len(planned.projected) == 1 and planned.result.info["choice"]["planes"] == list(planned.projected[0])
    k0, k1, k2 = planned.projected[0]
    assert k0 < K_FIT and k1 < k0 and k2 < k1           # every plane cut (101/41/0 when written)
    a, b = planned.result.info["choice"], unplanned.result.info["choice"]
    assert a["k"] == b["k"] < k0 and a["attempts"] == b["attempts"]
    # The steps come from the coefficients' energy: the projection's rounding differs per plane.
    assert a["step"] == pytest.approx(b["step"], rel=1e-6)
    assert a["estimated_percent"] == pytest.approx(b["estimated_percent"], rel=1e-4)
    assert a["estimated_percent"] <= 3.0
    assert a["bytes"] == pytest.approx(b["bytes"], rel=2e-3)


def test_no_plan_for_a_target_in_another_domain_than_the_model(pebbles, monkeypatch):
    """A scene-linear target with a curved working domain (pebbles: x^(1/1.6)): the model's
    error is the working domain's, so no plan; every component from the start, one projection."""
    run = _run(pebbles, monkeypatch, **LINEAR3)
    assert run.result.domain.name != "linear"
    assert run.projected == [(K_FIT,) * 3]


def test_choice_reaching_the_plan_projects_everything(pebbles, monkeypatch):
    # A plan of one component: the first attempt's choice reaches it, and is refused before
    # anything is measured or encoded.
    monkeypatch.setattr(ratecontrol, "_ERROR_PLAN_MARGIN", 0.0)
    monkeypatch.setattr(ratecontrol, "_ERROR_PLAN_EXTRA", 1)
    capped = _run(pebbles, monkeypatch, target_error=4.0)
    monkeypatch.undo()
    unplanned = _unplanned(pebbles, monkeypatch, target_error=4.0)
    assert capped.projected[0][0] == 1 and capped.projected[1:] == [(K_FIT,) * 3]
    assert unplanned.result.info["choice"]["k"] > 1
    assert capped.measured == unplanned.measured and capped.encodes == unplanned.encodes == [capped.result.k]
    _same_output(capped.result, unplanned.result)


def test_target_missed_on_the_plan_projects_everything(flakes, monkeypatch):
    # metal_flakes' encoded 2 %: four attempts miss within the plan (plane 0 all 169, the
    # others cut): a missed target is not taken on a plan either.
    # (Four attempts, as before issue 39's search: its sixth meets 2 %.)
    monkeypatch.setattr(ratecontrol, "_TARGET_ATTEMPTS", {True: 4, False: 4})
    capped = _run(flakes, monkeypatch, target_error=2.0)
    unplanned = _unplanned(flakes, monkeypatch, target_error=2.0)
    assert len(capped.projected) == 2 and capped.projected[0] != (K_FIT,) * 3 and capped.projected[0][0] == K_FIT
    assert capped.projected[1] == (K_FIT,) * 3
    assert len(capped.measured) == 8 and capped.measured[4:] == unplanned.measured
    assert capped.encodes == unplanned.encodes == [capped.result.k]   # the refused choice was never encoded
    assert unplanned.result.info["choice"]["attempts"] == 4
    assert unplanned.result.info["choice"]["estimated_percent"] > 2.0
    _same_output(capped.result, unplanned.result)


def _exact_encoded_percent(btf, cbtf) -> float:
    """The paper's metric on the input files' values over every sample and texel, of what
    ``cbtf`` reconstructs (encoded as a file holds it)."""
    from usdbtf.compress.decompress import compare
    from usdbtf.compress.format import reconstruct

    return compare(btf, lambda sel: reconstruct(cbtf, sel))["encoded"]["percent"]


def test_estimate_is_the_error_over_every_texel(pebbles):
    # 32 x 32 = 16 runs: 4 fitted, the other 12 all held out, the in-sample stratum all 4
    # fitted runs: both strata complete, so the weighted estimate is the exact error.  The
    # held-out texels alone (the estimate before issue 39) read high: the fitted texels are
    # reconstructed better.
    opts = CompressOptions(k=60, fit_texels=256, eval_texels=768)
    result = compress(pebbles, opts)
    est = result.info["estimated_error"]
    assert est["texels"] == 768 and est["in_sample_texels"] == 256
    exact = _exact_encoded_percent(pebbles, result)
    assert est["encoded"]["percent"] == pytest.approx(exact, rel=1e-5)
    import dataclasses as dc

    from usdbtf.compress.evaluate import held_out_error, held_out_set
    from usdbtf.compress.select_source import load_source
    from usdbtf.compress.texels import sample_texels
    texels = dc.replace(sample_texels(pebbles, opts), in_sample=None)   # the held-out stratum alone
    with load_source(pebbles, texels, opts) as source:
        alone = held_out_error(result, held_out_set(source, texels), domain="encoded").percent
    assert alone > 1.05 * exact


def test_target_error_lands_just_under_the_target(pebbles):
    # pebbles' first model choice measures ~30 % under an encoded 6 % target; the search
    # relaxes it until within _TARGET_TOLERANCE under.  The estimate is exact here (every
    # texel is fitted: 32 x 32 is smaller than the fitting sample).
    result = compress(pebbles, CompressOptions(target_error=6.0, budget_for="folder"))
    choice = result.info["choice"]
    exact = _exact_encoded_percent(pebbles, result)
    assert choice["estimated_percent"] == pytest.approx(exact, rel=1e-5)
    assert (1 - ratecontrol._TARGET_TOLERANCE) * 6.0 <= exact <= 6.0
    assert choice["attempts"] >= 2


def test_in_sample_stratum_streamed_as_in_memory(pebbles):
    # The in-sample texels are one more set a streaming source keeps up front: a streamed
    # (memory_budget=0) run estimates and chooses what an in-memory one does.
    opts = dict(target_error=6.0, fit_texels=256, eval_texels=256, budget_for="folder")
    mem = compress(pebbles, CompressOptions(**opts))
    streamed = compress(pebbles, CompressOptions(**opts, memory_budget=0))
    assert mem.info["estimated_error"]["in_sample_texels"] == 256
    assert streamed.info["estimated_error"] == mem.info["estimated_error"]
    _same_output(streamed, mem)
