"""UBO2014 ``.btf`` reader (usdbtf.ubo2014), checked against an independent reader.

Files are written by ``tests/bonn_btf_writer.py`` (no usdbtf code).  Two kinds of evidence:

* usdbtf decodes the values the writer's float64 reference computes from the *stored*
  factors with btflib's formulas (every signature, both matrix arrangements, PVF, BDI);
* btf-extractor (zeroeffects/btf, C++) decodes the same files to the same images, up to
  its documented differences: rows flipped, BGR, angles rounded to 0.1 deg, and colour
  model 11's inverse (its U = c1 Y + eps and [0, 1] clamp).  It reads DFMF and FMF with
  as many views as lights; PVF and BDI have only the first kind of evidence.
"""
from __future__ import annotations

import json
import pickle
import struct
from pathlib import Path

import numpy as np
import pytest

import bonn_btf_writer as w
from cli_helpers import run
from usdbtf import cli
from usdbtf.errors import BTFError
from usdbtf.io import open_btf
from usdbtf.sampling import to_vectors
from usdbtf.ubo2014 import UBO2014BTF, bonn_to_tangent_degrees, is_ubo2014, read_ubo2014, undecorrelate

# 3 views x 3 lights (btf-extractor needs nV == nL), 6 x 4 texels (not square: catches
# a transposed texel order), theta and phi in radians as the files store them.
VIEWS = np.array([[0.0, 0.0], [np.pi / 6, 0.0], [np.pi / 4, np.pi / 2]])
LIGHTS = np.array([[0.0, 0.0], [np.pi / 3, np.pi], [np.pi / 4, np.pi / 2]])
W, H = 6, 4
S, T = len(VIEWS) * len(LIGHTS), W * H
GEOM = dict(views_rad=VIEWS, lights_rad=LIGHTS, width=W, height=H)


def images(seed: int = 1, lo: float = 0.1, hi: float = 0.8) -> np.ndarray:
    """(S, H, W, 3) linear RGB in [lo, hi]; every texel and sample distinct."""
    return lo + (hi - lo) * np.random.default_rng(seed).random((S, H, W, 3))


def dfmf_channels(rgb: np.ndarray, k: int = S, model: int = 11):
    values = w.rgb_to_model11(rgb) if model == 11 else rgb
    flat = values.reshape(S, T, 3)
    return [w.factorise(flat[..., c], k) for c in range(3)]


def channel_values(channels, scalar_size: int = 2) -> np.ndarray:
    """(S, T, 3) the channels as the stored (rounded) factors multiply out, float64."""
    return np.stack([w.stored(u, scalar_size) @ w.stored(sxv, scalar_size).T for _, u, sxv in channels], axis=-1)


def as_images(values: np.ndarray) -> np.ndarray:
    return values.reshape(S, H, W, 3)


@pytest.fixture(scope="module")
def extractor():
    """btf-extractor's compiled UBO2014 reader.  Its package import needs nptyping 1.x,
    which numpy 2 breaks, so the extension module is imported directly."""
    return pytest.importorskip("ubo2014_cy", reason="btf-extractor is not installed (scripts/bootstrap.sh builds "
                                                    "it from its source distribution when a compiler is present)")


def extracted(extractor, path: Path) -> np.ndarray:
    """All samples through btf-extractor in usdbtf's sample order (v nL + l), rows and
    channels put back in btflib's convention (top row first, RGB)."""
    e = extractor.Ubo2014(str(path))
    out = np.stack([e._angleindex_to_image_unsafe(l, v) for v in range(len(VIEWS)) for l in range(len(LIGHTS))])
    return out[:, ::-1, :, ::-1]


# --------------------------------------------------------------------------- DFMF


@pytest.mark.parametrize("signature", ["!DFMF08FCR", "!DFMF08FC"])
def test_dfmf_model11_matches_btflib_formula_and_btf_extractor(tmp_path, extractor, signature):
    rgb = images()
    chans = dfmf_channels(rgb)
    path = w.dfmf_file(tmp_path / "m.btf", chans, signature=signature, rotations=2, **GEOM)
    btf = read_ubo2014(path)
    ours = btf.read_encoded(slice(None))
    values = channel_values(chans)
    want = as_images(w.model11_to_rgb_btflib(values))
    np.testing.assert_allclose(ours, want, rtol=2e-6, atol=1e-6)
    np.testing.assert_allclose(ours, rgb, atol=2e-3)  # half-float factors of the original images
    theirs = extracted(extractor, path)
    # The extractor computes zeroeffects' inverse from the same factor layout ...
    np.testing.assert_allclose(theirs, as_images(w.model11_to_rgb_zeroeffects(values)), rtol=2e-6, atol=1e-6)
    # ... which differs from btflib's by eps (1 - c1) in the chroma: a few 1e-5 here.
    diff = np.abs(theirs - ours)
    assert diff.max() < 1e-4 and diff.max() > 0


def test_dfmf_model0_identical_to_btf_extractor_and_row_order(tmp_path, extractor):
    rgb = images(2)
    rgb[:, 0] += 0.6  # top row (file row 0) brighter than the rest
    chans = dfmf_channels(rgb, model=0)
    path = w.dfmf_file(tmp_path / "rgb.btf", chans, model=0, **GEOM)
    ours = read_ubo2014(path).read_encoded(slice(None))
    np.testing.assert_allclose(ours, as_images(channel_values(chans)), rtol=2e-6, atol=1e-6)
    assert (ours[:, 0].mean(axis=(1, 2)) > ours[:, 1:].mean(axis=(1, 2, 3)) + 0.3).all()
    raw = extractor.Ubo2014(str(path))._angleindex_to_image_unsafe(1, 2)[..., ::-1]
    np.testing.assert_allclose(raw[::-1], ours[2 * 3 + 1], rtol=2e-6, atol=1e-6)  # sample v=2, l=1
    np.testing.assert_allclose(raw[-1], ours[7, 0], rtol=2e-6, atol=1e-6)  # extractor's bottom row = file row 0
    np.testing.assert_allclose(extracted(extractor, path), ours, rtol=2e-6, atol=1e-6)


def test_direction_tables_match_btf_extractor_and_known_direction(tmp_path, extractor):
    path = w.dfmf_file(tmp_path / "d.btf", dfmf_channels(images()), **GEOM)
    btf = read_ubo2014(path)
    e = extractor.Ubo2014(str(path))
    assert len(e.angles_vs_index_dict) == btf.n_samples
    for (tl, pl, tv, pv), (li, vi) in e.angles_vs_index_dict.items():
        s = vi * len(LIGHTS) + li
        for ours, theirs in ((btf.sampling.light[s], (tl, pl)), (btf.sampling.view[s], (tv, pv))):
            assert ours[0] == pytest.approx(theirs[0], abs=0.051)
            if theirs[0] > 0:
                assert (ours[1] - theirs[1] + 180) % 360 - 180 == pytest.approx(0, abs=0.051)
    # Light 2 is stored as (pi/4, pi/2): 45 deg from the normal toward the image's top edge
    # (+y in usdbtf's tangent frame = toward file row 0).
    np.testing.assert_allclose(btf.sampling.light[2], [45.0, 90.0], atol=1e-5)
    np.testing.assert_allclose(to_vectors(btf.sampling.light[2:3])[0], [0, np.sqrt(0.5), np.sqrt(0.5)], atol=1e-6)
    np.testing.assert_allclose(btf.sampling.view[::3, 0], [0, 30, 45], atol=1e-5)  # view-major order


def test_bonn_angles_canonical():
    got = bonn_to_tangent_degrees([[0.0, 1.3], [-np.pi / 6, 0.0], [np.pi / 3, -np.pi / 2], [np.pi / 2, 2 * np.pi]])
    np.testing.assert_allclose(got, [[0, 0], [30, 180], [60, 270], [90, 0]], atol=1e-9)
    with pytest.raises(BTFError, match="below the horizon"):
        bonn_to_tangent_degrees([[2.0, 0.0]])


def test_dfmf_truncated_k_texel_arrangement_and_float_scalars(tmp_path):
    rgb = images(3)
    chans = [(s[:kc], u[:, :kc], sxv[:, :kc]) for (s, u, sxv), kc in zip(dfmf_channels(rgb), (5, 2, 1))]
    for over_samples, scalar in ((True, 2), (False, 4)):
        path = w.dfmf_file(tmp_path / f"t{over_samples}.btf", chans, k_max=6, over_samples=over_samples,
                           scalar_size=scalar, **GEOM)
        btf = read_ubo2014(path)
        want = np.maximum(as_images(w.model11_to_rgb_btflib(channel_values(chans, scalar))), 0)
        np.testing.assert_allclose(btf.read_encoded(slice(None)), want, rtol=2e-5, atol=2e-6)
        f = btf.factors
        assert f.kind == "DFMF" and f.component_counts == [5, 2, 1] and f.color_model == 11
        assert f.channels[0].samples.shape == (S, 5) and f.channels[0].texels.shape == (T, 5)


def test_lazy_blocks_pickling_and_metadata(tmp_path):
    path = w.dfmf_file(tmp_path / "lazy.btf", dfmf_channels(images()), ppmm=20.0, **GEOM)
    btf = open_btf(path)
    assert isinstance(btf, UBO2014BTF) and is_ubo2014(path) and not is_ubo2014(tmp_path)
    full = btf.read_encoded(slice(None))
    np.testing.assert_array_equal(btf.read_encoded([7, 2], rows=(1, 3)), full[[7, 2], 1:3])
    np.testing.assert_allclose(btf.read_rows(1, 3), btf.read_samples(slice(None))[:, 1:3], rtol=1e-6)
    assert btf.metadata["physical_size_m"] == pytest.approx([W / 20 / 1000, H / 20 / 1000])
    assert btf.names[5] == "lazy.btf[view 1, light 2]"
    clone = pickle.loads(pickle.dumps(btf))
    np.testing.assert_array_equal(clone.read_encoded([4]), full[[4]])
    with pytest.raises(BTFError, match="rows 3..9"):
        btf.read_encoded([0], rows=(3, 9))


def test_cosine_flag_divides_out_light_cosine(tmp_path):
    chans = dfmf_channels(images(), model=0)
    plain = read_ubo2014(w.dfmf_file(tmp_path / "a.btf", chans, model=0, **GEOM)).read_encoded(slice(None))
    cos = read_ubo2014(w.dfmf_file(tmp_path / "b.btf", chans, model=0, cosine_flag=1, **GEOM)).read_encoded(slice(None))
    np.testing.assert_allclose(cos * np.tile(np.cos(LIGHTS[:, 0]), 3)[:, None, None, None], plain, rtol=1e-6)


# --------------------------------------------------------------------------- FMF


@pytest.mark.parametrize("signature,drr", [("!FMF12FCER", 1), ("!FMF12FCE", 0), ("!FMF06FCR", 0), ("!FMF06FC", 0)])
def test_fmf_matches_reference_and_btf_extractor(tmp_path, extractor, signature, drr):
    rgb = images(4)
    data = np.log(rgb + w.EPS) if drr else rgb
    # One factorisation of all channels: rows c + nC s, columns texels.
    matrix = data.reshape(S, T, 3).transpose(0, 2, 1).reshape(S * 3, T)
    s, u, sxv = w.factorise(matrix, T)
    path = w.fmf_file(tmp_path / "f.btf", s, u, sxv, signature=signature, drr=drr, header_version=2,
                      height_map=(3, 2), **GEOM)
    btf = read_ubo2014(path)
    values = (w.stored(u, 2) @ w.stored(sxv, 2).T).reshape(S, 3, T).transpose(0, 2, 1)
    if drr:
        values = np.exp(values) - w.EPS
    ours = btf.read_encoded(slice(None))
    np.testing.assert_allclose(ours, as_images(values), rtol=2e-6, atol=1e-6)
    np.testing.assert_allclose(ours, rgb, atol=2e-2)
    np.testing.assert_allclose(extracted(extractor, path), ours, rtol=2e-6, atol=2e-6)
    f = btf.factors
    assert f.kind == "FMF" and f.component_counts == [T] * 3 and f.dynamic_range_reduction == drr
    assert f.channels[0].texels is f.channels[2].texels  # shared by all channels


# --------------------------------------------------------------------------- PVF, BDI


@pytest.mark.parametrize("over_texels,legacy", [(True, False), (False, False), (True, True)],
                         ids=["weights over texels", "weights over lights", "legacy header"])
def test_pvf_matches_reference(tmp_path, over_texels, legacy):
    rng = np.random.default_rng(5)
    nl, k = len(LIGHTS), 3
    per_view, want = [], np.empty((S, T, 3))
    for v in range(len(VIEWS)):
        dim, n = (3 * nl, T) if over_texels else (3 * T, nl)
        ev, mean = rng.random(k), 0.5 + 0.1 * rng.random(dim)
        comp, weights = 0.1 * rng.standard_normal((dim, k)), rng.random((n, k))
        per_view.append((ev, mean, comp, weights))
        vals = comp @ weights.T + mean[:, None]                      # (dim, n)
        if over_texels:                                              # rows c + nC l, columns texels
            want[v * nl:(v + 1) * nl] = vals.reshape(nl, 3, T).transpose(0, 2, 1)
        else:                                                        # rows c + nC t, columns lights
            want[v * nl:(v + 1) * nl] = vals.reshape(T, 3, nl).transpose(2, 0, 1)
    path = w.pvf_file(tmp_path / "p.btf", per_view, legacy=legacy, **GEOM)
    btf = read_ubo2014(path)
    assert btf.factors is None and btf.describe()["components"] == [k] * 3
    np.testing.assert_allclose(btf.read_encoded(slice(None)), as_images(np.maximum(want, 0)), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(btf.read_encoded([8, 1], rows=(2, 4)), as_images(np.maximum(want, 0))[[8, 1], 2:4],
                               rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("sparse", [False, True])
def test_bdi_matches_reference(tmp_path, sparse):
    rgb = images(6)
    abrdfs = rgb.reshape(len(VIEWS), len(LIGHTS), H, W, 3).transpose(2, 3, 0, 1, 4)   # (H, W, nV, nL, nC)
    mask = None
    want = rgb.astype(np.float16).astype(np.float64)
    if sparse:
        mask = np.ones((H, W), bool)
        mask[1, 2] = mask[3, 0] = mask[3, 5] = False
        want = want * mask[None, :, :, None]
    path = w.bdi_file(tmp_path / "b.btf", abrdfs, mask=mask, lines=3, **GEOM)
    btf = read_ubo2014(path)
    np.testing.assert_array_equal(btf.read_encoded(slice(None)), want.astype(np.float32))
    np.testing.assert_array_equal(btf.read_encoded([3, 8], rows=(1, 4)), want[[3, 8], 1:4].astype(np.float32))
    assert btf.describe()["stored_texels"] == (T - 3 if sparse else T)


# --------------------------------------------------------------------------- colour models


def test_color_model_inverses():
    rgb = np.random.default_rng(7).uniform(0.05, 2.0, (50, 3))
    yuv = rgb @ w.RGB_TO_YUV.T
    y = yuv[:, :1]
    t = np.array([[0.5, 0.3, 0.2], [-0.1, 0.7, 0.2], [0.3, -0.2, 0.9]])
    mean = np.array([0.2, 0.1, 0.3])
    ycocg = rgb @ np.linalg.inv(np.array([[1, 1, -1], [1, 0, 1], [1, -1, -1]], float)).T
    forward = {
        1: yuv,
        3: (rgb - mean) @ np.linalg.inv(t),
        4: ycocg,
        9: np.c_[np.log(y + w.EPS), yuv[:, 1:]],
        10: np.c_[np.log(y + w.EPS), np.sign(yuv[:, 1:]) * (np.log(np.abs(yuv[:, 1:])) - np.log(w.EPS))],
        11: w.rgb_to_model11(rgb),
        12: np.log(rgb + w.EPS),
    }
    for model, enc in forward.items():
        got = undecorrelate(enc.astype(np.float32), model, mean=mean, matrix=t)
        np.testing.assert_allclose(got, rgb, rtol=2e-5, atol=2e-5, err_msg=f"model {model}")
    v = np.array([[2.0, 0.25, 0.5]], np.float32)
    np.testing.assert_allclose(undecorrelate(v.copy(), 5), [[0.5, 0.5, 1.0]])         # sum, ratios
    np.testing.assert_allclose(undecorrelate(v.copy(), 6), [[6 - 0.25, 6 * 1.25, 6 * 1.5]], rtol=1e-6)
    np.testing.assert_array_equal(undecorrelate(v.copy(), 0), v)


# --------------------------------------------------------------------------- info, bad input


def data_error_status() -> int:
    """The exit status of a BTFError.  BTFError.exit_code (65) once the CLI maps exit codes
    (the safety branch); the CLI on this branch still returns EXIT_BAD_INPUT (2) for all."""
    return getattr(cli, "EXIT_BAD_INPUT", BTFError.exit_code)


def test_info_names_signature_directions_and_components(tmp_path, capsys):
    chans = [(s[:kc], u[:, :kc], sxv[:, :kc]) for (s, u, sxv), kc in zip(dfmf_channels(images()), (7, 3, 2))]
    path = w.dfmf_file(tmp_path / "carpet01.btf", chans, **GEOM)
    code, out, err = run(capsys, "info", path)
    assert code == 0, err
    assert "UBO2014 DFMF BTF, 3 views x 3 lights = 9 samples of 6x4 texels (signature !DFMF08FCR)" in out
    assert "colour model 11 (log Y, U/Y, V/Y)" in out and "Linear Rec.709 (sRGB)" in out
    assert "channel 0: 7, channel 1: 3, channel 2: 2  (half floats)" in out
    # --json: the same facts, machine-readable (issue 15's info --json with issue 18's reader).
    code, out, err = run(capsys, "info", path, "--json")
    assert code == 0, err
    info = json.loads(out)
    assert (info["format"], info["views"], info["lights"], info["samples"], info["width"], info["height"]) == \
        ("UBO2014 DFMF", 3, 3, 9, 6, 4)
    assert info["file"]["signature"] == "!DFMF08FCR" and info["file"]["components"] == [7, 3, 2]
    assert info["file"]["color_model"] == 11


def _bad(tmp_path, name: str, data: bytes) -> Path:
    p = tmp_path / name
    p.write_bytes(data)
    return p


def good_dfmf(tmp_path) -> Path:
    return w.dfmf_file(tmp_path / "good.btf", dfmf_channels(images(), k=4), **GEOM)


def _channel0_offset(data: bytes) -> int:
    """Offset of channel 0's block header in a good DFMF file (after the 52-byte DFMF header)."""
    sig = len(b"!DFMF08FCR")
    meta = struct.unpack("<I", data[sig:sig + 4])[0]
    dirs = 4 + len(VIEWS) * (8 + 4 + 8 * len(LIGHTS))
    return sig + meta + dirs + 8 + 4 + 56  # + size, rotations count, DFMF header (k_max, model, mean, matrix)


def _resize(data: bytes, width: int, height: int) -> bytes:
    """Declare width x height in the header and in every channel's column count."""
    data = data.replace(struct.pack("<II", W, H), struct.pack("<II", width, height), 1)
    return data.replace(struct.pack("<II", S, T), struct.pack("<II", S, width * height))


BAD_CASES = {
    "wrong signature": (lambda d: b"!XYZ99" + d[6:], "not a Bonn BTF file"),
    "truncated factor block": (lambda d: d[:-100], "channel 2 factor block (S*V): truncated"),
    "trailing bytes": (lambda d: d + b"\0" * 8, "8 unexpected bytes after the last block"),
    "k above header": (lambda d: d[:_channel0_offset(d) - 56] + struct.pack("<I", 2) + d[_channel0_offset(d) - 52:],
                       "channel 0 factor block: component count 4 disagrees with the header's maximum of 2"),
    "rows disagree": (lambda d: d[:_channel0_offset(d) + 5] + struct.pack("<I", 10) + d[_channel0_offset(d) + 9:],
                      "channel 0 factor block: matrix is 10 x 24"),
    "NaN in a factor": (lambda d: d[:_channel0_offset(d) + 13 + 8 + 6] + np.float16(np.nan).tobytes()
                        + d[_channel0_offset(d) + 13 + 8 + 8:], "channel 0 factor block (U): holds NaN or Inf"),
    "absurd dimensions": (lambda d: d.replace(struct.pack("<II", W, H), struct.pack("<II", 100000, 100000), 1),
                          "channel 0 factor block: matrix is 9 x 24"),
    "absurd but consistent": (lambda d: _resize(d, 60000, 60000), "channel 0 factor block (S*V): truncated: needs"),
    "meta size": (lambda d: d[:10] + struct.pack("<I", struct.unpack("<I", d[10:14])[0] + 4) + d[14:],
                  "meta data block: declares"),
    "colour model": (lambda d: d[:_channel0_offset(d) - 52] + struct.pack("<i", 7) + d[_channel0_offset(d) - 48:],
                     "unknown colour model 7"),
    "CIELAB": (lambda d: d[:_channel0_offset(d) - 52] + struct.pack("<i", 2) + d[_channel0_offset(d) - 48:],
               "colour model 2 (CIELAB) is not supported"),
    "view count": (lambda d: d[:10 + struct.unpack("<I", d[10:14])[0]] + struct.pack("<I", 0xFFFFFFFF)
                   + d[14 + struct.unpack("<I", d[10:14])[0]:], "view count 4294967295 does not fit"),
}


@pytest.mark.parametrize("case", list(BAD_CASES))
def test_bad_dfmf_one_clear_error(tmp_path, capsys, case):
    corrupt, message = BAD_CASES[case]
    path = _bad(tmp_path, "bad.btf", corrupt(good_dfmf(tmp_path).read_bytes()))
    with pytest.raises(BTFError) as exc:
        read_ubo2014(path)
    assert str(path) in str(exc.value) and message in str(exc.value), str(exc.value)
    code, out, err = run(capsys, "info", path)
    assert code == data_error_status()
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("usdbtf info: error: ") and message in lines[0], err
    assert "Traceback" not in err


def test_bad_other_formats(tmp_path):
    chans = dfmf_channels(images(), k=3)
    views2 = np.array([[0.0, 0.0], [0.5, 0.0], [2.5, 0.0]])          # theta 143 deg: below the horizon
    cases = [
        (w.dfmf_file(tmp_path / "h.btf", chans, views_rad=views2, lights_rad=LIGHTS, width=W, height=H),
         "direction table: direction 2: theta 143.2394 deg is below the horizon"),
        (w.fmf_file(tmp_path / "f.btf", *w.factorise(np.ones((3 * S, T)), 2), k_repeat=3, **GEOM),
         "factor block: component count 3 disagrees with the header's 2"),
        (w.fmf_file(tmp_path / "v.btf", *w.factorise(np.ones((3 * S, T)), 2), header_version=3, **GEOM),
         "FMF header: unknown header version 3"),
        (w.bdi_file(tmp_path / "z.btf", np.ones((H, W, 3, 3, 3)), compression=1, **GEOM),
         "compression 1 is not supported"),
        (w.dfmf_file(tmp_path / "c.btf", chans, channel_names=("R", "G", "B", "IR"), **GEOM),
         "4 channels (R, G, B, IR); only RGB"),
    ]
    for path, message in cases:
        with pytest.raises(BTFError) as exc:
            read_ubo2014(path)
        assert str(path) in str(exc.value) and message in str(exc.value), str(exc.value)
    # A BDI holds every image: its values are checked when read, naming the sample.
    bad = np.ones((H, W, 3, 3, 3))
    bad[2, 3, 1, 2, 0] = np.nan
    btf = read_ubo2014(w.bdi_file(tmp_path / "n.btf", bad, **GEOM))
    with pytest.raises(BTFError, match=r"n.btf\[view 1, light 2\]: pixel values include NaN"):
        btf.read_samples(slice(None))


def test_view_dependent_light_lists_refused(tmp_path):
    path = good_dfmf(tmp_path)
    data = bytearray(path.read_bytes())
    first = data.index(np.asarray(LIGHTS, "<f4").tobytes())
    second = data.index(np.asarray(LIGHTS, "<f4").tobytes(), first + 1)
    data[second:second + 4] = np.float32(0.3).tobytes()
    path.write_bytes(bytes(data))
    with pytest.raises(BTFError, match=r"direction table \(view 1\): lists 3 lights that differ from view 0's"):
        read_ubo2014(path)


def test_memory_estimated_before_expanding(tmp_path, monkeypatch):
    from usdbtf.ubo2014 import reader

    btf = read_ubo2014(good_dfmf(tmp_path))
    monkeypatch.setattr(reader, "_available_bytes", lambda: 1000)
    with pytest.raises(BTFError, match="good.btf: expanding 9 samples x 4 rows needs about"):
        btf.read_samples(slice(None))


@pytest.mark.parametrize("fmt", ["DFMF", "PVF"])
def test_values_do_not_depend_on_the_request(tmp_path, monkeypatch, fmt):
    """Products run on fixed aligned tiles: any chunking reads bit-identical values (here
    with tiles small enough that every request spans several)."""
    from usdbtf.ubo2014 import formats

    monkeypatch.setattr(formats, "SAMPLE_TILE", 4)
    monkeypatch.setattr(formats, "TEXEL_TILE", 10)
    if fmt == "DFMF":
        path = w.dfmf_file(tmp_path / "t.btf", dfmf_channels(images(8), k=6), **GEOM)
    else:
        rng = np.random.default_rng(8)
        per_view = [(rng.random(2), 0.5 + rng.random(3 * len(LIGHTS)) * 0.1, 0.1 * rng.random((3 * len(LIGHTS), 2)),
                     rng.random((T, 2))) for _ in VIEWS]
        path = w.pvf_file(tmp_path / "t.btf", per_view, **GEOM)
    btf = read_ubo2014(path)
    full = btf.read_encoded(slice(None))
    chunked = np.concatenate([btf.read_encoded(slice(a, a + 2)) for a in range(0, S, 2)])
    np.testing.assert_array_equal(chunked, full)
    rows = np.concatenate([btf.read_encoded(slice(None), rows=(y, y + 1)) for y in range(H)], axis=1)
    np.testing.assert_array_equal(rows, full)
    np.testing.assert_array_equal(btf.read_encoded([8, 0, 5], rows=(1, 3)), full[[8, 0, 5], 1:3])
