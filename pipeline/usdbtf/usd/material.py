"""BtfMaterialAPI <-> :class:`~usdbtf.compress.format.CompressedBTF`.

:func:`author_btf` writes a compressed BTF's description onto a UsdShade.Material
(the textures themselves are files the caller has placed); :func:`read_btf` builds
the same CompressedBTF back from a composed prim, from any stage that references the
asset, so ``reconstruct(read_btf(prim))`` equals ``reconstruct(read_compressed(folder))``
bit for bit.

Two layouts of the textures (``btf:coefficientLayout``, schema version 2): ``gpuPages``, what
``package`` writes for a BTF the real-time preview draws (every light at every view): the one
copy of the BTF is the GPU tables (``btf:basis``, whose basis block holds the stored basis
codes; schema version 4: its de-quantisation, the codes being in the 8-bit basis page listed
last in ``btf:coefficients``) and the RGBA coefficient pages (``btf:coefficients``; a ``lod``
lists the pages its vectors need, a prefix, then its own basis page), which the Storm shader, the MaterialX node, the OSL shader and the CPU
readers all read (:func:`usdbtf.gpu.tables.unpack`); ``files``, one image per coefficient and a
basis image (other samplings, and every asset of schema version 1, which keeps reading).
"""
from __future__ import annotations

import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .. import __version__, photometry
from ..color import usd_color_space
from ..compress.codecs import Codec, Stored
from ..compress.format import CompressedBTF, basis_layout, cross_layout, image_to_basis
from ..errors import BTFError
from ..sampling import Sampling
from .plugin import API_SCHEMA, require_schema

SCHEMA_VERSION = 4
#: Versions :func:`read_btf` reads (1: the ``files`` layout only, before btf:coefficientLayout;
#: 3: the GPU tables' integer basis codes plus 2^23, usdbtf.compress.packs.BASIS_CODE_OFFSET;
#: 4: integer basis codes in an 8-bit basis page, listed last in btf:coefficients, which the
#: tables say: usdbtf.gpu.tables.BASIS_IN_PAGE).
READABLE_VERSIONS = (1, 2, 3, 4)
#: btf:coefficientLayout values.
FILES, GPU_PAGES = "files", "gpuPages"
#: btf:basisLayout of the GPU tables.
GPU_TABLES = "gpuTables"
NS = "btf:"
SCHEMA_VERSION_ATTR = NS + "schemaVersion"
#: Variant set on a packaged asset's root prim choosing how many basis vectors to use.
LOD_VARIANT_SET = "lod"


def _attr(prim, name: str):
    return prim.GetAttribute(NS + name)


def _set(prim, name: str, value) -> None:
    """Author a schema attribute (its type comes from the schema definition)."""
    attr = _attr(prim, name)
    if not attr:
        raise BTFError(f"{prim.GetPath()}: {NS + name} is not a {API_SCHEMA} attribute")
    attr.Set(value)


def author_btf(material, cbtf: CompressedBTF, basis: str, coefficients: list[str], *,
               physical_size: tuple[float, float] | None = None, error_curve: list | None = None,
               provenance_source: str | None = None, layout: str = FILES) -> None:
    """Apply BtfMaterialAPI to ``material`` (a Material prim) and author ``cbtf``'s description.

    basis, coefficients : asset paths (relative to the layer being edited) of the
        basis image and the k coefficient textures, energy order; with ``layout``
        :data:`GPU_PAGES`, of the GPU tables and the coefficient pages (module docstring).
    physical_size : (width, height) of the tile in metres.
    error_curve : [(k, percent), ...] measured reconstruction errors.
    provenance_source : what ``btf:provenance:source`` records (default: the path the
        compressed BTF recorded; packaging passes one relative to the asset).

    Every ``btf:`` attribute that holds numbers or textures is declared ``raw`` (data: codes,
    de-quantisation, directions), overriding the working space the Material declares for
    what the BTF reconstructs (``Usd.ColorSpaceAPI``, ``btf:colorSpace``).
    """
    from pxr import Gf, Sdf, Usd, Vt

    require_schema()
    if not material.ApplyAPI(API_SCHEMA):
        raise BTFError(f"{material.GetPath()}: cannot apply {API_SCHEMA} (only Material prims can hold a BTF)")
    k = cbtf.k
    if layout not in (FILES, GPU_PAGES):
        raise ValueError(f"coefficient layout {layout!r}")
    if layout == FILES and len(coefficients) != k:
        raise ValueError(f"{len(coefficients)} coefficient paths for k = {k}")
    _set(material, "schemaVersion", SCHEMA_VERSION)
    _set(material, "basis", Sdf.AssetPath(basis))
    _set(material, "coefficientLayout", layout)
    if layout == GPU_PAGES:
        _set(material, "basisLayout", GPU_TABLES)
    else:
        tiles = basis_layout(cbtf.sampling, k, cbtf.codec)
        _set(material, "basisLayout", tiles["kind"])
        if tiles["kind"] == "tiles":
            _set(material, "basisTile", Gf.Vec2i(tiles["views"], tiles["lights"]))
            _set(material, "basisGrid", Gf.Vec2i(*tiles["grid"]))
    _set(material, "basisScale", Vt.DoubleArray([float(x) for x in cbtf.basis.scale]))
    _set(material, "basisBias", Vt.DoubleArray([float(x) for x in cbtf.basis.bias]))
    _set(material, "basisCount", k)
    _set(material, "coefficients", Sdf.AssetPathArray([Sdf.AssetPath(p) for p in coefficients]))
    _set(material, "coefficientScale", Vt.Vec3dArray([Gf.Vec3d(*map(float, c.scale)) for c in cbtf.coefficients]))
    _set(material, "coefficientBias", Vt.Vec3dArray([Gf.Vec3d(*map(float, c.bias)) for c in cbtf.coefficients]))
    sv = cbtf.info.get("singular_values")
    if sv:
        _set(material, "singularValues", Vt.DoubleArray([float(x) for x in sv[:k]]))
    _set(material, "colorMatrix", Gf.Matrix3d(*[float(x) for x in np.asarray(cbtf.color_matrix).ravel()]))
    if not cbtf.domain.is_linear:                   # linear is the schema's fallback: older assets read the same
        _set(material, "domain:curve", cbtf.domain.curve)
        if cbtf.domain.curve == "power":
            _set(material, "domain:gamma", float(cbtf.domain.gamma))
    _set(material, "resolution", Gf.Vec2i(cbtf.width, cbtf.height))
    views, lights = cbtf.sampling.view, cbtf.sampling.light
    cross = cross_layout(cbtf.sampling)
    if cross is not None:          # V + L entries, not 2 V L (345,600 bytes of doubles at paper scale)
        V, L = cross
        views, lights = views[::L], lights[:L]
        _set(material, "directionLayout", "cross")
    _set(material, "viewDirections", Vt.Vec2dArray([Gf.Vec2d(*map(float, v)) for v in views]))
    _set(material, "lightDirections", Vt.Vec2dArray([Gf.Vec2d(*map(float, v)) for v in lights]))
    if cbtf.interpolated is not None and cbtf.interpolated.any():
        _set(material, "interpolatedSamples", Vt.IntArray([int(i) for i in np.flatnonzero(cbtf.interpolated)]))
    # usdbtf.photometry: what the values mean, and the white level they are relative to.
    _set(material, "photometry", photometry.CONVENTION)
    _set(material, "whiteLevel", photometry.white_level_of(cbtf.info, f"{material.GetPath()}: white_level"))
    _set(material, "colorSpace", cbtf.working_space)
    _set(material, "ocioConfig", cbtf.ocio_config or "ocio://default")
    if cbtf.source.get("color_space"):
        _set(material, "source:colorSpace", str(cbtf.source["color_space"]))
    if cbtf.source.get("bit_depth"):
        _set(material, "source:bitDepth", str(cbtf.source["bit_depth"]))
    if physical_size:
        _set(material, "physicalSize", Gf.Vec2f(*map(float, physical_size)))
    _author_coverage(material, cbtf)
    if error_curve:
        _set(material, "errorCurve:k", Vt.IntArray([int(kk) for kk, _ in error_curve]))
        _set(material, "errorCurve:percent", Vt.FloatArray([float(p) for _, p in error_curve]))
    prov = cbtf.info.get("provenance", {})
    if provenance_source is None:
        provenance_source = str(prov.get("source", cbtf.source.get("path", "")))
    _set(material, "provenance:source", provenance_source)
    if cbtf.info.get("solver") in ("rsvd", "paper"):
        _set(material, "provenance:solver", cbtf.info["solver"])
    _set(material, "provenance:codec", cbtf.codec)
    _set(material, "provenance:version", __version__)
    # The reconstructed values' colour space, for USD (inherited by everything below).
    usd_space = usd_color_space(cbtf.working_space, cbtf.ocio_config)
    if usd_space:
        Usd.ColorSpaceAPI.Apply(material).CreateColorSpaceNameAttr(usd_space)
    mark_data_attributes(material)


def _author_coverage(material, cbtf: CompressedBTF) -> None:
    """``btf:coverage:*`` from a partial compress's record (nothing for a whole one)."""
    from pxr import Gf, Vt

    from ..compress.coverage import read_coverage_record

    record = read_coverage_record(cbtf.info, str(material.GetPath()))
    if record is None:
        return
    for key, name in _COVERAGE_DIRECTIONS.items():
        if record.get(key):
            _set(material, "coverage:" + name, Vt.Vec2dArray([Gf.Vec2d(*map(float, d)) for d in record[key]]))
    for key, name in _COVERAGE_COUNTS.items():
        _set(material, "coverage:" + name, int(record[key]))
    if record.get("input_size"):
        _set(material, "coverage:inputResolution", Gf.Vec2i(*map(int, record["input_size"])))


#: Coverage record keys (:func:`usdbtf.compress.coverage.coverage_record`) -> btf:coverage: attribute names.
_COVERAGE_DIRECTIONS = {"views": "views", "lights": "lights", "input_view_directions": "inputViewDirections",
                        "input_light_directions": "inputLightDirections"}
_COVERAGE_COUNTS = {"input_views": "inputViews", "input_lights": "inputLights", "input_samples": "inputSamples",
                    "resolution_factor": "resolutionFactor"}


def read_coverage(material) -> dict | None:
    """The coverage record (the keys of :func:`usdbtf.compress.coverage.coverage_record`) a
    partial asset's ``btf:coverage:*`` attributes hold; None for an asset that covers its
    whole input (``btf:coverage:views`` unauthored)."""
    views = _get(material, "coverage:views", required=False)
    if views is None:
        return None
    record = {}
    for key, name in _COVERAGE_DIRECTIONS.items():
        value = _get(material, "coverage:" + name, required=False)
        record[key] = np.asarray(value, np.float64).reshape(-1, 2).tolist() if value is not None else None
    record["lights"] = record["lights"] or []
    for key, name in _COVERAGE_COUNTS.items():
        record[key] = int(_get(material, "coverage:" + name, required=False) or 0)
    size = _get(material, "coverage:inputResolution", required=False)
    record["input_size"] = [int(x) for x in size] if size is not None else None
    return record


_TEXT_TYPES = ("string", "token")


def mark_data_attributes(material) -> None:
    """Declare every authored ``btf:`` attribute holding numbers or assets ``raw``."""
    for attr in material.GetAuthoredAttributes():
        if attr.GetName().startswith(NS) and str(attr.GetTypeName()).rstrip("[]") not in _TEXT_TYPES:
            attr.SetColorSpace("raw")


# -- reading ---------------------------------------------------------------
def btf_materials(stage) -> list:
    """Every prim on ``stage`` with BtfMaterialAPI applied, in traversal order."""
    require_schema()
    return [p for p in stage.Traverse() if p.HasAPI(API_SCHEMA)]


def _get(prim, name: str, required: bool = True):
    attr = _attr(prim, name)
    value = attr.Get() if attr else None
    if value is None and required:
        raise BTFError(f"{prim.GetPath()}: {NS + name} is not authored")
    return value


def _authored(prim, name: str):
    """The authored (composed) value of a schema attribute, None where only the fallback applies."""
    attr = _attr(prim, name)
    return attr.Get() if attr and attr.HasAuthoredValue() else None


def _read_asset(prim, asset, what: str, reader=None) -> np.ndarray:
    """Stored pixels of an asset-valued attribute, read through Ar (so usdz members work);
    ``reader(path)`` reads a file (default ``Codec.read``)."""
    where = f"{prim.GetStage().GetRootLayer().identifier}: {prim.GetPath()}.{NS}{what}"
    return _read_resolved(where, asset, reader)


def _read_resolved(where: str, asset, reader=None) -> np.ndarray:
    """:func:`_read_asset` of an asset path already resolved (it needs no prim, no stage)."""
    from pxr import Ar

    reader = reader or Codec.read
    resolved = asset.resolvedPath
    if not resolved:
        raise BTFError(f"{where}: texture {asset.path!r} does not resolve (missing file?)")
    if "[" not in resolved and Path(resolved).is_file():
        return reader(Path(resolved))
    # A file inside a package (pkg.usdz[textures/c000.png]): OIIO reads files, so
    # copy the member's bytes out through Ar first.
    handle = Ar.GetResolver().OpenAsset(Ar.ResolvedPath(resolved))
    if handle is None:
        raise BTFError(f"{where}: cannot open texture {asset.path!r} ({resolved})")
    suffix = Path(resolved.rstrip("]").split("[")[-1]).suffix
    with tempfile.TemporaryDirectory(prefix="usdbtf-asset-") as tmp:
        path = Path(tmp) / f"texture{suffix}"
        path.write_bytes(bytes(handle.GetBuffer()))
        return reader(path)


def read_btf(material, *, k: int | None = None, lazy: bool = False) -> CompressedBTF:
    """The CompressedBTF described by a BtfMaterialAPI prim (composed values: a LOD
    variant's btf:basisCount applies).  ``k`` keeps fewer basis vectors still.

    ``lazy`` (the one-copy ``gpuPages`` layout only): the coefficients are a sequence whose
    item ``i`` (a Stored) is read from its pages when asked for, and not kept
    (:class:`usdbtf.gpu.tables.LazyCodes`; a reader walking them in order decodes each page
    once); for a reader that needs one at a time (the renderer building a mip level), not
    for one that indexes them repeatedly."""
    require_schema()
    path = material.GetPath()
    if not material.HasAPI(API_SCHEMA):
        raise BTFError(f"{path}: has no {API_SCHEMA}")
    version = _get(material, "schemaVersion")
    if version not in READABLE_VERSIONS:
        raise BTFError(f"{path}: {SCHEMA_VERSION_ATTR} = {version}, this usdbtf ({__version__}) reads versions "
                       f"{', '.join(map(str, READABLE_VERSIONS))}")
    coeff_assets = list(_get(material, "coefficients"))
    scales = np.asarray(_get(material, "coefficientScale"), np.float64).reshape(-1, 3)
    biases = np.asarray(_get(material, "coefficientBias"), np.float64).reshape(-1, 3)
    bscale = np.asarray(_get(material, "basisScale"), np.float64)
    bbias = np.asarray(_get(material, "basisBias"), np.float64)
    gpu = version >= 2 and str(_get(material, "coefficientLayout", required=False) or FILES) == GPU_PAGES
    # The pages list the files a level needs, not one per vector: the scales count the vectors.
    listed = len(scales) if gpu else len(coeff_assets)
    count = int(_get(material, "basisCount") or listed)
    k = min(count, listed) if k is None else k
    if not 1 <= k <= min(listed, len(scales), len(biases), len(bscale), len(bbias)):
        raise BTFError(f"{path}: basis count {k} does not match {listed} coefficient textures, "
                       f"{len(scales)} scales, {len(bscale)} basis scales")
    view, light = read_directions(material)
    if len(view) != len(light) or not len(view):
        raise BTFError(f"{path}: {len(view)} view and {len(light)} light directions")
    sampling = Sampling(view, light)
    width, height = (int(x) for x in _get(material, "resolution"))
    if gpu:
        basis, coefficients = _read_gpu_copy(material, coeff_assets, k, len(sampling), (height, width), lazy)
        basis = Stored(basis, bscale[:k], bbias[:k])
        coefficients = (_LazyStored(coefficients, scales, biases) if lazy else
                        [Stored(px, scales[i], biases[i]) for i, px in enumerate(coefficients)])
    else:
        basis, coefficients = _read_files(material, coeff_assets, k, sampling, (height, width), bscale, bbias,
                                          scales, biases)
    return _compressed(material, path, sampling, width, height, basis, coefficients, k)


class _LazyPages:
    """A sequence of ``n`` pages, page i read by ``read(i)`` when first asked for."""

    def __init__(self, read, n: int):
        self._read, self._n, self._cache = read, n, {}

    def __len__(self) -> int:
        return self._n

    def __getitem__(self, i: int):
        if i not in self._cache:
            self._cache = {}                         # one page at a time: pages are atlas-sized
            self._cache = {i: self._read(i)}
        return self._cache[i]

    def release(self) -> None:
        self._cache = {}


class _LazyStored(Sequence):
    """k coefficient Stored, item i read from its pages when asked for (read_btf's ``lazy``)."""

    def __init__(self, codes, scales: np.ndarray, biases: np.ndarray):
        self.codes, self._scales, self._biases = codes, scales, biases

    def __len__(self) -> int:
        return len(self.codes)

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(len(self)))]
        return Stored(self.codes[i], self._scales[i], self._biases[i])

    def release(self) -> None:
        """Drop the pages and packs read so far (the next item reads them again)."""
        self.codes.release()


def read_directions(material) -> tuple[np.ndarray, np.ndarray]:
    """(view, light) (S, 2) degrees per basis row of a BtfMaterialAPI prim: the arrays as
    authored, or the view-major cross product of btf:directionLayout 'cross'."""
    view = np.asarray(_get(material, "viewDirections"), np.float64).reshape(-1, 2)
    light = np.asarray(_get(material, "lightDirections"), np.float64).reshape(-1, 2)
    if str(_get(material, "directionLayout", required=False) or "perSample") == "cross":
        view, light = np.repeat(view, len(light), axis=0), np.tile(light, (len(view), 1))
    return view, light


def _read_gpu_copy(material, pages: list, k: int, samples: int, shape: tuple, lazy: bool = False) -> tuple:
    """(basis codes (S, k, 1), k coefficient codes (H, W, 3)) from the GPU tables and pages
    (``lazy``: the codes a :class:`usdbtf.gpu.tables.LazyCodes`, no page read yet)."""
    from ..gpu.tables import basis_in_page, unpack, unpack_lazy
    from ..imageio import read_rgba

    path = material.GetPath()
    tables = _read_asset(material, _get(material, "basis"), "basis", read_rgba)
    basis_page = None
    if basis_in_page(tables):           # schema 4: the basis page is listed last
        if not pages:
            raise BTFError(f"{path}: the GPU tables keep the basis codes in a basis page; {NS}coefficients lists none")
        basis_page = _read_asset(material, pages[-1], "coefficients", read_rgba)
        pages = pages[:-1]
    # Only the pages the first k vectors are on are read (unpack asks for them in order).
    # The stage may be gone when a lazy reader asks for a page: hold only the resolved paths.
    where = f"{material.GetStage().GetRootLayer().identifier}: {path}.{NS}coefficients"
    read = _LazyPages(lambda i: _read_resolved(f"{where}[{i}]", pages[i], read_rgba), len(pages))
    try:
        basis, coefficients = (unpack_lazy if lazy else unpack)(tables, read, k, basis_page)
    except BTFError as exc:
        raise BTFError(f"{path}: {exc}") from None
    if basis.shape[0] != samples:
        raise BTFError(f"{path}: the GPU tables hold {basis.shape[0]} basis rows for {samples} directions")
    held = coefficients.shape if lazy else coefficients[0].shape[:2]
    if held != shape:
        raise BTFError(f"{path}: GPU pages hold {held[1]}x{held[0]} texels, "
                       f"btf:resolution says {shape[1]}x{shape[0]}")
    return basis, coefficients


def _read_files(material, coeff_assets, k, sampling, shape, bscale, bbias, scales, biases) -> tuple:
    """(basis Stored, k coefficient Stored) of the ``files`` layout: a basis image, one file
    per coefficient."""
    path = material.GetPath()
    height, width = shape
    kind = str(_get(material, "basisLayout"))
    if kind == "tiles":
        views, lights = (int(x) for x in _get(material, "basisTile"))
        layout = {"kind": "tiles", "views": views, "lights": lights,
                  "grid": [int(x) for x in _get(material, "basisGrid")]}
        if views * lights != len(sampling):
            raise BTFError(f"{path}: basis tiles of {views} x {lights} do not hold {len(sampling)} samples")
    else:
        layout = {"kind": "columns"}
    image = _read_asset(material, _get(material, "basis"), "basis")[:, :, :1]
    rows, cols = ((layout["grid"][0] * layout["views"], layout["grid"][1] * layout["lights"])
                  if kind == "tiles" else (len(sampling), None))
    if image.shape[0] != rows or (cols is not None and image.shape[1] != cols) or \
            (cols is None and image.shape[1] < k):
        raise BTFError(f"{path}: basis image is {image.shape[1]}x{image.shape[0]}, which does not fit "
                       f"{len(sampling)} samples x {k} vectors ({kind} layout)")
    basis = Stored(image_to_basis(image, layout, k), bscale[:k], bbias[:k])
    coefficients = []
    for i in range(k):
        px = _read_asset(material, coeff_assets[i], f"coefficients[{i}]")
        if px.shape[:2] != (height, width):
            raise BTFError(f"{path}: coefficient texture {coeff_assets[i].path} is {px.shape[1]}x{px.shape[0]}, "
                           f"btf:resolution says {width}x{height}")
        coefficients.append(Stored(px, scales[i], biases[i]))
    return basis, coefficients


def _compressed(material, path, sampling, width, height, basis, coefficients, k) -> CompressedBTF:
    """The CompressedBTF of ``material`` around its read textures."""
    interp = np.zeros(len(sampling), bool)
    flagged = _get(material, "interpolatedSamples", required=False)
    if flagged:
        interp[np.asarray(flagged, int)] = True
    info = {"provenance": {"source": _get(material, "provenance:source", required=False),
                           "solver": _get(material, "provenance:solver", required=False),
                           "version": _get(material, "provenance:version", required=False)},
            "material": str(path)}
    sv = _get(material, "singularValues", required=False)
    if sv:
        info["singular_values"] = [float(x) for x in sv][:k]
    coverage = read_coverage(material)
    if coverage is not None:
        info["coverage"] = coverage
    # Unauthored btf:photometry: an asset from before the convention (legacy), values relative to W = 1.
    photometry.check_photometry(_authored(material, "photometry"), str(path))
    white = _authored(material, "whiteLevel")
    info["source_metadata"] = {"white_level": photometry.check_white_level(
        photometry.DEFAULT_WHITE_LEVEL if white is None else white, f"{path}: {NS}whiteLevel")}
    matrix = np.asarray(_get(material, "colorMatrix"), np.float64).reshape(3, 3)
    source = {"color_space": _get(material, "source:colorSpace", required=False),
              "bit_depth": _get(material, "source:bitDepth", required=False)}
    return CompressedBTF(sampling, width, height, basis, coefficients, matrix,
                         str(_get(material, "provenance:codec", required=False) or "png"),
                         str(_get(material, "colorSpace")), {key: v for key, v in source.items() if v}, interp,
                         _get(material, "ocioConfig", required=False), info, domain=_domain(material, path))


def _domain(material, path):
    """The working-domain curve of ``material`` (unauthored: linear), checked like a folder's."""
    from ..compress.domain import domain_from_metadata

    curve = _get(material, "domain:curve", required=False)
    if curve is None or str(curve) == "linear":
        return domain_from_metadata(None, str(path))
    entry = {"curve": str(curve)}
    if entry["curve"] == "power":
        entry["gamma"] = _get(material, "domain:gamma", required=False)
    return domain_from_metadata(entry, f"{path} btf:domain")
