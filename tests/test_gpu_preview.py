"""Issue 7: the real-time BTF preview (Storm glslfx, MaterialX node) checked without Storm.

* The plugin's shaders are generated from the one GLSL core and compile with glslang
  (Storm's glslfx with Storm's names declared, MaterialX's generated GLSL, the harness).
* The MaterialX definitions and the packaged document validate with the materialx package.
* A packaged asset carries the Storm shader next to the preview fallback and still passes
  every UsdValidation validator (usda, payload, usdz); LOD variants trim the textures.
* The shared GLSL, run on Mesa llvmpipe through EGL on the packaged textures, matches the
  CPU reference renderer (usdbtf.render) on a swatch and on a sphere: PSNR >= 40 dB.
"""
from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest

import usdbtf  # noqa: F401  (registers the schema plugin first)
from pxr import Sdr, UsdShade

from usdbtf.cli import main
from usdbtf.errors import BTFError
from usdbtf.gpu import glslang, shaders
from usdbtf.gpu.tables import gpu_layout, pack_count
from usdbtf.usd.asset import storm
from usdbtf.usd.read import load_btf, open_stage
from usdbtf.usd.asset.validate import validation_issues

PSNR_MIN = 40.0
needs_glslang = pytest.mark.skipif(glslang.glslang_path() is None,
                                   reason="glslangValidator not found and not installable here: "
                                          "scripts/bootstrap.sh installs glslang-tools when run as root")


@pytest.fixture(scope="module")
def egl():
    pytest.importorskip("moderngl", reason="moderngl not installed (pip install -e '.[test]')")
    from usdbtf.gpu.headless import create_context

    try:
        ctx = create_context()
    except BTFError as exc:
        pytest.skip(f"no headless OpenGL here: {exc}")
    yield ctx
    ctx.release()


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("gpu")


@pytest.fixture(scope="module")
def src(work, synth_capture) -> Path:
    return synth_capture("pebbles", "small", 32, out=work / "src")


def _package(src: Path, work: Path, codec: str, domain: str = "auto", full: bool = True) -> Path:
    """Compress ``src`` at k 12 and package it; ``full``: also the .usdz and the thumbnail
    (tests that only draw the asset's GPU textures skip both: their time, none of their checks)."""
    name = codec if domain == "auto" else f"{codec}_{domain.replace(':', '')}"
    compressed = work / f"c_{name}"
    assert main(["compress", str(src), "-o", str(compressed), "--k", "12", "--codec", codec, "--domain", domain,
                 "-q"]) == 0
    out = work / f"asset_{name}" / "pebbles.usda"
    assert main(["package", str(compressed), "-o", str(out), "-q"] + (["--usdz"] if full else ["--no-thumbnail"])) == 0
    return out


@pytest.fixture(scope="module")
def asset(src, work) -> Path:
    return _package(src, work, "png")


@pytest.fixture(scope="module")
def gl(egl, asset):
    from usdbtf.gpu.headless import HeadlessRenderer

    layout, wrap, _ = storm.layout_from_asset(asset)
    return HeadlessRenderer(layout, wrap=wrap, ctx=egl)


# ------------------------------------------------------------------ one source, generated files
def test_plugin_shaders_are_current_and_assembled_from_the_core():
    assert shaders.stale_plugin_files() == [], "run: python -m usdbtf.gpu.shaders"
    core = shaders.core_source()
    for text in (shaders.storm_glslfx(), shaders.materialx_impl(), shaders.harness_fragment()):
        assert core in text                          # the same text, not a hand-made copy
    assert (shaders.GLSL_DIR / "btf_core.glsl").read_text() in core


# ------------------------------------------------------------------ glslang
@needs_glslang
@pytest.mark.parametrize("textures, primvars, lights", [
    (["tables"] + [shaders.page_name(p) for p in range(15)], True, 2),   # every page connected
    (["tables", "page00"], False, 1),                                      # a small LOD, derivative frame
    ([], True, 0),                                                         # nothing bound, no lights
])
def test_storm_glslfx_compiles(textures, primvars, lights):
    text = (storm.plugin_dir_resources() / "shaders" / f"{shaders.SHADER_ID}.glslfx").read_text()
    glslang.compile_glsl(glslang.storm_translation_unit(text, textures=textures, primvars=primvars, lights=lights),
                         "frag", "UsdBtfSurface")


@needs_glslang
def test_glslang_rejects_a_broken_shader():
    """The control: the same check fails for a wrong call."""
    text = shaders.storm_glslfx().replace("btfPack(btfTables, BTF_PAGE_ARGS, p, st)", "btfPack(btfTables, p, st)")
    with pytest.raises(BTFError, match="does not compile"):
        glslang.compile_glsl(glslang.storm_translation_unit(text, textures=["tables"]), "frag", "broken")


@needs_glslang
def test_harness_shaders_compile():
    glslang.compile_glsl(shaders.HARNESS_VERTEX, "vert", "harness")
    glslang.compile_glsl(shaders.harness_fragment(), "frag", "harness")


# ------------------------------------------------------------------ MaterialX
def test_materialx_definitions_and_packaged_document_validate(asset, tmp_path):
    mtlx = pytest.importorskip("usdbtf.gpu.materialx", reason="materialx not installed")
    pytest.importorskip("MaterialX", reason="materialx not installed (pip install -e '.[test]')")
    mtlx.validate(mtlx.materialx_dir() / "usdbtf_defs.mtlx")
    doc = asset.parent / "pebbles_textures" / storm.GPU_DIR / storm.MTLX_FILE
    mtlx.validate(doc)
    text = doc.read_text()
    assert 'name="basisCount" type="integer" value="12"' in text and "page01.png" in text
    # The lower lod's own document: its tables and its one page (issue 39).
    low = doc.with_name(storm.lod_mtlx_name(6))
    mtlx.validate(low)
    assert 'name="basisCount" type="integer" value="6"' in low.read_text()
    assert 'value="tables_k6.exr"' in low.read_text() and "page01" not in low.read_text()
    bad = tmp_path / "bad.mtlx"                     # the control: a wrong input type is caught
    bad.write_text(text.replace('type="integer" value="12"', 'type="float" value="12.5"'))
    with pytest.raises(BTFError, match="invalid MaterialX"):
        mtlx.validate(bad)


@needs_glslang
def test_materialx_generated_glsl_compiles(asset):
    mtlx = pytest.importorskip("usdbtf.gpu.materialx")
    pytest.importorskip("MaterialX", reason="materialx not installed (pip install -e '.[test]')")
    vertex, pixel = mtlx.generate_glsl(asset.parent / "pebbles_textures" / storm.GPU_DIR / storm.MTLX_FILE)
    assert "mx_usdbtf_bsdf(closureData" in pixel and shaders.core_source().splitlines()[5] in pixel
    glslang.compile_glsl(vertex, "vert", "materialx")
    glslang.compile_glsl(pixel, "frag", "materialx")


# ------------------------------------------------------------------ the packaged asset
def test_asset_has_storm_shader_beside_the_fallback_and_passes_every_validator(asset):
    for layer in (asset, asset.with_name("pebbles_payload.usdc"), asset.with_suffix(".usdz")):
        assert validation_issues(layer, severities=("Error", "Warn")) == [], layer
    stage = open_stage(asset)
    material = UsdShade.Material(stage.GetPrimAtPath("/pebbles/mtl/BtfMaterial"))
    universal = material.GetSurfaceOutput().GetConnectedSources()[0][0].source.GetPrim()
    assert UsdShade.Shader(universal).GetIdAttr().Get() == "UsdPreviewSurface"
    shader = storm.storm_shader(material.GetPrim())
    assert shader.GetIdAttr().Get() == shaders.SHADER_ID
    assert material.ComputeSurfaceSource("glslfx")[0].GetPath() == shader.GetPath()
    assert material.ComputeSurfaceSource("ri")[0].GetPrim() == universal   # others get the fallback
    node = Sdr.Registry().GetShaderNodeByIdentifier(shaders.SHADER_ID)       # the plugin's definition,
    assert Path(node.GetResolvedDefinitionURI()) == \
        storm.plugin_dir_resources() / "sdr" / f"{shaders.SHADER_ID}.usda"     # found by filesystem discovery
    assert Path(node.GetResolvedImplementationURI()) == \
        storm.plugin_dir_resources() / "shaders" / f"{shaders.SHADER_ID}.glslfx"
    assert set(node.GetShaderInputNames()) == {name for name, *_ in shaders.INPUTS}
    with zipfile.ZipFile(asset.with_suffix(".usdz")) as z:
        names = z.namelist()
    assert not [n for n in names if n.endswith(".glslfx")]
    assert "pebbles_textures/gpu/tables.exr" in names and "pebbles_textures/gpu/page01.png" in names


def test_pages_hold_the_stored_codes_and_lods_load_only_their_pages(asset):
    import cv2

    cbtf = load_btf(asset)
    gpu = asset.parent / "pebbles_textures" / storm.GPU_DIR
    layout, _, _ = storm.layout_from_asset(asset)
    flat = layout.tables.reshape(-1, 4)
    directory = flat[int(flat[3, 0]):int(flat[3, 0]) + pack_count(cbtf.k)].astype(int)
    assert (int(flat[3, 1]), int(flat[3, 2])) == (cbtf.width, cbtf.height)
    pages = []
    for i in range(len(layout.pages)):
        png = gpu / f"{shaders.page_name(i)}.png"
        if png.is_file():                                  # 8-bit codes: read by an independent PNG decoder
            pages.append(cv2.imread(str(png), cv2.IMREAD_UNCHANGED)[:, :, [2, 1, 0, 3]])
        else:                                              # 16-bit codes: float32 EXR of code / 65535
            pages.append(np.rint(storm.read_rgba(gpu / f"{shaders.page_name(i)}.exr") * 65535.0))
    for p, (page, x0, y0, _) in enumerate(directory):
        g, c = divmod(p, 3)
        want = np.stack([cbtf.coefficients[4 * g + j].pixels[:, :, c] for j in range(4)], axis=-1)
        np.testing.assert_array_equal(pages[page][y0:y0 + cbtf.height, x0:x0 + cbtf.width], want)
    # k 12 with the level k6: a page ends at pack 6; each level loads only its pages.
    assert layout.first_packs == [0, 6]
    # Issue 39: each level's own tables, holding its k basis vectors and its packs' entries.
    for lod, k, n_pages in ((None, 12, 2), ("full", 12, 2), ("k6", 6, 1)):
        layout, _, got_k = storm.layout_from_asset(asset, lod=lod)
        assert (got_k, len(layout.pages)) == (k, n_pages)
        assert int(layout.tables.reshape(-1, 4)[1, 0]) == k and layout.first_packs == [0, 6][:n_pages]
    np.testing.assert_array_equal(layout.tables, storm.read_rgba(gpu / "tables_k6.exr"))
    np.testing.assert_array_equal(layout.tables, gpu_layout(cbtf, lods=[6]).lod_tables[6])


@pytest.mark.parametrize("k, size, lods", [(300, 32, (150, 75, 37)), (300, 1024, (150, 75, 37)), (300, 2048, ()),
                                           (64, 4096, (32, 16, 8))])
def test_every_k_fits_sixteen_samplers(k, size, lods):
    """Issue 25: at most 1 + MAX_PAGES samplers for any k the packager writes (compress
    allows k <= 300) at texture sizes up to 2048 (4096 at k = 64): the coefficient pages leave
    the last page slot to the basis page (schema 4); a level of detail's pages are its own; no
    two packs share a tile, no page exceeds PAGE_SIZE."""
    from usdbtf.gpu.tables import BASIS_PAGE, MAX_PAGES, PAGE_SIZE, page_breaks, page_plan

    plan, directory = page_plan(pack_count(k), size, size, page_breaks(k, lods))
    assert 1 + MAX_PAGES <= 16 and len(plan) <= BASIS_PAGE == MAX_PAGES - 1
    assert all(pack_count(n) in [first for first, *_ in plan] for n in lods)
    assert all(cols * size <= PAGE_SIZE and rows * size <= PAGE_SIZE and end - first <= cols * rows
               for first, end, cols, rows in plan)
    assert len({tuple(row[:3]) for row in directory}) == pack_count(k)
    assert all(int(row[0]) == i for i, (first, end, *_) in enumerate(plan) for row in directory[first:end])


def test_gpu_layout_refuses_a_sampling_without_every_light_at_every_view(asset):
    from dataclasses import replace

    cbtf = load_btf(asset)
    with pytest.raises(BTFError, match="every light at every view"):
        gpu_layout(replace(cbtf, sampling=cbtf.sampling.subset(slice(1, None))))


# ------------------------------------------------------------------ GPU == CPU
def _cpu(cbtf, wrap="clamp", k=None):
    from usdbtf.render import RenderOptions, Renderer

    return Renderer(cbtf, RenderOptions(k=k, shadows=False, filter="bilinear", wrap=wrap, threads=2))


SWATCH_CASES = [((0, 0), (30, 0)), ((30, 60), (45, 10)), ((55, 200), (80, 300)), ((12, 33), (20, 100)),
                ((75, 5), (60, 120))]


def test_headless_swatch_matches_cpu_renderer(gl, asset):
    from usdbtf.gpu.headless import psnr

    cpu = _cpu(load_btf(asset))
    values = []
    for view, light in SWATCH_CASES:
        ref = cpu.swatch(view, light)
        values.append(psnr(gl.swatch(view, light), ref))
    print("swatch PSNR (dB):", ", ".join(f"{v:.1f}" for v in values))
    assert min(values) >= PSNR_MIN
    # The control: a light off by 15 degrees of azimuth is told apart.
    assert psnr(gl.swatch((30, 60), (45, 25)), cpu.swatch((30, 60), (45, 10))) < PSNR_MIN


def test_schema3_tables_render_what_the_basis_page_renders(egl, gl, asset):
    """Issue 39 (schema 4): the shader reads the basis codes from the 8-bit basis page (page
    slot 14) where the tables say so, and from the tables as before where they hold them
    (schema 3: 2^23 + code): the same codes, so the same frame, value for value.  An old asset
    keeps rendering."""
    from basis_helpers import schema3_tables
    from usdbtf.gpu.headless import HeadlessRenderer
    from usdbtf.gpu.tables import BASIS_PAGE, GpuLayout, basis_in_page

    layout, wrap, _ = storm.layout_from_asset(asset)
    assert basis_in_page(layout.tables) and layout.slots()[BASIS_PAGE] is layout.basis_page
    old = GpuLayout(schema3_tables(layout.tables, load_btf(asset)), layout.pages, layout.k, layout.first_packs)
    assert not basis_in_page(old.tables) and old.slots()[BASIS_PAGE] is None
    gl3 = HeadlessRenderer(old, wrap=wrap, ctx=egl)
    try:
        _assert_same_swatches(gl, gl3)
    finally:
        gl3.release()


def _assert_same_swatches(gl, other) -> None:
    """Two headless renderers draw the same swatch frames, value for value (and not black)."""
    for view, light in SWATCH_CASES[:2]:
        frame, expected = gl.swatch(view, light), other.swatch(view, light)
        assert expected.max() > 0 and np.array_equal(frame, expected), (view, light)


def test_basis_page_in_two_columns_renders_what_the_tables_render(egl, asset, monkeypatch):
    """A basis page whose groups fill more than one column (paper sampling past k 364, ubo151
    past k 216): the column height lowered to two groups in the packer and the shader alike,
    k 12 (3 groups) goes in two columns; the codes read back exactly and the frame is the
    schema-3 tables' frame, value for value."""
    from basis_helpers import schema3_tables
    from usdbtf.compress import packs
    from usdbtf.compress.format import cross_layout
    from usdbtf.gpu import shaders
    from usdbtf.gpu.headless import HeadlessRenderer
    from usdbtf.gpu.tables import GpuLayout, gpu_layout, unpack

    cbtf = load_btf(asset)
    views, lights = cross_layout(cbtf.sampling)
    rows = 2 * 2 * views                                # two groups per column
    core = shaders.core_source()
    lowered = core.replace("16384 / (2 * views)", f"{rows} / (2 * views)")
    assert lowered != core
    monkeypatch.setattr(packs, "BASIS_PAGE_ROWS", rows)
    monkeypatch.setattr(shaders, "core_source", lambda: lowered)
    layout = gpu_layout(cbtf)
    assert layout.k == 12 and layout.basis_page.shape[:2] == (rows, 2 * lights)
    np.testing.assert_array_equal(unpack(layout.tables, list(layout.pages), basis_page=layout.basis_page)[0],
                                  cbtf.basis.pixels)
    _, wrap, _ = storm.layout_from_asset(asset)
    old = GpuLayout(schema3_tables(layout.tables, cbtf), layout.pages, layout.k, layout.first_packs)
    gl4, gl3 = HeadlessRenderer(layout, wrap=wrap, ctx=egl), HeadlessRenderer(old, wrap=wrap, ctx=egl)
    try:
        _assert_same_swatches(gl4, gl3)
    finally:
        gl4.release()
        gl3.release()


def test_headless_sphere_matches_cpu_renderer(egl, asset):
    from usdbtf.gpu.headless import HeadlessRenderer, psnr, uv_sphere
    from usdbtf.camera import auto_camera
    from usdbtf.render import parse_light

    layout, _, _ = storm.layout_from_asset(asset)
    gl = HeadlessRenderer(layout, wrap="repeat", ctx=egl)
    mesh = uv_sphere(0.05)
    camera = auto_camera(mesh.corner(), 128, 128)
    lights = [parse_light("dir:0.4,0.6,1"), parse_light("point:0.1,0.05,0.12:0.02")]
    ref = _cpu(load_btf(asset), wrap="repeat").render(mesh, camera, lights)
    out = gl.render(mesh, camera, lights)
    covered_cpu, covered_gl = ref[..., 3] > 0, out[..., 3] > 0
    both = covered_cpu & covered_gl
    assert both.sum() > 0.2 * both.size and both.sum() >= 0.99 * max(covered_cpu.sum(), covered_gl.sum())
    value = psnr(out[..., :3], ref[..., :3], both)
    print(f"sphere PSNR: {value:.1f} dB over {both.sum()} pixels")
    assert value >= PSNR_MIN
    dark = psnr(gl.render(mesh, camera, lights[:1])[..., :3], ref[..., :3], both)   # control: one light missing
    assert dark < PSNR_MIN


def test_lod_and_half_float_packs_match_cpu_renderer(egl, src, work):
    """An EXR-codec asset (half-float packs) at its k6 level of detail."""
    from usdbtf.gpu.headless import HeadlessRenderer, psnr

    exr = _package(src, work, "exr")
    assert (exr.parent / "pebbles_textures" / storm.GPU_DIR / "page00.exr").is_file()
    assert validation_issues(exr.with_suffix(".usdz")) == []
    layout, wrap, k = storm.layout_from_asset(exr, lod="k6")
    assert layout.pages[0].dtype == np.float16 and k == 6
    gl = HeadlessRenderer(layout, wrap=wrap, ctx=egl)
    cpu = _cpu(load_btf(exr, lod="k6"))
    value = psnr(gl.swatch((30, 60), (45, 10)), cpu.swatch((30, 60), (45, 10)))
    print(f"half-float k6 swatch PSNR: {value:.1f} dB")
    assert value >= PSNR_MIN


@pytest.mark.parametrize("domain", ["srgb", "linear", "gamma:3"])
def test_working_domain_curve_matches_cpu_renderer(egl, src, work, domain):
    """The shader's inverse curve (tables texel 2) equals the CPU renderer's, with two lights
    (each light's radiance after the curve) on a sphere."""
    from usdbtf.camera import auto_camera
    from usdbtf.gpu.headless import HeadlessRenderer, psnr, uv_sphere
    from usdbtf.render import parse_light

    asset = _package(src, work, "png", domain, full=False)
    cbtf = load_btf(asset)
    assert cbtf.domain.name == domain
    layout, _, _ = storm.layout_from_asset(asset)
    gl = HeadlessRenderer(layout, wrap="repeat", ctx=egl)
    value = psnr(gl.swatch((30, 60), (45, 10)), _cpu(cbtf).swatch((30, 60), (45, 10)))
    mesh = uv_sphere(0.05)
    camera = auto_camera(mesh.corner(), 96, 96)
    lights = [parse_light("dir:0.4,0.6,1"), parse_light("point:0.1,0.05,0.12:0.02")]
    ref = _cpu(cbtf, wrap="repeat").render(mesh, camera, lights)
    out = gl.render(mesh, camera, lights)
    both = (ref[..., 3] > 0) & (out[..., 3] > 0)
    sphere = psnr(out[..., :3], ref[..., :3], both)
    print(f"{domain}: swatch PSNR {value:.1f} dB, sphere {sphere:.1f} dB")
    assert value >= PSNR_MIN and sphere >= PSNR_MIN


def test_preview_command_reports_psnr(asset, tmp_path, capsys, egl):
    out = tmp_path / "p.exr"
    assert main(["preview", str(asset), "--swatch", "--view", "30,60", "--light", "45,10", "-o", str(out),
                 "--compare", "-q"]) == 0
    value = float(capsys.readouterr().out.split("PSNR vs CPU renderer:")[1].split("dB")[0])
    assert value >= PSNR_MIN and out.is_file() and out.with_suffix(".png").is_file()
