"""The photometric convention (usdbtf.photometry) on a white Lambertian BTF whose source records
a white level W = 0.8: every path returns radiance = value x irradiance / (pi W), i.e. what a
white Lambertian UsdPreviewSurface returns (E (n.l) / pi); the packaged asset says so
(btf:photometry, btf:whiteLevel, the Storm shader's whiteLevel) and reads it back; an asset
from before the convention reads as legacy with W = 1; a token from the future is refused."""
from __future__ import annotations

import math

import numpy as np
import pytest

import usdbtf  # noqa: F401  (registers the schema plugin first)
from pxr import Usd

from usdbtf import photometry
from usdbtf.compress import CompressOptions, compress
from usdbtf.errors import BTFError
from usdbtf.model import ArrayBTF
from usdbtf.render import RenderOptions, Renderer
from usdbtf.sampling import preset, to_vectors

WHITE = 0.8
ALBEDO = 0.5


@pytest.fixture(scope="module")
def lambertian():
    """A flat grey Lambertian (albedo 0.5) recorded with white level 0.8: value = 0.8 x 0.5 x cos."""
    sampling = preset("small")
    cos_l = np.clip(to_vectors(sampling.light)[:, 2], 0, 1).astype(np.float32)
    data = np.broadcast_to((WHITE * ALBEDO * cos_l)[:, None, None, None], (len(cos_l), 8, 8, 3)).copy()
    btf = ArrayBTF.from_linear(sampling, data)
    btf.metadata.update(physical_size_m=[0.01, 0.01], white_level=WHITE)
    opts = CompressOptions(k=2, codec="exr")
    opts.extra = {"source_metadata": dict(btf.metadata)}
    return compress(btf, opts), cos_l, sampling


def test_constants():
    assert photometry.capture_irradiance(WHITE) == pytest.approx(math.pi * WHITE)
    assert photometry.radiance_per_irradiance(WHITE) * photometry.capture_irradiance(WHITE) == pytest.approx(1.0)
    assert photometry.white_level_of({}) == 1.0
    with pytest.raises(BTFError, match="positive"):
        photometry.check_white_level(0.0)
    assert photometry.check_photometry(None, "x") == photometry.LEGACY
    with pytest.raises(BTFError, match="btf:photometry 'photons'"):
        photometry.check_photometry("photons", "x")


def test_cpu_renderer_returns_physical_radiance(lambertian):
    """Under irradiance E the CPU renderer returns albedo x E (n.l) / pi, what a Lambertian
    UsdPreviewSurface of that diffuseColor returns -- not the value x E of the old convention."""
    cbtf, cos_l, sampling = lambertian
    renderer = Renderer(cbtf, RenderOptions(filter="bilinear"))
    s = int(np.argmax(cos_l < 0.9))                  # an oblique measured light
    view, light = tuple(sampling.view[s]), tuple(sampling.light[s])
    for irradiance in (1.0, 2.5):
        got = renderer.swatch(view, light, irradiance)
        want = ALBEDO * irradiance * cos_l[s] / math.pi
        np.testing.assert_allclose(got, want, rtol=2e-3)
    # The default (the capture light, pi W) reproduces the measured value.
    np.testing.assert_allclose(renderer.swatch(view, light), WHITE * ALBEDO * cos_l[s], rtol=2e-3)


def test_package_records_the_convention(lambertian, tmp_path):
    """The asset authors btf:photometry and btf:whiteLevel and the Storm shader's whiteLevel;
    read back, the CPU renderer on the asset follows W; without the attributes (an old asset)
    the values read relative to W = 1; an unknown token is refused."""
    from usdbtf.usd.asset import package as pkg
    from usdbtf.usd.asset.inspect import describe
    from usdbtf.usd.material import btf_materials
    from usdbtf.usd.read import load_btf
    from usdbtf.usd.asset.storm import storm_shader

    cbtf, cos_l, sampling = lambertian
    asset = tmp_path / "a" / "white.usda"
    pkg.write_package(pkg.package(cbtf, pkg.PackageOptions(thumbnail=False)), asset)
    stage = Usd.Stage.Open(str(asset))
    material = btf_materials(stage)[0]
    assert material.GetAttribute("btf:photometry").Get() == photometry.CONVENTION
    assert material.GetAttribute("btf:whiteLevel").Get() == pytest.approx(WHITE)
    assert storm_shader(material).GetInput("whiteLevel").Get() == pytest.approx(WHITE)
    assert "photometry   reflectance: radiance = value x irradiance / (pi x 0.8)" in describe(asset)
    back = load_btf(asset)
    assert photometry.white_level_of(back.info) == pytest.approx(WHITE)
    s = int(np.argmax(cos_l < 0.9))
    view, light = tuple(sampling.view[s]), tuple(sampling.light[s])
    np.testing.assert_allclose(Renderer(back).swatch(view, light, 1.0), ALBEDO * cos_l[s] / math.pi, rtol=2e-3)

    # An asset from before the convention: no opinion on either attribute.
    for name in ("btf:photometry", "btf:whiteLevel"):
        for spec in material.GetAttribute(name).GetPropertyStack():
            layer = spec.layer
            layer.GetPrimAtPath(spec.path.GetPrimPath()).RemoveProperty(spec)
            layer.Save()
    old = Usd.Stage.Open(str(asset))
    assert btf_materials(old)[0].GetAttribute("btf:photometry").Get() == photometry.LEGACY    # the fallback
    assert photometry.white_level_of(load_btf(asset).info) == 1.0
    assert "photometry   legacy: radiance = value x irradiance / (pi x 1) (written before" in describe(asset)
    btf_materials(old)[0].GetAttribute("btf:photometry").Set("photons")
    old.GetRootLayer().Save()
    with pytest.raises(BTFError, match="btf:photometry 'photons'"):
        load_btf(asset)
