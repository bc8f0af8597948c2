"""``usdbtf render`` reads the one copy lazily (issue 39): only the mip levels a frame samples are
built, a packaged asset's pages are read when a level needs them, and the picture is the one
the whole-texture path (level 0 held, every level boxed from it) gives, bit for bit.

Inputs: the pebbles sample of quilt_render_data (48², k 24), packaged (``usdbtf package``).
"""
from __future__ import annotations

import numpy as np
import pytest

from quilt_render_data import pebbles, work  # noqa: F401 (fixtures)
from quilt_render_data import cli, plane_with_uv
from usdbtf.camera import Camera
from usdbtf.compress import read_compressed
from usdbtf.gpu.tables import pack_count
from usdbtf.mesh import Mesh
from usdbtf.photometry import capture_irradiance
from usdbtf.render import Light, RenderOptions, Renderer
from usdbtf.render.texture import CoefficientTexture, _box, _texel_major
from usdbtf.usd.read import load_btf


@pytest.fixture(scope="module")
def asset(work, pebbles):
    out = work / "asset" / "pebbles.usda"
    cli("package", pebbles, "-o", out, "-q")
    return out


def test_levels_from_planes_equal_the_boxed_level_0(pebbles):
    """A level made plane by plane from the codes is the texel-major level 0 boxed n times."""
    cbtf = read_compressed(pebbles)
    texture = CoefficientTexture(cbtf, 24)
    level = _texel_major(cbtf, 24)
    for n in range(1, 4):
        level = _box(level)
        fresh = CoefficientTexture(cbtf, 24).level(n)
        assert fresh.dtype == np.float32 and np.array_equal(fresh, level)
    assert np.array_equal(texture.level(0), _texel_major(cbtf, 24))
    assert texture.built == [(0, "level 0")]


def test_lazy_asset_reads_the_pages_of_its_k_and_equals_the_eager_read(asset):
    eager, lazy = load_btf(asset), load_btf(asset, lazy=True, k=8)
    codes = lazy.coefficients.codes
    assert codes.reads == []                                                  # nothing read when opened
    for i in range(8):
        st = lazy.coefficients[i]
        assert st.pixels.dtype == eager.coefficients[i].pixels.dtype
        assert np.array_equal(st.pixels, eager.coefficients[i].pixels)
        assert np.array_equal(st.scale, eager.coefficients[i].scale)
    assert sorted({p for _, p in codes.reads}) == list(range(pack_count(8)))  # the first 8 vectors' packs only
    assert len(codes.reads) == pack_count(8)                                  # each once, walked in order


def _far_plane():
    """A 5 cm plane 0.6 m away in a 40 x 32 frame: several texels per pixel (no level 0)."""
    points, faces, uv = plane_with_uv(0.05, 4)
    camera = Camera(np.array([0.0, 0.0, 0.6]), np.zeros(3), np.array([0.0, 1.0, 0.0]), 12.0, 40, 32)
    return Mesh(points, faces, uv=uv), camera


def test_render_builds_only_the_sampled_levels_and_the_picture_is_unchanged(asset):
    mesh, camera = _far_plane()
    lights = [Light("directional", np.array([0.3, 0.2, 1.0]) / np.linalg.norm([0.3, 0.2, 1.0]),
                    capture_irradiance(1.0))]
    opts = RenderOptions(threads=1, shadows=False)
    lazy = Renderer(load_btf(asset, lazy=True), opts)
    image = lazy.render(mesh, camera, lights)
    built = dict(lazy.texture.built)
    assert image[..., 3].sum() > 100 and np.isfinite(image).all()
    assert 0 not in lazy.texture.levels and built and min(built) >= 1         # level 0 never built
    assert list(built.values())[0] == "planes"                                 # streamed, then boxed
    # Today's path: level 0 held whole, every level boxed from it.
    whole = Renderer(load_btf(asset), opts)
    whole.texture.levels[0] = _texel_major(whole.cbtf, whole.texture.k)
    assert np.array_equal(image, whole.render(mesh, camera, lights))


def test_close_up_reads_level_0_as_codes_and_the_picture_is_unchanged(asset):
    """Magnified (a texel over several pixels): level 0 held as codes, taps de-quantised."""
    points, faces, uv = plane_with_uv(0.05, 4)
    mesh = Mesh(points, faces, uv=uv)
    camera = Camera(np.array([0.0, 0.0, 0.03]), np.zeros(3), np.array([0.0, 1.0, 0.0]), 30.0, 64, 48)
    lights = [Light("point", np.array([0.01, 0.02, 0.05]), 0.01)]
    for filt in ("mip", "bilinear"):
        opts = RenderOptions(threads=2, chunk=1024, filter=filt)
        lazy = Renderer(load_btf(asset, lazy=True), opts)
        image = lazy.render(mesh, camera, lights)
        assert (image[..., 3] > 0).all()
        assert lazy.texture.built[0] == (0, "codes") and 0 not in lazy.texture.levels
        whole = Renderer(load_btf(asset), opts)
        whole.texture.levels[0] = _texel_major(whole.cbtf, whole.texture.k)
        assert np.array_equal(image, whole.render(mesh, camera, lights))


def _taps_of_the_whole_texture(renderer, mesh, camera, lights, tile: int):
    """(frame, {level: tiles its taps read}) of a renderer reading level 0 whole: the texels
    every tap reads, recorded as it shades, grouped into ``tile``-texel tiles by plain arithmetic."""
    texture = renderer.texture
    texture.levels[0] = _texel_major(renderer.cbtf, texture.k)
    seen, read = {}, texture._tap_texels

    def record(n, idx):
        seen.setdefault(n, []).append(np.unique(idx))
        return read(n, idx)

    texture._tap_texels = record
    image = renderer.render(mesh, camera, lights)
    tiles = {}
    for n, idx in seen.items():
        w = texture.level_shape(n)[1]
        y, x = np.divmod(np.unique(np.concatenate(idx)), w)
        tiles[n] = len(np.unique((y // tile) * -(-w // tile) + x // tile))
    return image, dict(sorted(tiles.items()))


@pytest.mark.parametrize("eye, target, up, fov, levels", [
    ((-0.03, -0.03, 0.012), (-0.005, -0.005, 0.0), (0.0, 0.0, 1.0), 50.0, 5),   # grazing: levels 0..4
    ((-0.015, 0.015, 0.02), (-0.015, 0.015, 0.0), (0.0, 1.0, 0.0), 20.0, 1),    # a corner, magnified
])
def test_a_frame_decodes_only_the_tiles_its_taps_read(asset, eye, target, up, fov, levels):
    """A frame that samples part of the atlas makes only the tiles (8 x 8 texels here) its taps
    read -- the count a whole-texture render's own taps give -- in one pass over the pages
    (each pack read once), and its pixels are the whole texture's, bit for bit."""
    points, faces, uv = plane_with_uv(0.05, 4)
    mesh = Mesh(points, faces, uv=uv)
    camera = Camera(np.array(eye), np.array(target), np.array(up), fov, 48, 32)
    lights = [Light("directional", np.array([0.3, 0.2, 1.0]) / np.linalg.norm([0.3, 0.2, 1.0]),
                    capture_irradiance(1.0))]
    opts = RenderOptions(threads=2, chunk=256, shadows=False)
    lazy = Renderer(load_btf(asset, lazy=True), opts)
    lazy.texture.tile = 8
    image = lazy.render(mesh, camera, lights)
    whole, tiles = _taps_of_the_whole_texture(Renderer(load_btf(asset), opts), mesh, camera, lights, 8)
    assert (image[..., 3] > 0).sum() > 700 and np.array_equal(image, whole)
    assert lazy.texture.tiles_made == tiles and len(tiles) == levels
    assert tiles[0] <= 8                                           # of level 0's 36 tiles
    assert 0 not in lazy.texture.levels                           # no level held whole
    codes = lazy.cbtf.coefficients.codes
    assert len(codes.reads) == len(set(codes.reads)) == pack_count(24)   # one pass over the pages


def test_pages_read_in_bands_are_the_whole_read_and_a_truncated_page_is_one_error(asset, tmp_path):
    """read_rgba reads a scanline page in bands (no second whole-page buffer in OIIO's PNG
    reader): the same pixels as OIIO's whole-image read, and a truncated page still fails as one
    BTFError naming the file."""
    import OpenImageIO as oiio

    from usdbtf.errors import BTFError
    from usdbtf.imageio import read_rgba

    page = sorted((asset.parent / "pebbles_textures" / "gpu").glob("page*.png"))[0]
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    inp = oiio.ImageInput.open(str(page), config)
    whole = inp.read_image(0, 0, 0, 4, inp.spec().format)
    inp.close()
    bands = read_rgba(page)
    assert bands.dtype == whole.dtype and bands.shape == whole.shape and np.array_equal(bands, whole)
    cut = tmp_path / "cut.png"
    cut.write_bytes(page.read_bytes()[: page.stat().st_size // 2])
    with pytest.raises(BTFError, match="cut.png: GPU texture is corrupt or truncated"):
        read_rgba(cut)


def test_a_later_frame_holds_what_a_fresh_renderer_would_and_renders_the_same(asset):
    """Frames of one renderer (``--frames``): each makes only the tiles it lacks and drops the
    ones it no longer reads, so it holds what a fresh renderer of that frame holds, and its
    pixels are that renderer's."""
    points, faces, uv = plane_with_uv(0.05, 4)
    mesh = Mesh(points, faces, uv=uv)
    lights = [Light("directional", np.array([0.3, 0.2, 1.0]) / np.linalg.norm([0.3, 0.2, 1.0]),
                    capture_irradiance(1.0))]
    grazing = Camera(np.array([-0.03, -0.03, 0.012]), np.array([-0.005, -0.005, 0.0]), np.array([0.0, 0.0, 1.0]),
                     50.0, 48, 32)
    corner = Camera(np.array([-0.015, 0.015, 0.02]), np.array([-0.015, 0.015, 0.0]), np.array([0.0, 1.0, 0.0]),
                    20.0, 48, 32)
    opts = RenderOptions(threads=2, chunk=256, shadows=False)

    def renderer():
        r = Renderer(load_btf(asset, lazy=True), opts)
        r.texture.tile = 8
        return r

    def held(r):
        return {n: np.flatnonzero(t.slot >= 0).tolist() for n, t in sorted(r.texture._held.items())}

    frames = renderer()
    for camera in (grazing, corner, _far_plane()[1], grazing):
        image = frames.render(mesh, camera, lights)
        fresh = renderer()
        assert np.array_equal(image, fresh.render(mesh, camera, lights)) and held(frames) == held(fresh)
    # Made over the four frames: level 0's 8 + 4 + 0 + 8 again (the corner's went with the far frame).
    assert frames.texture.tiles_made[0] == 20
