"""Save the Thurston settings as a preset of the presets menu, or remove one."""

import bpy
from bl_operators.presets import AddPresetBase

from ..blender import properties


class THURSTON_OT_add_preset(AddPresetBase, bpy.types.Operator):
    """Save the Thurston settings as a preset, or remove one"""

    bl_idname = "thurston.add_preset"
    bl_label = "Add Thurston Preset"
    preset_menu = "THURSTON_MT_presets"
    preset_subdir = properties.PRESET_SUBDIR
    preset_defines = ["settings = bpy.context.scene.thurston"]
    preset_values = [
        f"settings.{name}"
        for name in (
            "space_id",
            "space_file",
            "scale",
            "quality",
            "tolerance",
            "shading",
            "max_distance",
            "max_crossings",
            "fog",
            "passes",
            "panorama_width",
            "samples",
            "use_adaptive_sampling",
            "adaptive_threshold",
            "adaptive_min_samples",
            "time_limit",
            "preview_samples",
            "use_preview_adaptive_sampling",
            "preview_adaptive_threshold",
            "preview_adaptive_min_samples",
            "threads",
        )
    ]


CLASSES = (THURSTON_OT_add_preset,)
