"""The asset's PNGs choose their filter (issue 39): the smaller encoding, the same pixels; a map
named ".jpg" is a JPEG, read back as what a reader decodes."""
import os

import usdbtf  # noqa: F401  (before numpy)
import numpy as np

from usdbtf.imageio import PNG_FILTERS, decode_image, encode_image, encode_png_smallest


def _each_filter(pixels, space):
    return [encode_image(pixels, "png", color_space=space,
                         attributes={"png:compressionLevel": 9, **({"png:filter": f} if f else {})})
            for f in PNG_FILTERS]


def test_the_smaller_filter_wins_and_the_pixels_are_the_same():
    rng = np.random.default_rng(0)
    # Noise about a mid-grey (like a noisy material's fitted maps): libpng's adaptive default
    # filters every row (least absolute sum), but the differences of noise cost more than it.
    noise = np.clip(rng.normal(128.0, 8.0, (32, 32, 3)), 0, 255).astype(np.uint8)
    ramp = np.stack(np.meshgrid(np.arange(32), np.arange(32)), -1).astype(np.uint16) * 2000   # filtered is smaller
    ramp = np.concatenate([ramp, ramp[..., :1]], -1)
    for pixels, winner in ((noise, 1), (ramp, 0)):
        encoded = _each_filter(pixels, "data")
        assert len(encoded[winner]) < len(encoded[1 - winner])        # the case is the one it claims
        best = encode_png_smallest(pixels, color_space="data", level=9)
        assert best == encoded[winner]
        assert np.array_equal(decode_image(best), pixels)


def test_fallback_maps_are_written_with_the_smaller_filter():
    from usdbtf.svbrdf import SvbrdfMaps
    from usdbtf.usd.asset import fallback
    from usdbtf.usd.asset.textures import DATA, TextureSet, png_as_data

    rng = np.random.default_rng(1)
    n = rng.normal(0.0, 0.3, (16, 16, 3)).astype(np.float32)
    n[..., 2] = 1.0
    grey = np.clip(rng.normal(0.2, 0.01, (16, 16, 3)), 0, 1).astype(np.float32)     # noise about a grey
    maps = SvbrdfMaps(grey, grey * 0.2,
                      np.full((16, 16), 0.4, np.float32), n / np.linalg.norm(n, axis=-1, keepdims=True), "ACEScg")
    textures = TextureSet()
    names = fallback.add_maps(maps, textures)
    pixels = fallback.encode_maps(maps)
    chose_none = 0
    for name, (_, kind) in fallback.MAP_FILES.items():
        colour = kind == "srgb"
        encoded = _each_filter(pixels[name], fallback.COLOUR_ENCODING if colour else DATA)
        expected = min(encoded, key=len)
        chose_none += len(expected) < len(encoded[0])
        written = textures.files[names[name]].data
        assert written == (expected if colour else png_as_data(expected)), name
        assert (decode_image(written) == pixels[name]).all()      # (a grey file reads back as RGB)
    assert chose_none            # the maps exercise the choice (libpng's default alone is larger)


def test_a_jpeg_map_is_read_back_as_its_decoded_pixels():
    """``MAP_FILES`` names choose the encoding (issue 39): a ".jpg" map is a 4:4:4 JPEG and
    ``shipped_pixels`` (what the fit's error as shipped is measured on) returns what a reader
    decodes from it -- close to, not equal to, the pixels -- while PNG maps come back unchanged."""

    from usdbtf.imageio import memory_file, read_info
    from usdbtf.usd.asset import fallback

    rng = np.random.default_rng(2)
    smooth = np.linspace(40, 200, 32)[None, :, None] + rng.normal(0.0, 6.0, (32, 32, 3))
    colour = np.clip(smooth, 0, 255).astype(np.uint8)
    grey = colour[..., :1].copy()
    files = {"diffuse": ("diffuse.jpg", "srgb"), "roughness": ("roughness.png", "unorm")}
    blob = fallback.encode_map_file(colour, *files["diffuse"])
    assert blob[:3] == b"\xff\xd8\xff"
    shipped = fallback.shipped_pixels({"diffuse": colour, "roughness": grey}, files)
    assert np.array_equal(shipped["diffuse"], decode_image(blob))
    diff = np.abs(shipped["diffuse"].astype(int) - colour.astype(int))
    assert 0 < diff.mean() < 3 and diff.max() < 32            # lossy, at high quality
    assert shipped["roughness"] is grey                          # lossless files: the pixels themselves
    with memory_file() as (fd, path):
        os.write(fd, blob)
        assert read_info(path).color_space == "srgb_rec709_scene"   # the colour encoding is declared


def _laplacian_codes(rng, shape, scale):
    """Noise-like integer codes about mid-range: a late coefficient's plane."""
    return np.clip(np.rint(rng.laplace(128.0, scale, shape)), 0, 255).astype(np.uint8)


def test_run_length_png_reads_back_exactly_for_every_layout_and_filter(monkeypatch):
    """``encode_png_rle`` (the asset's pages, issue 39) is a PNG any reader decodes to the same
    codes: gray, gray-alpha, RGB, RGBA (alpha unassociated: not premultiplied), 1/2/4-bit gray,
    every row filter, and images filtered in several row blocks (atlas pages)."""
    import OpenImageIO as oiio

    import usdbtf.imageio as imageio
    from usdbtf.imageio import encode_png_rle

    rng = np.random.default_rng(3)
    cases = [(_laplacian_codes(rng, (19, 23, c), 6.0), 8) for c in (1, 2, 3, 4)]
    cases.append((_laplacian_codes(rng, (19, 23), 20.0), 8))
    cases += [(rng.integers(0, 2**b, (19, 23)).astype(np.uint8), b) for b in (1, 2, 4)]
    cases[3][0][0, 0] = (7, 200, 13, 0)              # zero alpha beside colour: must not be cleared
    monkeypatch.setattr(imageio, "_PNG_ROWS_BYTES", 50)     # 1-2 rows per block: the "up" row crosses blocks
    for pixels, bits in cases:
        for row_filter in ("adaptive", 0, 1, 2, 3, 4):
            data = encode_png_rle(pixels, row_filter=row_filter, bit_depth=bits)
            with imageio.memory_file() as (fd, path):
                os.write(fd, data)
                spec = oiio.ImageSpec()
                spec.attribute("oiio:UnassociatedAlpha", 1)
                image = oiio.ImageInput.open(str(path), spec)
                back = image.read_image("uint8")
                image.close()
            if bits < 8:
                back = back // (255 // (2**bits - 1))          # readers scale low bit depths to 8 bits
            assert np.array_equal(back.reshape(pixels.shape), pixels), (pixels.shape, bits, row_filter)

