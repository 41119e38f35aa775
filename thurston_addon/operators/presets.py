"""Save the Thurston settings as a preset of the presets menu, or remove one."""

import bpy
from bl_operators.presets import AddPresetBase

from ..blender import properties

# Settings a preset leaves alone: the space enum (space_id is its value), the last render's
# statistics, and where this file saves its renders (Save To, Overwrite).
NOT_IN_PRESETS = {"space", "stats", "save_path", "overwrite"}


class THURSTON_OT_add_preset(AddPresetBase, bpy.types.Operator):
    """Save the Thurston settings as a preset, or remove one"""

    bl_idname = "thurston.add_preset"
    bl_label = "Add Thurston Preset"
    preset_menu = "THURSTON_MT_presets"
    preset_subdir = properties.PRESET_SUBDIR
    preset_defines = ["settings = bpy.context.scene.thurston"]
    # every setting of the render (sampling, light, bounces, ...), so that none is left behind when
    # one is added
    preset_values = [
        f"settings.{name}" for name in properties.ThurstonSettings.__annotations__ if name not in NOT_IN_PRESETS
    ]


CLASSES = (THURSTON_OT_add_preset,)
