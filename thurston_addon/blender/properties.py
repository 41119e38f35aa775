"""Scene-level settings (bpy.types.Scene.thurston) and the last render's statistics."""

import bpy

from .. import render, spaces
from ..passes import BLENDER_PASSES
from . import domain_guide
from .export import FILE, NAMED

DEFAULT_SPACE = "poincare"
PRESET_SUBDIR = "thurston"
MAX_SAMPLES = 4096  # render.Settings' most samples per pixel  # the settings presets' folder under Blender's presets
# Path settings accept Blender's // (relative to the .blend); Blender before 4.5 has no such flag.
_BLEND_RELATIVE = {"PATH_SUPPORTS_BLEND_RELATIVE"} if bpy.app.version >= (4, 5, 0) else set()
# The space enum's items before the setting stored the id: .blend files saved then hold an index into
# this list under the key "space".
_OLD_SPACE_ITEMS = (
    "half_turn",
    "hantzsche_wendt",
    "poincare",
    "quarter_turn",
    "seifert_weber",
    "sixth_turn",
    "third_turn",
    "torus",
    FILE,
)
# Blender keeps pointers into the items an enum callback returns: every list handed out stays alive
# here, one per distinct id list (the presets change rarely).
_ITEMS: dict[tuple, list] = {}


def space_missing(settings) -> bool:
    """The stored id is neither a preset (one in preset_dirs()) nor FILE nor NAMED."""
    return settings.space_id not in (FILE, NAMED) and spaces.preset_path(settings.space_id) is None


def _space_items(self, context):
    ids = spaces.preset_ids()
    missing = space_missing(self)
    key = (*ids, FILE, NAMED, *([self.space_id] if missing else []))
    if key not in _ITEMS:
        items = [(sid, sid.replace("_", " ").title(), f"Preset space {sid}", "NONE", i) for i, sid in enumerate(ids)]
        items.append((FILE, "Space File", "A space file (.toml) of your own", "NONE", len(ids)))
        items.append(
            (
                NAMED,
                "Named Space",
                "A family's member (lens(7,2)) or SnapPy's (snappy:m003(-3,1))",
                "NONE",
                len(ids) + 1,
            )
        )
        if missing:  # shown as chosen, so the dropdown does not go blank; load_space reports it
            items.append((key[-1], f"{key[-1]} (missing)", "No preset has this id", "ERROR", len(items)))
        _ITEMS[key] = items
    return _ITEMS[key]


def _name_suggestions(self, context, edit_text):
    """The space name field's search (free text is kept): each family's example, SnapPy's forms."""
    names = [f.example for f in spaces.FAMILIES] + ["snappy:m003(-3,1)", "snappy:weeks", "snappy:closed:0"]
    return [n for n in names if edit_text.lower() in n.lower()]


def _get_space(self):
    # The enum stores nothing: its value is the position of space_id in the current items.
    return next(number for sid, _, _, _, number in _space_items(self, None) if sid == self.space_id)


def _set_space(self, value):
    self.space_id = next(sid for sid, _, _, _, number in _space_items(self, None) if number == value)


@bpy.app.handlers.persistent
def migrate_space_index(*_):
    """Files saved before the setting stored the id: take the id from the old index, drop the index."""
    for bscene in bpy.data.scenes:
        settings = bscene.thurston
        old = settings.get("space")
        if isinstance(old, int) and not settings.get("space_id") and 0 <= old < len(_OLD_SPACE_ITEMS):
            settings["space_id"] = _OLD_SPACE_ITEMS[old]  # as stored data: no update, no guide rebuild
            del settings["space"]


def _space_changed(self, context):
    domain_guide.refresh(context.scene)


class ThurstonNote(bpy.types.PropertyGroup):
    kind: bpy.props.StringProperty(name="Kind", description="What the note is about (checks.py's kinds)")
    message: bpy.props.StringProperty(name="Message")
    value: bpy.props.FloatProperty(name="Value", description="What the note's fix sets, where it is a number")


class ThurstonStats(bpy.types.PropertyGroup):
    valid: bpy.props.BoolProperty(default=False)
    seconds: bpy.props.FloatProperty(name="Time", unit="TIME_ABSOLUTE")
    rays: bpy.props.IntProperty(name="Rays")
    crossings_per_ray: bpy.props.FloatProperty(name="Crossings per Ray")
    footprint: bpy.props.FloatProperty(
        name="Pixel Footprint", description="Chart units covered by a pixel sample at the median depth"
    )
    geodesic_error: bpy.props.FloatProperty(
        name="Geodesic Error",
        description="Largest distance, over sampled hits, between a traced hit and the reference geodesic (measured)",
    )
    chords_per_ray: bpy.props.FloatProperty(name="Chords per Ray", description="Embree queries per ray")
    bound: bpy.props.StringProperty(name="Accuracy", description="The hit-position accuracy the render promises")
    measured_error: bpy.props.FloatProperty(
        name="Measured Error",
        description="Largest hit-position difference, over sampled hits, to the same rays traced at 1/100 of the tolerance (chart units)",
    )
    noise: bpy.props.FloatProperty(
        name="Noise",
        description="RMS over the pixels of the standard error of each "
        "pixel's mean brightness, from its samples' spread "
        "(-1: one sample per pixel, not estimated)",
    )
    samples_mean: bpy.props.FloatProperty(
        name="Samples Mean", description="Samples per pixel used, the mean over the pixels"
    )
    samples_max: bpy.props.IntProperty(name="Samples Max", description="Samples per pixel used, the most")
    time_limit_reached: bpy.props.BoolProperty(
        name="Time Limit Reached", description="The time limit stopped the render before its last sample"
    )
    denoised: bpy.props.BoolProperty(name="Denoised", description="Whether the last render was denoised")
    summary: bpy.props.StringProperty(name="Summary")
    notes: bpy.props.CollectionProperty(
        type=ThurstonNote,
        name="Notes",
        description="What the last render found that can make it look wrong, and what to change",
    )


class ThurstonSettings(bpy.types.PropertyGroup):
    # The space is stored by id: an enum stored by position would change when a preset is added.
    space_id: bpy.props.StringProperty(
        name="Space ID",
        default=DEFAULT_SPACE,
        update=_space_changed,
        description=f"Preset id of the space, {FILE} for the space file, or {NAMED} for the space name",
    )
    space: bpy.props.EnumProperty(
        name="Space",
        items=_space_items,
        get=_get_space,
        set=_set_space,
        description="The 3-manifold the scene lives in",
    )
    space_name: bpy.props.StringProperty(
        name="Name",
        default="lens(7,2)",
        update=_space_changed,
        search=_name_suggestions,
        description="A family's member, e.g. lens(7,2), flat(amphicosm1), nil(3), or snappy:NAME (see `thurston spaces`)",
    )
    space_file: bpy.props.StringProperty(
        name="Space File",
        subtype="FILE_PATH",
        update=_space_changed,
        options=_BLEND_RELATIVE,
        description="A space file (.toml): geometry, generators, defaults",
    )
    scale: bpy.props.FloatProperty(
        name="Scale",
        default=1.0,
        min=1e-6,
        soft_max=100.0,
        update=_space_changed,
        description="Blender units per chart unit",
    )
    quality: bpy.props.EnumProperty(
        name="Quality",
        items=[
            (
                k,
                k.title(),
                f"{v.samples} sample(s) per pixel; curved geodesics: hit positions within {v.footprint_fraction:g} of a pixel",
            )
            for k, v in render.QUALITY.items()
        ],
        default="standard",
    )
    shading: bpy.props.EnumProperty(
        name="Shading", items=[(k, k.title(), f"{k} shading") for k in render.SHADING], default="lambert"
    )
    max_distance: bpy.props.FloatProperty(
        name="Max Distance",
        default=0.0,
        min=0.0,
        description="Geodesic length at which rays stop (0: the space's default)",
    )
    max_crossings: bpy.props.IntProperty(
        name="Max Crossings",
        default=-1,
        min=-1,
        description="Face crossings after which rays stop (-1: the space's default)",
    )
    fog: bpy.props.FloatProperty(
        name="Fog", default=0.0, min=0.0, description="Distance at which colour falls to 1/e (0: none)"
    )
    light_reach: bpy.props.FloatProperty(
        name="Light Reach",
        default=0.0,
        min=0.0,
        description="Each light lights along every geodesic up to this long, to "
        "every copy of the light (0: the space's default)",
    )
    light_samples: bpy.props.IntProperty(
        name="Light Samples",
        default=render.Settings.light_samples,
        min=1,
        max=4096,
        description="Points sampled on the emissive meshes and area lights per shaded point and sample",
    )
    light_paths: bpy.props.IntProperty(
        name="Light Paths",
        default=-1,
        min=-1,
        max=2**20,
        description="Shadow walks per shaded point for direct light: the strongest geodesics to the "
        "lights' copies always, the rest sampled in proportion to their light (unbiased); 0: every "
        "geodesic (the exact sum); -1: automatic (8 with bounces, else the exact sum)",
    )
    light_map: bpy.props.IntProperty(
        name="Light Map",
        default=-1,
        min=-1,
        max=render.MAX_MAP_TEXELS,
        description="Texels per cube-face edge of each point light's visibility map, which answers whether "
        "light reaches a point along each geodesic in place of its shadow walk; 0: none, every geodesic "
        "walked; -1: automatic (E3, S3 and H3: a texel per pixel angle at standard quality; else none)",
    )
    bounces: bpy.props.IntProperty(
        name="Bounces",
        default=render.Settings.bounces,
        min=0,
        max=render.MAX_BOUNCES,
        description="Bounces after each camera hit: global illumination by path tracing "
        "along geodesics, at any quality (0: direct light only)",
    )
    tolerance: bpy.props.FloatProperty(
        name="Tolerance",
        default=0.0,
        min=0.0,
        precision=6,
        step=0.001,
        description="Where geodesics bend (Nil, Sol, S2xR, H2xR, SL2): how far the traced "
        "chords may stray from the true geodesic, in Blender units (0: from "
        "the quality's bound, a fraction of the pixel footprint)",
    )
    passes: bpy.props.EnumProperty(
        name="Passes",
        options={"ENUM_FLAG"},
        items=[(p.upper(), p.title(), f"Write the {p} pass") for p in render.PASSES],
        default={p.upper() for p in render.PASSES},
    )
    panorama_width: bpy.props.IntProperty(name="Panorama Width", default=2048, min=16, max=16384)
    panorama_stereo: bpy.props.BoolProperty(
        name="Stereo Panorama",
        description="Bake Panorama bakes an omni-directional stereo pair, left eye on top (for headsets), with "
        "the camera's Stereoscopy settings, into the image 'Thurston Stereo Panorama' (the World keeps its own)",
        default=False,
    )
    save_path: bpy.props.StringProperty(
        name="Save To",
        subtype="FILE_PATH",
        options=_BLEND_RELATIVE,
        description="Also save renders here (.exr: all passes, .png: colour); empty: don't save",
    )
    overwrite: bpy.props.BoolProperty(
        name="Overwrite", default=False, description="Replace the file at Save To if it exists"
    )
    threads: bpy.props.IntProperty(name="Threads", default=0, min=0, max=render.MAX_THREADS, description="0: all cores")
    # Render on Cluster (docs/farm.md): the saved .blend rendered by `thurston render-blend --cluster`
    farm_address: bpy.props.StringProperty(
        name="Cluster",
        default="local:2",
        description="The Ray cluster: local:N (N workers on this machine) or HOST:PORT",
    )
    farm_command: bpy.props.StringProperty(
        name="Thurston Command",
        subtype="FILE_PATH",
        description="The thurston command of an install with the 'farm' extra, such as .venv/bin/thurston "
        "(empty: thurston on the PATH); Ray runs there, not in Blender",
    )
    # Sampling, under Cycles' names (scene.cycles): the render's (F12, animations, render-blend, the
    # operators' renders) and the viewport's (preview_*). Defaults that differ from Cycles' keep files
    # saved before these settings existed rendering as they did: adaptive sampling off, and sample
    # counts of 0 (the quality's; the viewport: the render's). Translated in export.render_settings.
    samples: bpy.props.IntProperty(
        name="Samples",
        default=0,
        min=0,
        max=MAX_SAMPLES,
        description="Samples per pixel of renders, the most a pixel takes under adaptive sampling (0: the quality's)",
    )
    use_adaptive_sampling: bpy.props.BoolProperty(
        name="Use Adaptive Sampling",
        default=False,
        description="Automatically reduce the number of samples per pixel based on estimated noise level",
    )
    adaptive_threshold: bpy.props.FloatProperty(
        name="Adaptive Sampling Threshold",
        default=0.01,
        min=0.0,
        max=1.0,
        soft_min=0.001,
        precision=4,
        description="A pixel stops taking samples once the standard error of its mean brightness is "
        "below this, after Min Samples (0: off, every pixel takes every sample)",
    )
    adaptive_min_samples: bpy.props.IntProperty(
        name="Adaptive Min Samples",
        default=0,
        min=0,
        max=MAX_SAMPLES,
        description="Samples every pixel takes before adaptive sampling may stop it (0: automatic, 4; "
        "at most the samples per pixel)",
    )
    time_limit: bpy.props.FloatProperty(
        name="Time Limit",
        default=0.0,
        min=0.0,
        step=100.0,
        unit="TIME_ABSOLUTE",
        description="Seconds after which no further sample pass starts (the pass under way finishes, "
        "every pixel whole). Zero disables the limit",
    )
    preview_samples: bpy.props.IntProperty(
        name="Viewport Samples",
        default=0,
        min=0,
        max=MAX_SAMPLES,
        description="Samples per pixel the rendered viewport adds one by one, the most a pixel takes "
        "under adaptive sampling (0: the render's)",
    )
    use_preview_adaptive_sampling: bpy.props.BoolProperty(
        name="Use Adaptive Sampling",
        default=False,
        description="Automatically reduce the number of samples per pixel based on estimated noise "
        "level, for viewport renders",
    )
    preview_adaptive_threshold: bpy.props.FloatProperty(
        name="Adaptive Sampling Threshold",
        default=0.1,
        min=0.0,
        max=1.0,
        soft_min=0.001,
        precision=4,
        description="A pixel stops taking samples once the standard error of its mean brightness is "
        "below this, after Min Samples (0: off), for viewport renders",
    )
    preview_adaptive_min_samples: bpy.props.IntProperty(
        name="Adaptive Min Samples",
        default=0,
        min=0,
        max=MAX_SAMPLES,
        description="Samples every pixel takes before adaptive sampling may stop it (0: automatic, 4), "
        "for viewport renders",
    )
    use_denoising: bpy.props.BoolProperty(
        name="Denoise",
        default=False,
        description="Denoise final renders with Intel Open Image Denoise (the library Blender ships), "
        "guided by the albedo and normal; the view layer's Denoising Data keeps the guides and the "
        "noisy image as passes",
    )
    stats: bpy.props.PointerProperty(type=ThurstonStats)


class ThurstonViewLayerSettings(bpy.types.PropertyGroup):
    """The add-on's own passes of a view layer (Blender's own, such as Depth, are on the view layer)."""

    __annotations__ = {
        p.flag: bpy.props.BoolProperty(name=p.label or p.name, description=p.description)
        for p in BLENDER_PASSES
        if p.addon_flag
    }


CLASSES = (ThurstonNote, ThurstonStats, ThurstonSettings, ThurstonViewLayerSettings)


def register():
    bpy.types.Scene.thurston = bpy.props.PointerProperty(type=ThurstonSettings)
    bpy.types.ViewLayer.thurston = bpy.props.PointerProperty(type=ThurstonViewLayerSettings)
    bpy.app.handlers.load_post.append(migrate_space_index)


def unregister():
    bpy.app.handlers.load_post.remove(migrate_space_index)
    del bpy.types.ViewLayer.thurston
    del bpy.types.Scene.thurston
