"""Scene-level settings (bpy.types.Scene.thurston) and the last render's statistics."""
import bpy

from .. import render, spaces

_PRESET_ITEMS = None


def _space_items(self, context):
    # Blender keeps a reference to enum items returned by a callback only while we do
    global _PRESET_ITEMS
    if _PRESET_ITEMS is None:
        _PRESET_ITEMS = [(sid, sid.replace("_", " ").title(), f"Preset space {sid}") for sid in spaces.preset_ids()]
        _PRESET_ITEMS.append(("FILE", "Space File", "A space file (.toml) of your own"))
    return _PRESET_ITEMS


def _space_changed(self, context):
    from . import guide

    guide.refresh(context.scene)


class ThurstonStats(bpy.types.PropertyGroup):
    valid: bpy.props.BoolProperty(default=False)
    seconds: bpy.props.FloatProperty(name="Time", unit="TIME_ABSOLUTE")
    rays: bpy.props.IntProperty(name="Rays")
    crossings_per_ray: bpy.props.FloatProperty(name="Crossings per Ray")
    footprint: bpy.props.FloatProperty(name="Pixel Footprint", description="Chart units covered by a pixel sample at the median depth")
    geodesic_error: bpy.props.FloatProperty(name="Geodesic Error", description="Largest distance, over sampled hits, between a traced hit and the exact geodesic (measured)")
    summary: bpy.props.StringProperty(name="Summary")


class ThurstonSettings(bpy.types.PropertyGroup):
    space: bpy.props.EnumProperty(name="Space", items=_space_items, update=_space_changed,
                                  description="The 3-manifold the scene lives in")
    space_file: bpy.props.StringProperty(name="Space File", subtype="FILE_PATH", update=_space_changed,
                                         description="A space file (.toml): geometry, generators, defaults")
    scale: bpy.props.FloatProperty(name="Scale", default=1.0, min=1e-6, soft_max=100.0, update=_space_changed,
                                   description="Blender units per chart unit")
    quality: bpy.props.EnumProperty(name="Quality", items=[(k, k.title(), f"{v} sample(s) per pixel") for k, v in render.QUALITY.items()],
                                    default="standard")
    shading: bpy.props.EnumProperty(name="Shading", items=[(k, k.title(), f"{k} shading") for k in render.SHADING], default="lambert")
    max_distance: bpy.props.FloatProperty(name="Max Distance", default=0.0, min=0.0,
                                          description="Geodesic length at which rays stop (0: the space's default)")
    max_crossings: bpy.props.IntProperty(name="Max Crossings", default=-1, min=-1,
                                         description="Face crossings after which rays stop (-1: the space's default)")
    fog: bpy.props.FloatProperty(name="Fog", default=0.0, min=0.0, description="Distance at which colour falls to 1/e (0: none)")
    passes: bpy.props.EnumProperty(
        name="Passes", options={"ENUM_FLAG"},
        items=[(p.upper(), p.title(), f"Write the {p} pass") for p in render.PASSES],
        default={p.upper() for p in render.PASSES})
    panorama_width: bpy.props.IntProperty(name="Panorama Width", default=2048, min=16, max=16384)
    save_path: bpy.props.StringProperty(name="Save To", subtype="FILE_PATH",
                                        description="Also save renders here (.exr: all passes, .png: colour); empty: don't save")
    overwrite: bpy.props.BoolProperty(name="Overwrite", default=False, description="Replace the file at Save To if it exists")
    threads: bpy.props.IntProperty(name="Threads", default=0, min=0, description="0: all cores")
    stats: bpy.props.PointerProperty(type=ThurstonStats)


CLASSES = (ThurstonStats, ThurstonSettings)


def register():
    bpy.types.Scene.thurston = bpy.props.PointerProperty(type=ThurstonSettings)


def unregister():
    del bpy.types.Scene.thurston
