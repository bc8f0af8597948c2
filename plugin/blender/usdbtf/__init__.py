"""usdbtf for Blender: import a usdbtf asset, render its measured BTF (Cycles, OSL) or its
fitted lobes (Principled BSDF) in Cycles.

File > Import > usdbtf asset: Blender's own USD importer brings the geometry and the
UsdPreviewSurface fallback; the add-on then gives each BTF material two surfaces
(``network.py``) and shows one (Material properties > usdbtf > Surface):

* **Measured BTF (one sun)**: the Cycles OSL network on the asset's BTF textures, the
  measurement itself, lit by the one sun chosen in the panel (as emission: no other lamp, the
  world or bounces light it).  Render with Cycles, Open Shading Language on (CPU).
* **Fitted lobes (every light)**: a Principled BSDF on the asset's OpenPBR fallback maps (base,
  specular with anisotropy, sheen = fuzz, normal map), which every lamp, the world and bounces
  light; an approximation of the BTF (its fitted error is in ``usdbtf inspect``).

The panel also picks the level of detail (``lod``) of the measured BTF.
"""
import bpy
from bpy.app.handlers import persistent
from bpy.props import EnumProperty, PointerProperty, StringProperty
from bpy_extras.io_utils import ImportHelper

from . import network

bl_info = {
    "name": "usdbtf",
    "author": "usdbtf",
    "version": (0, 1, 0),
    "blender": (4, 2, 0),
    "location": "File > Import > usdbtf asset; Material properties > usdbtf",
    "description": "Import usdbtf assets: the measured BTF (Cycles OSL, one sun) or its fitted lobes "
                   "(Principled BSDF, every light)",
    "category": "Import-Export",
}


def _lod_items(material, context):
    # Blender keeps the strings of dynamic enum items alive only while referenced.
    _lod_items.cache = [(name, name, f"basis vectors: {level['basisCount'] or 'all'}")
                        for name, level in network.lods_of(material).items()] or [("", "none", "")]
    return _lod_items.cache


def _lod_changed(material, context):
    if material.usdbtf_lod:
        network.apply_lod(material, material.usdbtf_lod)


#: (identifier, label, description) of the material's two surfaces (network.set_surface).
SURFACE_ITEMS = [
    (network.SURFACE_BTF, "Measured BTF (one sun)",
     "The measurement itself, Cycles OSL: lit by the one sun below only (no other lamps, world or bounces)"),
    (network.SURFACE_PRINCIPLED, "Fitted lobes (every light)",
     "Principled BSDF fitted to the BTF (the asset's OpenPBR maps): every lamp, the world and bounces light it"),
]


def _surface_changed(material, context):
    network.set_surface(material, material.usdbtf_surface)


def _is_sun(_, obj):
    return obj.type == "LIGHT" and obj.data.type == "SUN"


class IMPORT_SCENE_OT_usdbtf(bpy.types.Operator, ImportHelper):
    """Import a usdbtf asset (USD) with its measured BTF as a Cycles OSL material"""

    bl_idname = "import_scene.usdbtf"
    bl_label = "Import usdbtf asset"
    bl_options = {"REGISTER", "UNDO"}
    filter_glob: StringProperty(default="*.usd;*.usda;*.usdc", options={"HIDDEN"})
    lod: StringProperty(name="lod", description="Level of detail (the asset's lod variant); empty: its default")
    surface: EnumProperty(name="Surface", items=SURFACE_ITEMS, default=network.SURFACE_BTF)

    def execute(self, context):
        try:
            objects, materials = network.import_asset(self.filepath, self.lod or None, self.surface)
        except (ValueError, RuntimeError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        context.scene.render.engine = "CYCLES"
        context.scene.cycles.device = "CPU"
        context.scene.cycles.shading_system = True
        sun = next((o for o in context.scene.objects if _is_sun(None, o)), None)
        for material in materials:
            material.usdbtf_sun = sun
            material.usdbtf_surface = self.surface
            network.sync_sun(material, sun)
        warning = network.working_space_warning(self.filepath)
        if warning:
            self.report({"WARNING"}, warning)
        self.report({"INFO"}, f"usdbtf: {len(objects)} objects, {len(materials)} BTF materials")
        return {"FINISHED"}


class MATERIAL_PT_usdbtf(bpy.types.Panel):
    bl_label = "usdbtf"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "material"

    @classmethod
    def poll(cls, context):
        return context.material is not None and "usdbtf_lods" in context.material

    def draw(self, context):
        material = context.material
        self.layout.prop(material, "usdbtf_surface")
        if material.usdbtf_surface == network.SURFACE_PRINCIPLED:
            self.layout.label(text="Principled BSDF fitted to the BTF: every lamp, the world and bounces")
            return
        self.layout.prop(material, "usdbtf_lod")
        self.layout.prop(material, "usdbtf_sun")
        self.layout.label(text="Measured BTF (Cycles, Open Shading Language): this sun only, as emission")


@persistent
def _follow_suns(scene, depsgraph=None):
    """Keep every usdbtf material's light parameters on its sun (moved, rotated, dimmed)."""
    for material in bpy.data.materials:
        sun = getattr(material, "usdbtf_sun", None)
        if sun is not None:
            network.sync_sun(material, sun)


def _menu(self, context):
    self.layout.operator(IMPORT_SCENE_OT_usdbtf.bl_idname, text="usdbtf asset (.usda)")


def register():
    bpy.utils.register_class(IMPORT_SCENE_OT_usdbtf)
    bpy.utils.register_class(MATERIAL_PT_usdbtf)
    bpy.types.Material.usdbtf_lod = EnumProperty(name="lod", description="Level of detail: basis vectors and "
                                                 "the textures they need", items=_lod_items, update=_lod_changed)
    bpy.types.Material.usdbtf_surface = EnumProperty(name="Surface", items=SURFACE_ITEMS,
                                                     default=network.SURFACE_BTF, update=_surface_changed,
                                                     description="Which of the material's two surfaces renders")
    bpy.types.Material.usdbtf_sun = PointerProperty(name="Sun", type=bpy.types.Object, poll=_is_sun,
                                                    description="The sun lamp whose direction lights the BTF")
    bpy.types.TOPBAR_MT_file_import.append(_menu)
    for handlers in (bpy.app.handlers.depsgraph_update_post, bpy.app.handlers.frame_change_post):
        handlers.append(_follow_suns)


def unregister():
    for handlers in (bpy.app.handlers.depsgraph_update_post, bpy.app.handlers.frame_change_post):
        if _follow_suns in handlers:
            handlers.remove(_follow_suns)
    bpy.types.TOPBAR_MT_file_import.remove(_menu)
    del bpy.types.Material.usdbtf_sun
    del bpy.types.Material.usdbtf_surface
    del bpy.types.Material.usdbtf_lod
    bpy.utils.unregister_class(MATERIAL_PT_usdbtf)
    bpy.utils.unregister_class(IMPORT_SCENE_OT_usdbtf)
