"""``usdbtf render``: the reference renderer.

Swatch = ``usdbtf decompress`` at measured directions (files through OIIO, 1e-4 relative);
hemisphere interpolation exact against brute force and continuous across triangle edges;
the rasteriser; a flat plane seen from far above reproduces the swatch pixel for pixel
(texture orientation, tangent frame and azimuth conventions end to end); cast shadows; the
CLI on an unwrapped, atlas-quilted sphere; bad input.
"""
from __future__ import annotations

import json

import numpy as np
import OpenImageIO as oiio
import pytest

from cli_helpers import bad_input, bad_usage, ok
from quilt_render_data import pebbles, work  # noqa: F401 (fixtures)
from quilt_render_data import PHYSICAL_SIZE, plane_with_uv, write_sphere
from usdbtf import color
from usdbtf.camera import Camera, parse_camera
from usdbtf.color import resolve_space
from usdbtf.compress import read_compressed
from usdbtf.imageio import read_image, read_info
from usdbtf.mesh import Mesh
from usdbtf.photometry import capture_irradiance
from usdbtf.raster import rasterize
from usdbtf.render import Light, RenderOptions, Renderer
from usdbtf.render.hemisphere import Triangulation, directions_to_vectors, project
from usdbtf.sampling import preset


@pytest.fixture(scope="module")
def renderer(pebbles):
    return Renderer(read_compressed(pebbles), RenderOptions(threads=2, chunk=4096))


# ------------------------------------------------------------------ swatch == decompress


def test_swatch_at_measured_directions_equals_decompress(work, pebbles, capsys):
    cbtf = read_compressed(pebbles)
    samples = [0, 40, 100, 168]
    ok(capsys, "decompress", pebbles, "-o", work / "recon", "--samples", ",".join(map(str, samples)), "-q")
    # Read decompress's float files directly (a reconstruction may dip slightly below zero,
    # which the BTF reader rejects as input), converted to the working space through OCIO.
    manifest = json.loads((work / "recon" / "btf.json").read_text())
    to_working = color.processor(manifest["color_space"], "scene_linear")
    for n, s in enumerate(samples):
        view, light = cbtf.sampling.view[s], cbtf.sampling.light[s]
        out = work / f"swatch{s}.exr"
        ok(capsys, "render", pebbles, "--swatch", "--view", f"{view[0]},{view[1]}", "--light",
           f"{light[0]},{light[1]}", "-o", out, "-q")
        got, info = read_image(out)
        assert resolve_space(info.color_space) == "ACEScg" and got.dtype == np.float32 and got.shape == (48, 48, 3)
        pixels, file_info = read_image(work / "recon" / manifest["samples"][n]["image"])
        assert file_info.bit_depth == "float"
        want = to_working.apply(pixels)                            # working space (ACEScg)
        assert np.abs(want).max() > 0.01
        # The manifest writer clamps float values below 0 in the file's space (Rec.709): compare
        # the swatch through the same clamp (a curve's reconstruction is >= 0 in ACEScg, whose
        # wider gamut can still hold colours with a negative Rec.709 channel).
        got = to_working.apply(np.maximum(color.processor("scene_linear", manifest["color_space"]).apply(got), 0))
        np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-4 * np.abs(want).max())
        png, png_info = read_image(out.with_suffix(".png"))
        # OIIO reads the PNG's sRGB chunk back as the sRGB encoding (same curve as the display).
        assert png.dtype == np.uint8 and resolve_space(png_info.color_space) in ("sRGB - Display",
                                                                                 "sRGB Encoded Rec.709 (sRGB)")


# ------------------------------------------------------------------ hemisphere interpolation


def _brute_force(tri: Triangulation, vectors):
    """Weights by testing every triangle, else projecting onto every boundary edge."""
    q = project(vectors)
    out = np.zeros((len(q), len(tri.directions)))
    p = tri.points
    for n, x in enumerate(q):
        for a, b, c in tri.triangles:
            m = np.array([p[b] - p[a], p[c] - p[a]]).T
            u, v = np.linalg.solve(m, x - p[a])
            if min(u, v, 1 - u - v) >= -1e-9:
                out[n, [a, b, c]] = np.clip([1 - u - v, u, v], 0, None)
                out[n] /= out[n].sum()
                break
        else:
            best = None
            for a, b in tri.boundary:
                t = np.clip(np.dot(x - p[a], p[b] - p[a]) / np.dot(p[b] - p[a], p[b] - p[a]), 0, 1)
                d = np.linalg.norm(x - (p[a] + t * (p[b] - p[a])))
                if best is None or d < best[0]:
                    best = (d, a, b, t)
            out[n, best[1]] += 1 - best[3]
            out[n, best[2]] += best[3]
    return out


def _dense(tri, idx, w):
    out = np.zeros((len(idx), len(tri.directions)))
    np.add.at(out, (np.arange(len(idx))[:, None], idx), w)
    return out


@pytest.mark.parametrize("name", ["small", "paper"])
def test_weights_are_exact_barycentrics(name):
    sampling = preset(name)
    views = np.unique(sampling.view, axis=0)
    tri = Triangulation.from_directions(views)
    rng = np.random.default_rng(0)
    theta = np.degrees(np.arccos(rng.uniform(-0.2, 1, 300)))          # includes below-horizon queries
    vec = directions_to_vectors(np.stack([theta.clip(0, 180), rng.uniform(0, 360, 300)], axis=1))
    idx, w, _ = tri.weights(vec)
    np.testing.assert_allclose(_dense(tri, idx, w), _brute_force(tri, vec), atol=1e-9)
    # Measured directions reproduce themselves exactly.
    idx, w, _ = tri.weights(directions_to_vectors(views))
    np.testing.assert_allclose(_dense(tri, idx, w), np.eye(len(views)), atol=1e-12)
    # The triangles tile the hull: their areas add up to the convex hull's.
    import cv2
    pts = tri.points[tri.triangles]
    e1, e2 = pts[:, 1] - pts[:, 0], pts[:, 2] - pts[:, 0]
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum()
    hull = cv2.contourArea(cv2.convexHull(tri.points.astype(np.float32)))
    assert area == pytest.approx(hull, rel=1e-5)


def test_interpolation_is_continuous_across_triangle_edges():
    lights = np.unique(preset("paper").light, axis=0)
    tri = Triangulation.from_directions(lights)
    values = np.random.default_rng(1).random(len(lights))
    crossed = set()
    for phi in (7.0, 100.0, 233.0):                        # rays from the pole out past the last ring
        theta = np.linspace(0.0, 89.0, 40001)
        idx, w, _ = tri.weights(directions_to_vectors(np.stack([theta, np.full_like(theta, phi)], axis=1)))
        f = (w * values[idx]).sum(axis=1)
        crossed |= {tuple(sorted(t)) for t in idx[w.min(axis=1) > 1e-3]}
        step = np.abs(np.diff(f))
        assert step.max() < 2e-3, step.max()              # ~1e-4 per step; a jump would be O(0.1)
    for theta in (20.0, 50.0, 80.0):                       # circles around the pole
        phi = np.linspace(0.0, 360.0, 40001)
        idx, w, _ = tri.weights(directions_to_vectors(np.stack([np.full_like(phi, theta), phi], axis=1)))
        f = (w * values[idx]).sum(axis=1)
        assert np.abs(np.diff(f)).max() < 2e-3
        assert abs(f[0] - f[-1]) < 1e-9
    assert len(crossed) > 20                               # the paths really crossed many triangles
    # Straddling an edge: points a hair apart on either side get the same blend.
    a, b, c = tri.triangles[len(tri.triangles) // 2]
    mid = (tri.points[a] + tri.points[b]) / 2
    normal = np.array([-(tri.points[b] - tri.points[a])[1], (tri.points[b] - tri.points[a])[0]])
    normal /= np.linalg.norm(normal)
    pair = np.stack([mid + 1e-7 * normal, mid - 1e-7 * normal])
    r, ang = np.hypot(*pair.T) * 90.0, np.degrees(np.arctan2(pair[:, 1], pair[:, 0]))
    idx, w, _ = tri.weights(directions_to_vectors(np.stack([r, ang], axis=1)))
    assert set(idx[0]) != set(idx[1])                      # two different triangles ...
    np.testing.assert_allclose(_dense(tri, idx, w)[0], _dense(tri, idx, w)[1], atol=1e-5)   # ... same blend


def test_swatch_is_continuous_between_samples(renderer):
    """Rendered images, not just weights: a light moving across the edge between two light
    triangles changes the image by O(step)."""
    tri = renderer.interp.lights
    a, b, _ = tri.triangles[3]
    mid = (tri.directions[a] + tri.directions[b]) / 2
    images = [renderer.swatch((20.0, 40.0), (mid[0] + d, mid[1] + d)) for d in (-1e-4, 0.0, 1e-4)]
    scale = np.abs(images[1]).max()
    assert np.abs(images[0] - images[1]).max() < 1e-4 * scale
    assert np.abs(images[2] - images[1]).max() < 1e-4 * scale


# ------------------------------------------------------------------ rasteriser


def test_rasteriser_coverage_and_depth():
    square = np.array([[[10.2, 10.2], [30.7, 10.2], [30.7, 30.7]], [[10.2, 10.2], [30.7, 30.7], [10.2, 30.7]]])
    r = rasterize(square, None, 40, 40)
    covered = r.tri >= 0
    assert covered.sum() == 21 * 21                              # centres 10.5 .. 30.5
    assert covered[10:31, 10:31].all()
    # A nearer triangle over part of it wins; the farther one keeps the rest.
    over = np.array([[[0.0, 0.0], [40.0, 0.0], [0.0, 40.0]]])                 # covers x + y <= 40
    r = rasterize(np.concatenate([square, over]), np.array([[1.0] * 3, [1.0] * 3, [0.5] * 3]), 40, 40, depth=True)
    assert (r.tri[10:19, 10:19] == 2).all() and r.depth[12, 12] == pytest.approx(0.5)
    assert r.tri[30, 30] in (0, 1) and r.depth[30, 30] == pytest.approx(1.0)


# ------------------------------------------------------------------ full renders


def _plane(size_m, n=4):
    points, faces, uv = plane_with_uv(size_m, n)
    return Mesh(points, faces, uv=uv, normals=np.tile([0.0, 0.0, 1.0], (len(points), 1)))


@pytest.mark.parametrize("light", [(45.0, 0.0), (60.0, 300.0)])
def test_flat_plane_from_far_above_reproduces_the_swatch(renderer, light):
    """The sample's own plane (x = image right, y = image up, 1 pixel per texel) seen straight
    down from 50 m under a distant light at a measured direction is the swatch."""
    half = PHYSICAL_SIZE / 2
    cam = Camera(np.array([0, 0, 50.0]), np.zeros(3), np.array([0, 1.0, 0]), np.degrees(2 * np.arctan(half / 50)),
                 48, 48)
    # The capture light (irradiance pi W, usdbtf.photometry) reproduces the measured values.
    sun = Light("directional", directions_to_vectors([light])[0], capture_irradiance())
    image = renderer.render(_plane(PHYSICAL_SIZE), cam, [sun])
    assert (image[..., 3] == 1).all()
    swatch = renderer.swatch((0.0, 0.0), light)
    scale = np.abs(swatch).mean()
    assert np.abs(image[..., :3] - swatch).mean() < 2e-3 * scale
    # The comparison has teeth: the light mirrored across the image axes gives another image.
    mirrored = renderer.swatch((0.0, 0.0), (light[0], light[1] + 180.0))
    assert np.abs(mirrored - swatch).mean() > 0.05 * scale


def test_minified_texture_is_mip_filtered(renderer):
    """Four texels per pixel: the mip filter averages them (the swatch box-filtered 4 x 4, in
    the working domain: mip levels average coefficients, like a GPU's texture filter);
    plain bilinear would pick single texels instead."""
    half = PHYSICAL_SIZE / 2
    cam = Camera(np.array([0, 0, 50.0]), np.zeros(3), np.array([0, 1.0, 0]), np.degrees(2 * np.arctan(half / 50)),
                 12, 12)
    sun = Light("directional", directions_to_vectors([(45.0, 0.0)])[0], capture_irradiance())
    dom = renderer.cbtf.domain
    swatch = dom.forward(renderer.swatch((0.0, 0.0), (45.0, 0.0)))
    want = dom.inverse(swatch.reshape(12, 4, 12, 4, 3).mean(axis=(1, 3)))
    mip = renderer.render(_plane(PHYSICAL_SIZE), cam, [sun])[..., :3]
    assert np.abs(mip - want).mean() < 5e-3 * np.abs(want).mean()
    plain = Renderer(renderer.cbtf, RenderOptions(filter="bilinear")).render(_plane(PHYSICAL_SIZE), cam, [sun])
    assert np.abs(plain[..., :3] - want).mean() > 5 * np.abs(mip - want).mean()


def test_cast_shadows(renderer):
    ground = _plane(0.2, n=8)
    points, faces, uv = plane_with_uv(0.04, 2, z=0.05)                # a floating square occluder
    roof = Mesh(points, faces, uv=uv, normals=np.tile([0.0, 0.0, 1.0], (len(points), 1)))
    mesh = Mesh.concatenate([ground, roof])
    cam = parse_camera(f"eye=0,0,1 target=0,0,0 fov={np.degrees(2 * np.arctan(0.1)):.6f}", 100, 100)
    sun = Light("directional", np.array([1.0, 0.0, 1.0]) / np.sqrt(2), 1.0)
    lit = Renderer(renderer.cbtf, RenderOptions(shadows=False)).render(mesh, cam, [sun])[..., :3].mean(axis=2)
    shaded = renderer.render(mesh, cam, [sun])[..., :3].mean(axis=2)
    # 2 mm per pixel, x to the right: the shadow falls at x in [-0.07, -0.03], y in [-0.02, 0.02].
    cols = lambda x0, x1: slice(int((x0 + 0.1) / 0.002) + 2, int((x1 + 0.1) / 0.002) - 2)
    rows = slice(int((0.1 - 0.02) / 0.002) + 2, int((0.1 + 0.02) / 0.002) - 2)
    in_shadow = (shaded[rows, cols(-0.07, -0.03)].mean(), lit[rows, cols(-0.07, -0.03)].mean())
    beside = (shaded[rows, cols(0.03, 0.07)].mean(), lit[rows, cols(0.03, 0.07)].mean())
    assert in_shadow[0] < 0.05 * in_shadow[1]
    assert beside[0] == pytest.approx(beside[1], rel=1e-6)


@pytest.fixture(scope="module")
def sphere_quilt(work, pebbles):
    """An icosphere (r = 3 cm) unwrapped and atlas-quilted from the pebbles sample, through the CLI."""
    from quilt_render_data import cli

    sphere = write_sphere(work / "sphere.obj", radius=0.03, subdivisions=3)
    cli("unwrap", sphere, "-o", work / "sphere_uv", "--btf", pebbles, "-q")
    cli("quilt", pebbles, "--atlas", work / "sphere_uv" / "mesh.usda", "-o", work / "sphere_q", "--block", 12, "-q")
    return work / "sphere_q", work / "sphere_uv" / "mesh.usda"


SPHERE_VIEW = ("--size", 96, 80, "--camera", "eye=0,0,0.2 target=0,0,0 fov=24", "--light", "point:0.2,0,0.2:0.08")


def test_render_cli_on_an_atlas_quilted_sphere(work, sphere_quilt, capsys):
    quilted, layer = sphere_quilt
    out = work / "sphere.exr"
    ok(capsys, "render", quilted, "--mesh", layer, *SPHERE_VIEW, "--light", "dir:0,1,0.2:0.2", "-o", out, "-q")
    info = read_info(out)
    assert (info.width, info.height, info.channels, resolve_space(info.color_space)) == (96, 80, 4, "ACEScg")
    png, _ = read_image(out.with_suffix(".png"))
    assert png.shape[:2] == (80, 96)
    rgba = oiio.ImageBuf(str(out)).get_pixels(oiio.FLOAT)
    # The sphere (r = 3 cm at 20 cm, fov 24 deg) covers a disc of about 22 px radius.
    radius_px = 0.03 / np.sqrt(0.2 ** 2 - 0.03 ** 2) * 40 / np.tan(np.radians(12))
    assert rgba[..., 3].sum() == pytest.approx(np.pi * radius_px ** 2, rel=0.08)
    lum = rgba[..., :3].mean(axis=2)
    right, left = lum[30:50, 56:68].mean(), lum[30:50, 28:40].mean()
    assert right > 1.5 * left                                             # the point light is on the right


def test_render_a_packaged_usd_asset_like_its_folder(work, sphere_quilt, capsys):
    """ASSET may be the USD asset `usdbtf package` makes (BTF and mesh read back from it)."""
    quilted, layer = sphere_quilt
    ok(capsys, "package", quilted, "--mesh", layer, "-o", work / "asset" / "sphere.usda", "-q")
    ok(capsys, "render", work / "asset" / "sphere.usda", *SPHERE_VIEW, "-o", work / "from_asset.exr", "--no-png",
       "-q")
    ok(capsys, "render", quilted, "--mesh", layer, *SPHERE_VIEW, "-o", work / "from_folder.exr", "--no-png", "-q")
    a = oiio.ImageBuf(str(work / "from_asset.exr")).get_pixels(oiio.FLOAT)
    b = oiio.ImageBuf(str(work / "from_folder.exr")).get_pixels(oiio.FLOAT)
    assert b[..., 3].sum() > 1000
    np.testing.assert_allclose(a, b, atol=1e-5 * np.abs(b).max())


# ------------------------------------------------------------------ bad input


def test_render_bad_input(work, pebbles, capsys):
    out = work / "bad.exr"
    bad_usage(capsys, "render", pebbles, "--swatch", "--light", "30,0", "-o", out, names="--view")
    bad_usage(capsys, "render", pebbles, "--swatch", "--view", "95,0", "--light", "30,0", "-o", out, names="--view")
    bad_usage(capsys, "render", pebbles, "--swatch", "--view", "0,0", "--light", "x", "-o", out, names="--light")
    bad_usage(capsys, "render", pebbles, "--swatch", "--view", "0,0", "--light", "30,0", "-o", work / "bad.png",
              names="bad.png")
    sphere = write_sphere(work / "plain.obj", subdivisions=1)
    bad_input(capsys, "render", pebbles, "--mesh", sphere, "--light", "point:1,1,1", "-o", out,
              names="no texture coordinates")
    bad_usage(capsys, "render", pebbles, "--mesh", sphere, "--light", "spot:1,1,1", "-o", out, names="spot:1,1,1")
    bad_usage(capsys, "render", pebbles, "--mesh", sphere, "--camera", "eye=0,0,1", "--light", "dir:0,0,1", "-o", out,
              names="--camera")
    bad_input(capsys, "render", work / "nowhere", "--swatch", "--view", "0,0", "--light", "30,0", "-o", out,
              names="nowhere")
    assert not out.exists() and not (work / "bad.png").exists()
    assert not [p for p in work.iterdir() if p.name.startswith(".bad")]


def test_chunk_size_follows_k_and_changes_no_pixel(renderer):
    """Pixels per shading task shrink as k grows (a task's (pixels, 3, k) taps stay near
    CHUNK_BYTES: the 256² thumbnail at k 242 peaked 0.33 GB above rate control's memory with
    16,384 pixels a task), and the frame is the same bits at any chunk size."""
    from usdbtf.render.core import CHUNK_BYTES, chunk_pixels

    assert chunk_pixels(8) == 16384 and chunk_pixels(100_000) == 1024
    assert 5 * 4 * 242 * chunk_pixels(242) <= CHUNK_BYTES < 5 * 4 * 242 * (chunk_pixels(242) + 1)
    half = PHYSICAL_SIZE / 2
    cam = Camera(np.array([0.03, -0.04, 0.05]), np.zeros(3), np.array([0, 0, 1.0]), 2 * np.degrees(np.arctan(half / 0.06)),
                 64, 48)
    sun = Light("directional", directions_to_vectors([(35.0, 60.0)])[0], capture_irradiance())
    frames = [Renderer(renderer.cbtf, RenderOptions(threads=2, chunk=chunk)).render(_plane(PHYSICAL_SIZE), cam, [sun])
              for chunk in (None, 100, 16384)]
    assert (frames[0][..., 3] > 0).sum() > 1000             # the plane fills much of the frame
    assert np.array_equal(frames[0], frames[1]) and np.array_equal(frames[0], frames[2])
