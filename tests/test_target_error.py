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

import numpy as np
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

    def held_out_error(cbtf, held, k=None, *a, **kw):
        e = real_error(cbtf, held, k, *a, **kw)
        assert cbtf.encoded is None                      # the quantised textures, not an encode
        measured.append((k, e.percent, real_error(real_encode(cbtf), held, k, *a, **kw).percent))
        return e

    with monkeypatch.context() as m:
        m.setattr(ratecontrol, "held_out_error", held_out_error)
        run = _run(pebbles, monkeypatch, **LINEAR3)
    choice = run.result.info["choice"]
    assert all(unencoded == encoded for _, unencoded, encoded in measured)   # bit for bit
    # The four attempts (whole quantisations), met at the 4th; then the trim's evaluations of
    # fewer components (k given), and, when it kept fewer, the trimmed quantisation's own.
    attempts = [m for _, m, _ in measured[:4]]
    assert choice["attempts"] == 4 and measured[3][0] is None and all(m[0] is None for m in measured[:4])
    assert all(m > 3.0 for m in attempts[:3]) and attempts[3] <= 3.0
    # Then the trim's evaluations of fewer components (k given); the choice is the fewest seen
    # to meet the target (the 4th attempt's k when none did), with the error measured there.
    trims = [(k, m) for k, m, _ in measured[4:]]
    assert all(k is not None for k, _ in trims)
    met = {k: m for k, m in trims if m <= 3.0}
    if met:
        assert choice["k"] == min(met) and choice["estimated_percent"] == met[min(met)]
        assert all(m > 3.0 for k, m in trims if k < choice["k"])
    else:
        assert choice["estimated_percent"] == attempts[3]
    assert choice["estimated_percent"] <= 3.0
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


@pytest.mark.parametrize("answer", [1, 37, 99, 100])
def test_fewest_components_finds_the_fewest_that_meet_the_target(answer):
    """A smoothly falling error, 3 (answer / n)^0.3 %, that meets a 3 % target from ``answer`` on
    (n <= 100): within _TRIM_TRIES evaluations the trim returns exactly that n and its error from
    a model guess 20 components too optimistic, one a quarter of the way short each time, or
    one as the model reads it (the error's ratio to the target, 5 % pessimistic); bisection
    (no guess) needs up to 8.  A guess that never sees room below its reference still returns a
    measured pass within the cap, and the fewest within 12."""
    errors = 3.0 * (answer / np.maximum(np.arange(101), 1)) ** 0.3
    guesses = {"optimistic": lambda n, e: max(1, answer - 20),
               "pessimistic": lambda n, e: answer + (n - answer) // 4,
               "model": lambda n, e: max(1, int(n * (3.0 / e) ** (-1 / 0.3) * 1.05)),
               "bisection": None, "no room": lambda n, e: n}
    for name, guess in guesses.items():
        for tries in (ratecontrol._TRIM_TRIES, 12):
            seen = []

            def error_at(n):
                seen.append(n)
                return float(errors[n])

            n, e = ratecontrol._fewest_components(error_at, 100, float(errors[100]), 3.0, guess, tries=tries)
            assert len(seen) <= tries and e == float(errors[n]) <= 3.0 and n >= answer, name
            if name not in ("bisection", "no room") or tries == 12:
                assert n == answer, (name, tries, seen)


def test_fewest_components_returns_a_measured_pass_whatever_the_error():
    """Error that does not fall with n (noise around the target): the answer is one that was
    measured to meet it, never an unmeasured n, and the tries are capped."""
    rng = np.random.default_rng(1)
    errors = 3.0 + rng.normal(0, 0.2, 101)
    errors[100] = 2.9
    seen = {}

    def error_at(n):
        seen[n] = float(errors[n])
        return seen[n]

    n, e = ratecontrol._fewest_components(error_at, 100, 2.9, 3.0, lambda n, e: n // 2)
    assert e <= 3.0 and (n == 100 or seen[n] == e) and len(seen) <= ratecontrol._TRIM_TRIES


def test_fewest_components_starts_from_the_attempts_at_its_step():
    """Errors already measured at the chosen step (the search's attempts with fewer components)
    bracket the answer from the start: with a miss one below the choice nothing is evaluated,
    and with a miss 10 below only the bracket between is searched."""
    errors = 3.0 * (37 / np.maximum(np.arange(101), 1)) ** 0.3
    seen = []

    def error_at(n):
        seen.append(n)
        return float(errors[n])

    assert ratecontrol._fewest_components(error_at, 37, float(errors[37]), 3.0, lambda n, e: 1,
                                          known={36: float(errors[36]), 20: float(errors[20])}) == (37, 3.0)
    assert seen == []
    n, _ = ratecontrol._fewest_components(error_at, 47, float(errors[47]), 3.0, lambda n, e: 1,
                                          known={37 - 10: float(errors[27])})
    assert n == 37 and seen and all(27 < m < 47 for m in seen)


def test_a_plain_k_samples_the_fitted_stratum_in_proportion_a_budget_in_full():
    """Issue 42: a plain k's estimate is a report, its fitted stratum (2048 of 16384 texels at
    128^2) sampled in proportion to the texels it stands for (4 runs of 64, not 16); under a
    target the estimate steers the choice and keeps the held-out sample's size."""
    from types import SimpleNamespace

    from usdbtf.compress.texels import MIN_IN_SAMPLE_RUNS, RUN, sample_texels

    image = SimpleNamespace(width=128, height=128)
    plain = sample_texels(image, CompressOptions(k=150))
    assert (len(plain.fit), len(plain.evaluation), len(plain.in_sample)) == (2048, 1024, MIN_IN_SAMPLE_RUNS * RUN)
    assert np.isin(plain.in_sample, plain.fit).all() and not np.isin(plain.evaluation, plain.fit).any()
    for budget in (CompressOptions(target_error=5.0), CompressOptions(max_bytes=10**6)):
        texels = sample_texels(image, budget)
        assert (len(texels.fit), len(texels.in_sample)) == (4096, 1024)
    # A larger image's fitted share is smaller still, but never below four runs; a larger
    # held-out sample gets a proportionally larger fitted one.
    assert len(sample_texels(SimpleNamespace(width=512, height=512), CompressOptions(k=150)).in_sample) == 4 * RUN
    wide = sample_texels(image, CompressOptions(k=150, eval_texels=8192))
    assert len(wide.in_sample) == 19 * RUN          # ceil(128 runs x 2048 / 14336)
