"""The working-domain curve (issue 16): compress fits and quantises f(x); every reader applies
f^-1 after the dot product.

The curves round-trip and are monotone and finite; ``--domain`` and the metadata's ``domain``
accept only the whitelist; a gamma-domain folder decompresses to the in-memory
reconstruction, its estimated error is the real one, and the CPU renderer's swatch equals
decompress with two lights adding after the curve; ``auto`` is deterministic and keeps a
linear domain for data a linear basis reconstructs exactly; a folder without ``domain``
(``btf-compressed/1``) still reads as linear.
"""
from __future__ import annotations

import json
import math
import shutil


import numpy as np
import pytest

from cli_helpers import bad_input, bad_usage, ok
from compress_helpers import compress_into
from usdbtf.compress import CompressOptions, compress, read_compressed, reconstruct
from usdbtf.compress.domain import AUTO_CANDIDATES, LINEAR, Domain, domain_from_metadata, parse_domain
from usdbtf.compress.format import FORMAT, FORMAT_DOMAIN
from usdbtf.errors import BTFError, UsageError
from usdbtf.io import open_btf
from usdbtf.model import ArrayBTF
from usdbtf.render import Light, RenderOptions, Renderer
from usdbtf.render.hemisphere import directions_to_vectors
from usdbtf.sampling import preset

CURVES = [Domain("power", 1.6), Domain("power", 2.2), Domain("srgb"), LINEAR]


# ------------------------------------------------------------------ the curves


@pytest.mark.parametrize("dom", CURVES, ids=lambda d: d.name)
def test_curve_round_trip_monotone_finite(dom):
    x = np.concatenate([np.zeros(1), np.geomspace(1e-8, 1e4, 4001)]).astype(np.float32)
    d = dom.forward(x)
    assert d.dtype == np.float32 and np.isfinite(d).all() and (np.diff(d) >= 0).all()
    np.testing.assert_allclose(dom.inverse(d), x, rtol=2e-5, atol=1e-12)
    if not dom.is_linear:   # negatives: clamped to 0 both ways (documented in domain.py)
        assert dom.forward(np.float32([-1.0]))[0] == 0 and dom.inverse(np.float32([-0.5]))[0] == 0


@pytest.mark.parametrize("dom", CURVES[:3], ids=lambda d: d.name)
def test_a_value_s_bits_do_not_depend_on_where_it_sits(dom):
    """The same value gives the same bits at every offset and in every run length, with zeros,
    -0.0 and denormals among its neighbours: a Dask chunk, a streaming block and a test's
    slice compress a sample alike (OpenCV 5.1's pow failed this on partial SIMD vectors)."""
    rng = np.random.default_rng(11)
    x = rng.random(4099, dtype=np.float32) * np.float32(1.5)
    x[::7] = 0.0
    x[3::11] = -0.0
    x[5::13] = np.float32(1e-41)                    # denormal
    x[6::17] = 1.0
    whole_f, whole_i = dom.forward(x.copy()), dom.inverse(x.copy())
    assert (whole_f[x == 0] == 0).all() and (np.signbit(whole_f[x == 0]) == 0).all()   # 0 ** e = +0
    if dom.curve == "power":
        assert (whole_f[x == 1] == 1).all() and (whole_i[x == 1] == 1).all()
    for start in range(70):
        for stop in (x.size, x.size - 1, x.size - 9, start + 1, start + 17):
            part = x[start:stop]
            assert np.array_equal(dom.forward(part.copy()).view(np.uint32), whole_f[start:stop].view(np.uint32))
            assert np.array_equal(dom.inverse(part.copy()).view(np.uint32), whole_i[start:stop].view(np.uint32))
    strided = x[1::3]                               # a non-contiguous view: powered in a copy
    assert np.array_equal(dom.forward(strided).view(np.uint32), whole_f[1::3].view(np.uint32))


def test_srgb_curve_is_the_encoding_and_continuous():
    dom = Domain("srgb")
    codes = np.arange(256) / 255.0
    lin = np.where(codes <= 0.04045, codes / 12.92, ((codes + 0.055) / 1.055) ** 2.4)
    np.testing.assert_allclose(dom.forward(lin), codes, atol=2e-6)
    edge = np.float32([0.0031308 * (1 - 1e-6), 0.0031308 * (1 + 1e-6)])
    assert abs(float(np.diff(dom.forward(edge))[0])) < 1e-6


def test_domain_option_and_metadata_whitelist(tmp_path):
    assert parse_domain("auto") is None and parse_domain("linear") is LINEAR and parse_domain("gamma:1") is LINEAR
    assert parse_domain("gamma:2.2") == Domain("power", 2.2) and parse_domain("sRGB") == Domain("srgb")
    for bad in ("gamma:0.5", "gamma:5", "gamma:nan", "gamma:", "log", "power", "gamma:2;rm -rf /"):
        with pytest.raises(UsageError, match="--domain"):
            parse_domain(bad)
    assert domain_from_metadata(None, "f") is LINEAR
    assert domain_from_metadata({"curve": "power", "gamma": 1.6}, "f") == Domain("power", 1.6)
    for bad in ({"curve": "log"}, {"curve": "power"}, {"curve": "power", "gamma": 9}, {"curve": "power", "gamma": True},
                {"curve": "srgb", "gamma": 2}, {"curve": "srgb", "x": 1}, "srgb", [1]):
        with pytest.raises(BTFError, match="f: domain"):
            domain_from_metadata(bad, "f")


# ------------------------------------------------------------------ compress and read back


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    folder = tmp_path_factory.mktemp("domain")
    raw = folder / "raw"
    from usdbtf.cli import main
    assert main(["synth", "metal_flakes", "-o", str(raw), "--sampling", "small", "--size", "32", "--seed", "2",
                 "-q"]) == 0
    return folder, raw


@pytest.fixture(scope="module")
def gamma_folder(data):
    folder, raw = data
    out = folder / "c_gamma"
    result = compress_into(open_btf(raw), out, CompressOptions(k=16, domain="gamma:2.2"))
    return out, result


def test_gamma_folder_records_its_curve_and_decompresses_to_the_in_memory_result(data, gamma_folder, capsys):
    folder, raw = data
    out, result = gamma_folder
    doc = json.loads((out / "btf-compressed.json").read_text())
    assert doc["format"] == FORMAT_DOMAIN and doc["domain"] == {"curve": "power", "gamma": 2.2}
    back = read_compressed(out)
    assert back.domain == Domain("power", 2.2) == result.domain
    want = reconstruct(result, [3, 50, 120])
    np.testing.assert_array_equal(reconstruct(back, [3, 50, 120]), want)
    assert want.min() >= 0                                          # the inverse clamps below zero
    # decompress writes the source's 8-bit encoding: the in-memory reconstruction encoded the same way
    ok(capsys, "decompress", out, "-o", folder / "d_gamma", "--samples", "3,50,120", "-q")
    files = open_btf(folder / "d_gamma")
    from usdbtf import color
    from usdbtf.manifest import encode_for_file
    to_file = color.processor(back.working_space, files.color_space)
    np.testing.assert_array_equal(files.read_encoded(slice(0, 3)), encode_for_file(want, to_file, "uint8"))
    # the estimated (held-out) error is the real error of the reconstruction, in scene-linear
    report = json.loads(ok(capsys, "error", raw, folder / "d_gamma"))
    assert set(report) >= {"linear", "encoded"}
    est = result.info["estimated_error"]["linear"]["percent"]
    full = compress_error(open_btf(raw), result)
    assert est == pytest.approx(full, rel=0.25)


def compress_error(btf, cbtf) -> float:
    from usdbtf.compress.decompress import compare
    return compare(btf, lambda sel: reconstruct(cbtf, sel))["linear"]["percent"]


def test_linear_folder_keeps_format_1_and_reads_as_before(data, tmp_path):
    folder, raw = data
    out = tmp_path / "c_lin"
    result = compress_into(open_btf(raw), out, CompressOptions(k=16, domain="linear"))
    doc = json.loads((out / "btf-compressed.json").read_text())
    assert doc["format"] == FORMAT and "domain" not in doc
    back = read_compressed(out)
    assert back.domain is LINEAR or back.domain == LINEAR
    rows = back.basis_values()[[7]]
    from usdbtf.compress.format import working_coefficients
    plain = (rows @ working_coefficients(back).reshape(back.k, -1)).reshape(1, back.height, back.width, 3)
    np.testing.assert_array_equal(reconstruct(back, [7]), plain)     # no curve: the dot product itself
    # A /1 folder that claims a curve is refused (an old reader would ignore it).
    doc["domain"] = {"curve": "srgb"}
    (out / "btf-compressed.json").write_text(json.dumps(doc))
    with pytest.raises(BTFError, match="domain.*btf-compressed/1.1"):
        read_compressed(out)
    assert result.domain == LINEAR


def test_damaged_domain_entry_is_one_error(gamma_folder, tmp_path, capsys):
    src, _ = gamma_folder
    bad = tmp_path / "bad"
    shutil.copytree(src, bad)
    doc = json.loads((bad / "btf-compressed.json").read_text())
    doc["domain"] = {"curve": "power", "gamma": "$(reboot)"}
    (bad / "btf-compressed.json").write_text(json.dumps(doc))
    bad_input(capsys, "decompress", bad, "-o", tmp_path / "out", names="domain.gamma")


def test_domain_flag_is_validated(data, tmp_path, capsys):
    _, raw = data
    bad_usage(capsys, "compress", raw, "-o", tmp_path / "c", "--domain", "gamma:9", names="--domain")


def test_auto_is_deterministic_and_keeps_linear_for_a_low_rank_input(data, tmp_path):
    _, raw = data
    btf = open_btf(raw)
    a = compress(btf, CompressOptions(k=8))
    b = compress(btf, CompressOptions(k=8))
    assert a.domain == b.domain and a.domain in AUTO_CANDIDATES
    assert a.encoded.basis == b.encoded.basis and a.encoded.coefficients == b.encoded.coefficients
    scores = a.info["choice"]["domain_scores"]
    assert set(scores) == {d.name for d in AUTO_CANDIDATES}
    assert min(scores, key=lambda n: scores[n]["score"]) == a.domain.name
    assert not any("fine" in entry for entry in scores.values())      # a small input: the fine pass alone
    # rank 2: a linear basis is exact, any curve is not
    s = preset("tiny")
    rng = np.random.default_rng(0)
    x = (rng.random((len(s), 2)) @ rng.random((2, 8 * 8 * 3))).reshape(len(s), 8, 8, 3).astype(np.float32)
    low = compress(ArrayBTF.from_linear(s, x), CompressOptions(codec="exr", k=4))
    assert low.domain == LINEAR and low.k == 2


def test_auto_rescores_near_ties_with_the_fine_pass(data, monkeypatch):
    """The coarse pass (here on a small input, its size limits lowered) decides alone when no
    candidate is within the tie margin of its best; candidates within it are scored again by
    the fine pass, whose best wins, and the fine scores are recorded beside the coarse ones."""
    from usdbtf.compress import domain_choice
    from usdbtf.compress.select_source import load_source
    from usdbtf.compress.texels import sample_texels

    _, raw = data
    btf = open_btf(raw)
    opts = CompressOptions(k=8)
    texels = sample_texels(btf, opts)
    monkeypatch.setattr(domain_choice, "COARSE_MIN_SAMPLES", 1)
    monkeypatch.setattr(domain_choice, "COARSE_MIN_TEXELS", 1)
    with load_source(btf, texels, opts) as source:
        coarse, _ = domain_choice.score_domains(source, texels, 8, opts, strides=domain_choice.COARSE)
        fine, _ = domain_choice.score_domains(source, texels, 8, opts, strides=domain_choice.FINE)
        monkeypatch.setattr(domain_choice, "TIE_MARGIN", -1.0)          # no ties: the coarse pass alone
        alone, _, recorded = domain_choice.choose_by_scores(source, texels, 8, opts)
        assert alone.name == min(coarse, key=lambda n: coarse[n]["score"])
        assert recorded == coarse and not any("fine" in e for e in recorded.values())
        monkeypatch.setattr(domain_choice, "TIE_MARGIN", 1e9)           # every candidate tied: all scored again
        tied, _, recorded = domain_choice.choose_by_scores(source, texels, 8, opts)
        assert tied.name == min(fine, key=lambda n: fine[n]["score"])
        assert {n: e["fine"] for n, e in recorded.items()} == fine
        assert {n: {k: v for k, v in e.items() if k != "fine"} for n, e in recorded.items()} == coarse
    assert coarse != fine                                               # two different subsamples


@pytest.mark.parametrize("margin", [-1.0, 1e9], ids=["coarse-alone", "fine-over-ties"])
def test_two_pass_choice_is_the_same_streamed_and_in_memory(data, monkeypatch, margin):
    """The coarse pass and the fine pass read the same stored values from a streamed source
    (first pass kept columns, spill file) as from memory: the same scores, the same bytes."""
    from usdbtf.compress import domain_choice

    _, raw = data
    monkeypatch.setattr(domain_choice, "COARSE_MIN_SAMPLES", 1)
    monkeypatch.setattr(domain_choice, "COARSE_MIN_TEXELS", 1)
    monkeypatch.setattr(domain_choice, "TIE_MARGIN", margin)
    mem = compress(open_btf(raw), CompressOptions(k=8))
    streamed = compress(open_btf(raw), CompressOptions(k=8, memory_budget=0, workers=2, chunk_bytes=1))
    assert mem.info["choice"]["domain_scores"] == streamed.info["choice"]["domain_scores"]
    assert any("fine" in e for e in mem.info["choice"]["domain_scores"].values()) == (margin > 0)
    assert mem.encoded.basis == streamed.encoded.basis and mem.encoded.coefficients == streamed.encoded.coefficients


# ------------------------------------------------------------------ renderer


def test_swatch_equals_reconstruction_and_lights_add_after_the_curve(gamma_folder):
    out, _ = gamma_folder
    cbtf = read_compressed(out)
    r = Renderer(cbtf, RenderOptions(threads=1))
    s = 57
    view, light = cbtf.sampling.view[s], cbtf.sampling.light[s]
    want = reconstruct(cbtf, [s])[0]
    np.testing.assert_allclose(r.swatch(view, light), want, rtol=1e-4, atol=1e-5 * np.abs(want).max())
    # intensity is a radiance factor: twice the capture light (pi W, usdbtf.photometry), twice the
    # image (not f^-1(2 d))
    np.testing.assert_allclose(r.swatch(view, light, 2.0 * math.pi), 2 * want, rtol=1e-4, atol=1e-5 * np.abs(want).max())
    # two lights on a plane seen from above: the sum of the two one-light renders
    from quilt_render_data import PHYSICAL_SIZE, plane_with_uv
    from usdbtf.camera import Camera
    from usdbtf.mesh import Mesh
    points, faces, uv = plane_with_uv(PHYSICAL_SIZE, 2)
    plane = Mesh(points, faces, uv=uv, normals=np.tile([0.0, 0.0, 1.0], (len(points), 1)))
    half = PHYSICAL_SIZE / 2
    cam = Camera(np.array([0, 0, 50.0]), np.zeros(3), np.array([0, 1.0, 0]), np.degrees(2 * np.arctan(half / 50)),
                 16, 16)
    a = Light("directional", directions_to_vectors([(30.0, 0.0)])[0], 1.0)
    b = Light("directional", directions_to_vectors([(50.0, 120.0)])[0], 0.5)
    both = r.render(plane, cam, [a, b])[..., :3]
    one = r.render(plane, cam, [a])[..., :3] + r.render(plane, cam, [b])[..., :3]
    np.testing.assert_allclose(both, one, rtol=1e-5, atol=1e-6)
