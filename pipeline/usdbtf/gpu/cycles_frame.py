"""Render usdbtf assets in Blender's Cycles through the usdbtf add-on (OSL): a script, not a module.

Run by the Python of the bpy 5.0.1 environment (``scripts/bootstrap.sh`` makes
``.venv-storm-5.0``), never imported by usdbtf::

    .venv-storm-5.0/bin/python pipeline/usdbtf/gpu/cycles_frame.py JOBS.json ADDON_FOLDER

JOBS.json: ``{"frames": [{"asset", "lod" (null: the asset's own), "output" (.exr), "size": [w, h],
"camera": {"kind": "pole"} | {"kind": "perspective", "eye", "target", "up", "fov"},
"sun": [x, y, z] (towards the light, the asset's USD space), "irradiance", "samples", "fallback",
"surface", "maps"}], "report": path}``.  ``"fallback": true`` imports the asset with Blender's USD importer
only (its UsdPreviewSurface fallback as a Principled BSDF, what Blender shows without the add-on);
``"surface"``: the add-on's surface shown ("BTF", the default: the OSL BTF; "PRINCIPLED": its
Principled BSDF of the fitted OpenPBR lobes).  ``"maps"`` ({map: OpenPBR map file}, the
``openpbr_*.png`` of an asset's fallback folder): no asset is read; a unit square in the xy
plane (normal +z, UV map ``st`` over it, as a swatch) carries the add-on's Principled BSDF of
those maps (``network.build_principled``), so that its conversions are checked on maps made
for the purpose.
Everything in USD space is converted to Blender's with the imported root's transform (the
importer's up-axis and unit conversion).  Frames of one asset and lod share one import.  A
"pole" camera looks orthographically down the swatch's normal (+z in USD), its extent filling
the frame.  The report (JSON) lists each frame's render seconds.  It uses only the standard
library, ``bpy`` and the add-on (``ADDON_FOLDER/usdbtf``, loaded as ``usdbtf_blender``).

Exit status: 0 written, 3 no bpy, 5 a frame failed.
"""
from __future__ import annotations

import importlib.util
import json
import math
import sys
import time
from pathlib import Path


def _addon(folder: Path):
    spec = importlib.util.spec_from_file_location("usdbtf_blender", folder / "usdbtf" / "__init__.py",
                                                  submodule_search_locations=[str(folder / "usdbtf")])
    module = importlib.util.module_from_spec(spec)
    sys.modules["usdbtf_blender"] = module
    spec.loader.exec_module(module)
    module.register()
    return module


def _setup_scene(bpy, threads: int = 2):
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.shading_system = True          # Open Shading Language
    scene.cycles.use_denoising = False
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.max_bounces = 0                # the BTF is emission: nothing bounces
    scene.cycles.filter_width = 0.01            # samples at pixel centres, as the CPU reference
    scene.render.film_transparent = True
    scene.render.threads_mode = "FIXED"
    scene.render.threads = threads
    scene.render.resolution_percentage = 100
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_depth = "32"
    scene.render.image_settings.color_mode = "RGBA"
    scene.view_settings.view_transform = "Standard"
    return scene


def _look(mathutils, obj, eye, forward, up):
    """Place ``obj`` (a camera or light: looks along its -Z, up +Y) at ``eye`` facing ``forward``."""
    f = forward.normalized()
    right = f.cross(up).normalized()
    true_up = right.cross(f)
    rotation = mathutils.Matrix((right, true_up, -f)).transposed()
    obj.matrix_world = mathutils.Matrix.Translation(eye) @ rotation.to_4x4()


def _camera(bpy, mathutils, spec: dict, to_world, meshes):
    data = bpy.data.cameras.new("usdbtf_camera")
    camera = bpy.data.objects.new("usdbtf_camera", data)
    bpy.context.scene.collection.objects.link(camera)
    bpy.context.scene.camera = camera
    rot = to_world.to_3x3()
    if spec["kind"] == "pole":
        # The meshes' extent in USD space (the swatch: z = 0, normal +z).
        inverse = to_world.inverted()
        corners = [inverse @ (o.matrix_world @ mathutils.Vector(c)) for o in meshes for c in o.bound_box]
        lo = mathutils.Vector([min(c[i] for c in corners) for i in range(3)])
        hi = mathutils.Vector([max(c[i] for c in corners) for i in range(3)])
        centre = (lo + hi) / 2
        data.type = "ORTHO"
        data.ortho_scale = max(hi.x - lo.x, hi.y - lo.y)
        data.clip_start, data.clip_end = 0.5, 2.0
        eye = to_world @ mathutils.Vector((centre.x, centre.y, hi.z + 1.0))
        _look(mathutils, camera, eye, rot @ mathutils.Vector((0, 0, -1)), rot @ mathutils.Vector((0, 1, 0)))
    else:
        eye, target, up = (mathutils.Vector(spec[k]) for k in ("eye", "target", "up"))
        data.type = "PERSP"
        data.sensor_fit = "VERTICAL"
        data.sensor_height = 24.0
        data.lens = 0.5 * data.sensor_height / math.tan(math.radians(spec["fov"]) / 2)
        data.clip_start, data.clip_end = 1e-3, 100.0
        _look(mathutils, camera, to_world @ eye, rot @ (target - eye), rot @ up)
    return camera


def _sun(bpy, mathutils, direction, irradiance, to_world):
    data = bpy.data.lights.new("usdbtf_sun", "SUN")
    data.energy = irradiance
    sun = bpy.data.objects.new("usdbtf_sun", data)
    bpy.context.scene.collection.objects.link(sun)
    towards = (to_world.to_3x3() @ mathutils.Vector(direction)).normalized()
    helper = mathutils.Vector((0, 0, 1)) if abs(towards.z) < 0.9 else mathutils.Vector((0, 1, 0))
    _look(mathutils, sun, mathutils.Vector((0, 0, 0)), -towards, helper)    # a sun shines along its -Z
    return sun


def _maps_plane(bpy, addon, maps: dict):
    """A unit square (UV map ``st``) whose material is the add-on's Principled BSDF of ``maps``."""
    corners = [(-0.5, -0.5, 0.0), (0.5, -0.5, 0.0), (0.5, 0.5, 0.0), (-0.5, 0.5, 0.0)]
    mesh = bpy.data.meshes.new("usdbtf_maps")
    mesh.from_pydata(corners, [], [(0, 1, 2, 3)])
    uv = mesh.uv_layers.new(name=addon.network.UV_MAP)
    for loop in mesh.loops:
        x, y, _ = corners[loop.vertex_index]
        uv.data[loop.index].uv = (x + 0.5, y + 0.5)
    plane = bpy.data.objects.new("usdbtf_maps", mesh)
    bpy.context.scene.collection.objects.link(plane)
    material = bpy.data.materials.new("usdbtf_maps")
    material.use_nodes = True
    tree = material.node_tree
    for node in list(tree.nodes):
        tree.nodes.remove(node)
    output = tree.nodes.new("ShaderNodeOutputMaterial")
    bsdf = addon.network.build_principled(material, maps)
    tree.links.new(bsdf.outputs["BSDF"], output.inputs["Surface"])
    mesh.materials.append(material)
    return [plane]


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    jobs = json.loads(Path(argv[0]).read_text())
    try:
        import bpy
        import mathutils
    except ImportError as exc:
        print(f"cycles_frame: no bpy here ({exc})", file=sys.stderr)
        return 3
    addon = _addon(Path(argv[1]))
    report, loaded = [], None
    for frame in jobs["frames"]:
        key = (frame["asset"], frame.get("lod"), bool(frame.get("fallback")), frame.get("surface", "BTF"),
               json.dumps(frame.get("maps"), sort_keys=True))
        if key != loaded:
            bpy.ops.wm.read_factory_settings(use_empty=True)
            scene = _setup_scene(bpy)
            start = time.perf_counter()
            if frame.get("maps"):
                objects, materials = _maps_plane(bpy, addon, frame["maps"]), []
            elif frame.get("fallback"):
                before = set(bpy.data.objects)
                if "FINISHED" not in bpy.ops.wm.usd_import(filepath=frame["asset"], import_usd_preview=True):
                    print(f"cycles_frame: {frame['asset']}: Blender's USD import failed", file=sys.stderr)
                    return 5
                objects, materials = [o for o in bpy.data.objects if o not in before], []
            else:
                objects, materials = addon.network.import_asset(frame["asset"], frame.get("lod"),
                                                                frame.get("surface", "BTF"))
            import_seconds = time.perf_counter() - start
            roots = [o for o in objects if o.parent is None]
            to_world = roots[0].matrix_world.copy() if roots else mathutils.Matrix.Identity(4)
            meshes = [o for o in objects if o.type == "MESH"]
            loaded = key
        for obj in [o for o in scene.objects if o.name.startswith(("usdbtf_camera", "usdbtf_sun"))]:
            bpy.data.objects.remove(obj)
        scene.render.resolution_x, scene.render.resolution_y = frame["size"]
        scene.cycles.samples = int(frame.get("samples", 1))
        _camera(bpy, mathutils, frame["camera"], to_world, meshes)
        sun = _sun(bpy, mathutils, frame["sun"], float(frame.get("irradiance", 1.0)), to_world)
        for material in materials:
            addon.network.sync_sun(material, sun)
        scene.render.filepath = frame["output"]
        start = time.perf_counter()
        bpy.ops.render.render(write_still=True)
        seconds = time.perf_counter() - start
        if not Path(frame["output"]).is_file():
            print(f"cycles_frame: {frame['output']}: Cycles wrote no frame", file=sys.stderr)
            return 5
        report.append({"output": frame["output"], "seconds": seconds, "import_seconds": import_seconds})
    Path(jobs["report"]).write_text(json.dumps({"frames": report}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
