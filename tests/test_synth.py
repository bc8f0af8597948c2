"""Tests for usdbtf.synth: the procedural synthetic BTF generator.

Conventions under test (see the module docstring): texel (i, j) sits at x = j,
y = -i (row 0 = top = +y side, column 0 = left = -x side); directions (theta, phi)
point away from the surface; reference plane at the mean height.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from usdbtf import synth
from usdbtf.sampling import Sampling, preset, to_vectors

E = synth.IRRADIANCE


def _flat(n=16, albedo=0.7, specular=0.0, roughness=0.5, sheen=0.0, height=None):
    return synth.Material(
        height=np.zeros((n, n), np.float32) if height is None else height,
        albedo=np.full((n, n, 3), albedo, np.float32),
        specular=np.full((n, n), specular, np.float32),
        roughness=np.full((n, n), roughness, np.float32),
        sheen=sheen,
        name="test",
    )


def _bump(n=32, amp=6.0, radius=4.0, flat_top=False):
    """A single bump centred on texel (n/2, n/2) on flat ground at height 0."""
    r, c = np.mgrid[0:n, 0:n].astype(np.float64)
    d = np.hypot(r - n / 2, c - n / 2)
    if flat_top:  # a steep-sided disc: height amp inside radius, ~1 texel edge
        h = amp * np.clip(radius + 0.5 - d, 0.0, 1.0)
    else:
        h = amp * np.exp(-0.5 * (d / radius) ** 2)
    return _flat(n, height=h.astype(np.float32))


def _bilinear_wrap(img, rows, cols):
    """Independent reference for bilinear lookup with wrap-around."""
    n = img.shape[0]
    r0, c0 = np.floor(rows).astype(int), np.floor(cols).astype(int)
    fr, fc = rows - r0, cols - c0
    a, b = img[r0 % n, c0 % n], img[r0 % n, (c0 + 1) % n]
    c, d = img[(r0 + 1) % n, c0 % n], img[(r0 + 1) % n, (c0 + 1) % n]
    return (1 - fr) * ((1 - fc) * a + fc * b) + fr * ((1 - fc) * c + fc * d)


def _lum(img):
    return img @ np.array([0.2126, 0.7152, 0.0722], np.float32)


# ------------------------------------------------------------------ materials


@pytest.mark.parametrize("name", sorted(synth.PRESETS))
def test_preset_deterministic_and_seeded(name):
    a = synth.make_material(name, 32, seed=3)
    b = synth.make_material(name, 32, seed=3)
    c = synth.make_material(name, 32, seed=4)
    for field in ("height", "albedo", "specular", "roughness"):
        assert getattr(a, field).tobytes() == getattr(b, field).tobytes(), field
    assert a.sheen == b.sheen and a.name == b.name == name
    assert not np.array_equal(a.height, c.height)
    assert not np.array_equal(a.albedo, c.albedo)


@pytest.mark.parametrize("name", sorted(synth.PRESETS))
def test_preset_arrays_valid(name):
    m = synth.make_material(name, 48, seed=1)
    assert m.size == 48
    assert m.height.shape == m.specular.shape == m.roughness.shape == (48, 48)
    assert m.albedo.shape == (48, 48, 3)
    for arr in (m.height, m.albedo, m.specular, m.roughness):
        assert arr.dtype == np.float32
        assert np.all(np.isfinite(arr))
        assert not arr.flags.writeable
    assert 0 <= m.albedo.min() and m.albedo.max() <= 1
    assert m.roughness.min() > 0
    # relief scales with the tile: several texels at 128, so parallax and shadows
    # show clearly at grazing angles
    assert np.ptp(m.height) > 0.04 * 48
    assert np.ptp(synth.make_material(name, 128, seed=1).height) > 5.0


def test_unknown_preset_names_choices():
    with pytest.raises(ValueError, match="pebbles.*ridged_fabric.*fuzzy_moss"):
        synth.make_material("granite")


def test_material_validation():
    good = _flat(8)
    with pytest.raises(ValueError):
        synth.Material(np.zeros((8, 9)), good.albedo, good.specular, good.roughness)
    with pytest.raises(ValueError):
        synth.Material(good.height, good.albedo[..., :2], good.specular, good.roughness)
    with pytest.raises(ValueError):
        synth.Material(good.height, good.albedo * 2, good.specular, good.roughness)
    with pytest.raises(ValueError):
        synth.Material(good.height, good.albedo, good.specular, np.zeros((8, 8)))
    # the material copies its inputs: later edits by the caller don't leak in
    h = np.zeros((8, 8), np.float32)
    m = synth.Material(h, good.albedo, good.specular, good.roughness)
    h[0, 0] = 5
    assert m.height[0, 0] == 0


def test_presets_differ():
    mats = {name: synth.make_material(name, 64, seed=0) for name in ("pebbles", "ridged_fabric", "fuzzy_moss")}
    peb, fab, moss = mats["pebbles"], mats["ridged_fabric"], mats["fuzzy_moss"]
    # moss is green; pebbles greyish-brown (red >= blue, channels close)
    g = moss.albedo.mean(axis=(0, 1))
    assert g[1] > 1.3 * g[0] and g[1] > 2 * g[2]
    p = peb.albedo.mean(axis=(0, 1))
    assert p[0] >= p[2] and p.max() / p.min() < 1.6
    # gloss: pebbles > fabric > moss (almost none); sheen: moss > fabric > pebbles
    assert peb.specular.mean() > moss.specular.mean() * 3
    assert peb.roughness.mean() < fab.roughness.mean() < moss.roughness.mean()
    assert moss.sheen > fab.sheen > peb.sheen == 0
    # moss is the finest and tallest relief: steepest slopes
    slope = {k: np.abs(np.diff(m.height, axis=1)).mean() / np.ptp(m.height) for k, m in mats.items()}
    assert np.abs(np.diff(moss.height, axis=1)).mean() > np.abs(np.diff(peb.height, axis=1)).mean()
    assert len(set(round(s, 3) for s in slope.values())) == 3
    # fabric is periodic along both axes (the weave repeats every 2 threads)
    period = 2 * 64 // (2 * round(64 / 16))
    assert np.corrcoef(fab.height.ravel(), np.roll(fab.height, period, axis=1).ravel())[0, 1] > 0.8
    assert np.corrcoef(fab.height.ravel(), np.roll(fab.height, period, axis=0).ravel())[0, 1] > 0.8
    assert np.corrcoef(peb.height.ravel(), np.roll(peb.height, period, axis=1).ravel())[0, 1] < 0.5


# --------------------------------------------------------------------- tiling


@pytest.mark.parametrize("name", sorted(synth.PRESETS))
def test_heightfield_tiles(name):
    h = synth.make_material(name, 64, seed=2).height.astype(np.float64)
    for hh in (h, h.T):
        seam = np.abs(hh[:, 0] - hh[:, -1]).mean()
        cols = np.abs(np.diff(hh, axis=1)).mean(axis=0)  # mean step per column pair
        assert seam <= 2.0 * cols.mean()
        assert seam <= cols.max() * 1.001


@pytest.mark.parametrize("name", sorted(synth.PRESETS))
def test_render_tiles_and_is_translation_equivariant(name):
    m = synth.make_material(name, 32, seed=0)
    view, light = (50.0, 30.0), (60.0, 200.0)
    img = synth.render_sample(m, view, light).astype(np.float64)
    seam = np.abs(img[:, 0] - img[:, -1]).mean()
    inner = np.abs(np.diff(img, axis=1)).mean()
    assert seam <= 2.0 * inner
    # All lookups wrap: rendering the material rolled on the torus equals rolling the
    # rendering (a non-wrapping lookup would break this near the edges).
    shift = (11, -7)

    def roll(a):
        return np.roll(a, shift, axis=(0, 1))

    rolled = synth.Material(roll(m.height), roll(m.albedo), roll(m.specular), roll(m.roughness), m.sheen,
                            retro=m.retro, slope=None if m.slope is None else roll(m.slope))
    # rtol: flake sparkles reach ~50, where float32 rounding of the bilinear weights shows
    np.testing.assert_allclose(synth.render_sample(rolled, view, light), roll(img), atol=2e-4, rtol=1e-4)


# ------------------------------------------------------------ masking/parallax


def test_masking_changes_image_and_hit_displacement_sign():
    m = synth.make_material("pebbles", 64, seed=0)
    cache = synth.RenderCache(m)
    top = synth.render_sample(m, (0, 0), (0, 0), cache=cache)
    graze = synth.render_sample(m, (70, 0), (0, 0), cache=cache)
    assert np.abs(top - graze).mean() > 0.02

    rows, cols = np.mgrid[0:64, 0:64].astype(np.float64)
    head_on = synth.trace_view(m, (0, 0), cache=cache)
    np.testing.assert_allclose(head_on.row, rows)
    np.testing.assert_allclose(head_on.col, cols)

    tan = math.tan(math.radians(70))
    for phi, (ex, ey) in {0: (1, 0), 90: (0, 1), 180: (-1, 0), 270: (0, -1)}.items():
        hits = synth.trace_view(m, (70, phi), cache=cache)
        dx = hits.col - cols  # +x = +column
        dy = -(hits.row - rows)  # +y = -row
        assert np.abs(dx).max() + np.abs(dy).max() > 2.0
        # The hit lies on the ray towards the camera: displacement = h tan(theta) (cos, sin)(phi)
        np.testing.assert_allclose(dx, hits.height * tan * ex, atol=2e-3)
        np.testing.assert_allclose(dy, hits.height * tan * ey, atol=2e-3)
        # ... and the hit height is the heightfield's there (first intersection)
        high = hits.height > 1.0
        assert high.mean() > 0.05
        along = dx * ex + dy * ey
        assert np.all(along[high] > 0), f"phi={phi}: high hits must move towards the camera azimuth"
        low = hits.height < -0.5
        assert np.all(along[low] < 0)
        # the hit is on the surface: its height is the (bilinear) heightfield's there
        resid = np.abs(hits.height - _bilinear_wrap(m.height - m.height.mean(), hits.row, hits.col))
        assert np.percentile(resid, 99) < 1e-2 and resid.max() < 0.25


def test_bump_appears_shifted_away_from_camera_and_hides_ground_behind():
    n, amp, radius = 48, 6.0, 5.0
    m = _bump(n, amp=amp, radius=radius, flat_top=True)
    c0 = n / 2
    tan = math.tan(math.radians(60))
    hits = synth.trace_view(m, (60, 0))  # camera on the +x side
    rows, cols = np.mgrid[0:n, 0:n]
    on_top = hits.height > amp - 0.5 - m.height.mean()
    # the top of the bump is seen at texels shifted by -h tan(theta) along x
    assert np.isclose(cols[on_top].mean(), c0 - amp * tan, atol=1.0)
    assert np.isclose(rows[on_top].mean(), c0, atol=0.5)
    # ground just behind the bump (the -x side) is masked: no texel shows it
    ground = hits.height < 0.5 - m.height.mean()
    row = int(c0)
    seen = np.mod(hits.col[row][ground[row]], n)
    behind_lo, behind_hi = c0 - radius - amp * tan + 1.5, c0 - radius - 1.0
    assert behind_hi - behind_lo > 5
    assert not np.any((seen > behind_lo) & (seen < behind_hi))
    # whereas head-on it is visible
    assert np.any((cols[row] > behind_lo) & (cols[row] < behind_hi))


# ------------------------------------------------------------------- shadows


def test_low_light_casts_more_shadow():
    m = synth.make_material("pebbles", 64, seed=0)
    cache = synth.RenderCache(m)
    low = synth.shadow_map(m, (75, 30), cache=cache)
    high = synth.shadow_map(m, (0, 0), cache=cache)
    assert low.shape == (64, 64) and low.dtype == np.float32
    assert np.all((low >= 0) & (low <= 1))
    assert np.all(high == 1)
    assert (low < 0.5).mean() > 0.15
    # ... and in the images: more near-black texels, relative to the lit level
    img_low = _lum(synth.render_sample(m, (0, 0), (75, 30), cache=cache))
    img_high = _lum(synth.render_sample(m, (0, 0), (15, 30), cache=cache))
    dark_low = (img_low < 0.1 * np.median(img_low)).mean()
    dark_high = (img_high < 0.1 * np.median(img_high)).mean()
    assert dark_low > dark_high + 0.1


@pytest.mark.parametrize(
    "phi, axis, sign",
    [(0, "col", -1), (180, "col", +1), (90, "row", +1), (270, "row", -1)],
)
def test_shadow_falls_opposite_the_light(phi, axis, sign):
    # phi 0: light on the +x (right) side -> shadow to the left (smaller column);
    # phi 90: light on the +y (top) side -> shadow below (larger row).
    n = 32
    m = _bump(n, amp=6.0, radius=3.0)
    vis = synth.shadow_map(m, (70, phi))
    rows, cols = np.mgrid[0:n, 0:n]
    dark = vis < 0.5
    assert dark.sum() > 10
    coord = {"col": cols, "row": rows}[axis]
    other = {"col": rows, "row": cols}[axis]
    assert sign * (coord[dark].mean() - n / 2) > 3.0
    assert abs(other[dark].mean() - n / 2) < 1.0
    # the rendered head-on image shows the same shadow, with the opposite flank lit
    img = _lum(synth.render_sample(m, (0, 0), (70, phi)))
    ground_lit = 0.7 * E / math.pi * math.cos(math.radians(70))
    assert img[dark].max() < 0.5 * ground_lit
    assert img[~dark].mean() > 0.5 * ground_lit


def test_rotating_light_by_180_mirrors_shadow():
    m = _bump(32, amp=6.0, radius=3.0)
    a = synth.shadow_map(m, (65, 40))
    b = synth.shadow_map(m, (65, 220))
    # the bump is symmetric about its centre (16, 16): point reflection maps one onto the other
    b_reflected = np.roll(b[::-1, ::-1], (1, 1), axis=(0, 1))
    assert (a < 0.5).sum() > 10
    assert np.abs(a - b_reflected).mean() < 0.02
    assert np.abs(a - b).mean() > 0.05


# ------------------------------------------------------------------ shading


@pytest.mark.parametrize("view", [(0, 0), (45, 100), (70, 10)])
@pytest.mark.parametrize("light", [(0, 0), (30, 40), (60, 200), (75, 300)])
def test_flat_lambertian_is_albedo_over_pi_E_cos(view, light):
    m = _flat(16, albedo=0.7)
    img = synth.render_sample(m, view, light)
    expected = 0.7 / math.pi * E * math.cos(math.radians(light[0]))
    assert img.shape == (16, 16, 3) and img.dtype == np.float32
    np.testing.assert_allclose(img, expected, rtol=1e-5)


def test_white_lambertian_head_on_reads_0_8():
    img = synth.render_sample(_flat(8, albedo=1.0), (30, 0), (0, 0))
    np.testing.assert_allclose(img, 0.8, rtol=1e-6)


def test_flat_glossy_mirror_peak():
    m = _flat(8, albedo=0.2, specular=0.04, roughness=0.15)
    diffuse = 0.2 / math.pi * E * math.cos(math.radians(40))
    mirror = synth.render_sample(m, (40, 200), (40, 20))
    off = synth.render_sample(m, (40, 200), (40, 110))
    far = synth.render_sample(m, (40, 200), (40, 200))
    assert mirror.mean() > 2 * off.mean()
    assert mirror.mean() > 2 * diffuse
    assert off.mean() > far.mean() >= diffuse * (1 - 1e-5)
    # the specular lobe is uncoloured (white highlight on a grey albedo)
    assert np.ptp(mirror) < 1e-5


def test_sheen_brightens_grazing_only():
    plain = _flat(8, albedo=0.3)
    fuzzy = _flat(8, albedo=0.3, sheen=1.0)
    head_on = (0, 0), (0, 0)
    np.testing.assert_allclose(synth.render_sample(fuzzy, *head_on), synth.render_sample(plain, *head_on), rtol=1e-6)
    graze = (75, 0), (70, 10)
    assert synth.render_sample(fuzzy, *graze).mean() > 1.3 * synth.render_sample(plain, *graze).mean()


@pytest.mark.parametrize("axis", ["x", "y"])
def test_normal_orientation_on_a_ramp(axis):
    # A tilted plane (with a wrap-around cliff far from the inspected texels).
    n, slope = 32, 0.3
    r, c = np.mgrid[0:n, 0:n].astype(np.float32)
    if axis == "x":
        h = slope * c  # rises towards +x: faces -x, lit by a light from phi = 180
        toward, away = (45, 180), (45, 0)
        region = (slice(None), slice(10, 28))
        normal = np.array([-slope, 0, 1])
    else:
        h = slope * r  # rises with row = towards -y: faces +y, lit from phi = 90
        toward, away = (45, 90), (45, 270)
        region = (slice(10, 28), slice(None))
        normal = np.array([0, slope, 1])
    normal /= np.linalg.norm(normal)
    m = _flat(n, albedo=0.5, height=h)
    for light, other in ((toward, away), (away, toward)):
        img = synth.render_sample(m, (0, 0), light)[region]
        expected = 0.5 / math.pi * E * max(0.0, normal @ to_vectors(np.array([light]))[0])
        np.testing.assert_allclose(img, expected, rtol=1e-4)
    lit = synth.render_sample(m, (0, 0), toward)[region].mean()
    unlit = synth.render_sample(m, (0, 0), away)[region].mean()
    assert lit > 1.2 * unlit


def test_retro_lobe_is_exact_on_a_flat_surface():
    # L = E cos(theta_l) albedo (1/pi + retro (p + 2) / (2 pi) max(v.l, 0)^p (1 - n.v)):
    # nothing head-on (n.v = 1), strongest with the light behind a grazing camera.
    plain = _flat(8, albedo=0.3)
    retro = synth.Material(plain.height, plain.albedo, plain.specular, plain.roughness, retro=0.8)
    np.testing.assert_allclose(synth.render_sample(retro, (0, 0), (0, 0)), synth.render_sample(plain, (0, 0), (0, 0)),
                               rtol=1e-6)
    p = synth.RETRO_EXPONENT
    for view, light in (((60, 20), (60, 20)), ((60, 20), (40, 50)), ((70, 0), (30, 180))):
        v, l = to_vectors(np.array([view, light], float))
        lobe = 0.8 * (p + 2) / (2 * math.pi) * max(v @ l, 0.0) ** p * (1 - v[2])
        expected = E * math.cos(math.radians(light[0])) * 0.3 * (1 / math.pi + lobe)
        np.testing.assert_allclose(synth.render_sample(retro, view, light), expected, rtol=1e-5)
    graze = synth.render_sample(retro, (70, 0), (70, 0)).mean()
    assert graze > 2 * synth.render_sample(plain, (70, 0), (70, 0)).mean()


def test_slope_map_tilts_shading_not_geometry():
    # A flat surface with a constant slope map shades like the tilted plane of the ramp
    # test (n = (-0.3, 0, 1) / |.|) but casts no shadow and shows no parallax.
    slope = np.zeros((16, 16, 2), np.float32)
    slope[..., 0] = 0.3
    plain = _flat(16, albedo=0.5)
    tilted = synth.Material(plain.height, plain.albedo, plain.specular, plain.roughness, slope=slope)
    normal = np.array([-0.3, 0.0, 1.0]) / math.hypot(0.3, 1.0)
    for light in ((45, 180), (45, 0), (80, 0)):
        expected = 0.5 / math.pi * E * max(0.0, normal @ to_vectors(np.array([light], float))[0])
        np.testing.assert_allclose(synth.render_sample(tilted, (50, 90), light), expected, rtol=1e-4, atol=1e-7)
    assert np.all(synth.shadow_map(tilted, (80, 0)) == 1)
    hits = synth.trace_view(tilted, (60, 0))
    np.testing.assert_allclose(hits.col, np.mgrid[0:16, 0:16][1], atol=1e-6)


def test_new_material_fields_validated():
    good = _flat(8)
    with pytest.raises(ValueError, match="retro"):
        synth.Material(good.height, good.albedo, good.specular, good.roughness, retro=-1)
    with pytest.raises(ValueError, match="slope"):
        synth.Material(good.height, good.albedo, good.specular, good.roughness, slope=np.zeros((8, 8, 3)))
    with pytest.raises(ValueError, match="slope"):
        synth.Material(good.height, good.albedo, good.specular, good.roughness, slope=np.full((8, 8, 2), np.nan))
    m = synth.Material(good.height, good.albedo, good.specular, good.roughness, slope=np.zeros((8, 8, 2)))
    assert m.slope.dtype == np.float32 and not m.slope.flags.writeable


# ------------------------------------------------- the presets' characters


def _apparent(m, cache, view, light):
    """Mean luminance of one image over E cos(theta_l): an apparent BRDF, comparable across lights."""
    return float(_lum(synth.render_sample(m, view, light, cache=cache)).mean()) / (E * math.cos(math.radians(light[0])))


def test_crevice_stones_keep_their_dark_texels_in_shadow():
    # Deep narrow crevices: a quarter of the heightfield is shadowed under most lights
    # (the others: almost none), and the darkest image texels are mostly dark because
    # they are shadowed, not because of their albedo.
    n, s = 48, preset("small")
    share = {}
    for name in ("crevice_stones", "pebbles", "fuzzy_moss"):
        m = synth.make_material(name, n, seed=0)
        cache = synth.RenderCache(m)
        lights = np.unique(s.light, axis=0)
        mostly_shadowed = np.mean([cache.shadow(l) < 0.5 for l in lights], axis=0) > 0.5
        imgs = _lum(synth.render_all(m, s))
        shadowed = np.empty(imgs.shape, bool)
        for i, (v, l) in enumerate(zip(s.view, s.light)):
            hits = cache.hits(v)
            shadowed[i] = _bilinear_wrap(cache.shadow(l), hits.row, hits.col) < 0.5
        mean = imgs.mean(axis=0)
        darkest = mean <= np.percentile(mean, 10)
        share[name] = (mostly_shadowed.mean(), shadowed[:, darkest].mean())
    stones = share.pop("crevice_stones")
    assert stones[0] > 0.15, stones
    assert stones[1] > 0.35, stones
    for name, (mostly, dark) in share.items():
        assert mostly < 0.05 and stones[1] > 1.5 * dark, (name, mostly, dark)


def test_metal_flakes_sparkle():
    # Per texel, the brightest sample over the median one: a few flakes flare by orders
    # of magnitude (a heavy tail over the texels); a rough material's texels all peak alike.
    s = preset("small")
    tail = {}
    for name in ("metal_flakes", "pebbles", "satin_weave"):
        imgs = _lum(synth.render_all(synth.make_material(name, 48, seed=0), s))
        peak = imgs.max(axis=0) / np.maximum(np.median(imgs, axis=0), 1e-6)
        tail[name] = np.percentile(peak, 99) / np.median(peak)
    assert tail["metal_flakes"] > 20, tail
    assert tail["pebbles"] < 5 and tail["satin_weave"] < 5, tail
    # the flakes are spatially random: neighbouring texels do not flare together
    m = synth.make_material("metal_flakes", 48, seed=0)
    img = _lum(synth.render_sample(m, (30, 0), (30, 180)))
    hot = img > 10 * np.median(img)
    assert 0.005 < hot.mean() < 0.2
    assert (hot & np.roll(hot, 3, axis=1)).mean() < 0.3 * hot.mean()


def test_velvet_is_brighter_at_grazing():
    # Grazing over head-on apparent BRDF, camera beside the light: velvet's sheen and
    # retro-reflection make it the largest of all presets (masking alone brightens tall
    # rough materials at grazing too, but less) ...
    grazing = {}
    for name in synth.PRESETS:
        m = synth.make_material(name, 48, seed=0)
        cache = synth.RenderCache(m)
        head_on = _apparent(m, cache, (0, 0), (0, 0))
        grazing[name] = np.mean([_apparent(m, cache, (75, ph), (75, ph)) for ph in (0, 90, 180, 270)]) / head_on
    velvet = grazing.pop("velvet")
    assert velvet > 1.3 * max(grazing.values()), (velvet, grazing)
    # ... and the lobes are what does it: the same pile without them is several times
    # darker at grazing, a little darker head-on (where only the fibres' tilted flanks
    # see the lobes), and as dark with the light opposite the camera
    m = synth.make_material("velvet", 48, seed=0)
    bare = synth.Material(m.height, m.albedo, m.specular, m.roughness)
    for view, light, lo, hi in (((0, 0), (0, 0), 1.0, 1.5), ((75, 30), (75, 30), 4.0, None),
                                ((60, 30), (60, 30), 3.0, None), ((60, 30), (60, 210), 1.0, 1.2)):
        ratio = _apparent(m, None, view, light) / _apparent(bare, None, view, light)
        assert ratio >= lo and (hi is None or ratio <= hi), (view, light, ratio)


def test_satin_highlights_are_anisotropic_in_phi():
    # Half vector tilted 15 deg off the normal, turned about it: across the warp floats
    # (phi 0 / 180) the threads' flanks catch it, along them (90 / 270) hardly any texel
    # does.  The bright texels' level differs by a large factor; isotropic presets: none.
    def anisotropy(name):
        m = synth.make_material(name, 64, seed=0)
        cache = synth.RenderCache(m)
        p95 = [np.percentile(_lum(synth.render_sample(m, (55, ph), (25, ph + 180), cache=cache)), 95)
               for ph in (0, 90, 180, 270)]
        return (p95[0] + p95[2]) / (p95[1] + p95[3])

    assert anisotropy("satin_weave") > 2.0
    for name in ("pebbles", "ridged_fabric", "velvet"):
        assert 0.8 < anisotropy(name) < 1.25, name


# -------------------------------------------------------------- render / API


@pytest.mark.parametrize("name", sorted(synth.PRESETS))
def test_render_all_tiny_finite_nonnegative(name):
    m = synth.make_material(name, 32, seed=0)
    s = preset("tiny")
    imgs = synth.render_all(m, s)
    assert imgs.shape == (len(s), 32, 32, 3) and imgs.dtype == np.float32
    assert np.all(np.isfinite(imgs)) and imgs.min() >= 0
    # mostly below 1 so that 8-bit encodings only clip specular peaks (metallic flakes
    # are nothing but specular peaks: a few percent of their values clip, as a camera's would)
    assert np.percentile(imgs, 97 if name == "metal_flakes" else 99) < 1.0
    assert imgs.mean() > 0.02
    # render yields the same images, in sampling order, as one-at-a-time calls
    cache = synth.RenderCache(m)
    for k in (0, 7, len(s) - 1):
        np.testing.assert_array_equal(imgs[k], synth.render_sample(m, s.view[k], s.light[k], cache=cache))
    assert len(list(synth.render_samples(m, s))) == len(s)


def test_render_any_order_and_chunk():
    m = synth.make_material("ridged_fabric", 16, seed=0)
    s = preset("tiny")
    base = synth.render_all(m, s)
    order = np.random.default_rng(0).permutation(len(s))
    shuffled = Sampling(s.view[order], s.light[order])
    for chunk in (None, 1):
        out = np.stack(list(synth.render_samples(m, shuffled, chunk=chunk)))
        np.testing.assert_array_equal(out, base[order])


def test_render_checks_arguments_eagerly():
    with pytest.raises(TypeError):
        synth.render_samples(_flat(4), [((0, 0), (0, 0))])
    with pytest.raises(TypeError):
        synth.RenderCache("pebbles")


def test_cache_reuse_and_binding():
    m = synth.make_material("fuzzy_moss", 32, seed=0)
    cache = synth.RenderCache(m, max_views=2)
    a = synth.render_sample(m, (45, 10), (60, 100), cache=cache)
    for v in ((10, 0), (20, 0), (30, 0)):  # evict (45, 10)
        synth.render_sample(m, v, (60, 100), cache=cache)
    np.testing.assert_array_equal(a, synth.render_sample(m, (45, 10), (60, 100), cache=cache))
    np.testing.assert_array_equal(a, synth.render_sample(m, (45, 370), (60, -260)))  # same directions
    assert synth.trace_view(m, (45, 10), cache=cache) is synth.trace_view(m, (45, 10.0), cache=cache)
    other = synth.make_material("fuzzy_moss", 32, seed=0)
    with pytest.raises(ValueError, match="different Material"):
        synth.render_sample(other, (0, 0), (0, 0), cache=cache)


def test_direction_convention_matches_sampling():
    dirs = np.array([[0, 0], [10, 0], [45, 90], [70, 200], [75, 330]], float)
    ours = np.stack([synth._direction(d)[0] for d in dirs])
    np.testing.assert_allclose(ours, to_vectors(dirs), atol=1e-12)
    with pytest.raises(ValueError):
        synth.render_sample(_flat(4), (95, 0), (0, 0))
