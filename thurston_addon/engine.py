"""The THURSTON render engine: F12 renders through the tracer into the Combined pass and the
requested passes (Depth, Normal, IndexOB, and Crossings as an AOV); the viewport in rendered mode
draws progressively refined frames."""
from __future__ import annotations

import numpy as np
import bpy

from . import export, render

CROSSINGS_AOV = "Crossings"
# Callables (done, total) told of the progress of final renders; batch renders show it on the terminal.
progress_listeners: list = []


def _flip_rows(a):
    return np.ascontiguousarray(a[::-1])  # Blender's rows are bottom-up


class ThurstonRenderEngine(bpy.types.RenderEngine):
    bl_idname = "THURSTON"
    bl_label = "Thurston"
    bl_use_preview = False
    bl_use_postprocess = True
    bl_use_shading_nodes_custom = False

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._viewport = None  # (key, level, pixels) of the progressive viewport render
        self._viewport_world = None  # (space, tracer) of the scene as last exported, or the error

    def update_render_passes(self, scene=None, renderlayer=None):
        self.register_pass(scene, renderlayer, "Combined", 4, "RGBA", "COLOR")
        if renderlayer.use_pass_z:
            self.register_pass(scene, renderlayer, "Depth", 1, "Z", "VALUE")
        if renderlayer.use_pass_normal:
            self.register_pass(scene, renderlayer, "Normal", 3, "XYZ", "VECTOR")
        if renderlayer.use_pass_object_index:
            self.register_pass(scene, renderlayer, "IndexOB", 1, "X", "VALUE")
        for aov in renderlayer.aovs:
            if aov.name == CROSSINGS_AOV:
                self.register_pass(scene, renderlayer, aov.name, 1 if aov.type == "VALUE" else 3,
                                   "X" if aov.type == "VALUE" else "RGB", aov.type)

    def render(self, depsgraph):
        bscene = depsgraph.scene
        w, h = export.resolution(bscene)
        try:
            space, scene, camera, settings, notes = export.collect(bscene, depsgraph, w, h, camera_object=self.camera_override)
        except (export.ExportError, render.RenderError) as exc:
            self.report({"ERROR"}, f"Thurston: {exc}")
            return
        for note in notes:
            self.report({"WARNING"}, f"Thurston: {note}")

        def progress(done, total):
            self.update_progress(done / max(total, 1))
            for listener in progress_listeners:
                listener(done, total)
            return not self.test_break()

        try:
            result = render.render(space, scene, settings, camera=camera, progress=progress)
        except render.Cancelled:
            return
        except Exception as exc:  # RenderEngine.render swallows exceptions: report instead
            self.report({"ERROR"}, f"Thurston render failed: {exc}")
            return
        export.store_stats(bscene.thurston, result)
        self.update_stats("Thurston", result.summary())
        self.write_result(bscene, result, scene, w, h)

    def write_result(self, bscene, result, scene, w, h):
        passes = export.blender_passes(result, bscene.thurston.scale)
        out = self.begin_result(0, 0, w, h)
        layer = out.layers[0]
        rgba = np.ones((h, w, 4), np.float32)
        rgba[..., :3] = np.nan_to_num(passes["color"])
        values = {
            "Combined": rgba,
            # Blender's Z pass holds a large value where nothing is hit
            "Depth": np.where(np.isfinite(passes["depth"]), passes["depth"], 1e10)[..., None],
            "Normal": np.nan_to_num(passes["normal"]),
            "IndexOB": export.index_pass(result, scene)[..., None],
            CROSSINGS_AOV: passes["crossings"][..., None].astype(np.float32),
        }
        for rp in layer.passes:
            a = values.get(rp.name)
            if a is None:
                continue
            a = np.asarray(a, np.float32)
            if a.shape[-1] != rp.channels:
                a = np.repeat(a[..., :1], rp.channels, axis=-1)
            rp.rect.foreach_set(_flip_rows(a).ravel())
        self.end_result(out)

    # --- viewport: progressive refinement, coarse first ---------------------------------------------
    def view_update(self, context, depsgraph):
        """The scene changed: export it and build the tracer once, for all refinement levels."""
        self._viewport = None
        bscene = depsgraph.scene
        try:
            space = export.load_space(bscene.thurston)
            scene = export.export_scene(depsgraph, bscene.thurston.scale, [])
            self._viewport_world = (space, render.make_tracer(space, scene, bscene.thurston.threads))
        except (export.ExportError, render.RenderError) as exc:
            self._viewport_world = exc
        self.tag_redraw()

    def view_draw(self, context, depsgraph):
        import gpu  # unavailable in background mode, needed only here
        from gpu_extras.presets import draw_texture_2d

        region = context.region
        w, h = region.width, region.height
        key = (w, h, tuple(map(tuple, context.region_data.view_matrix)))
        level = 8 if self._viewport is None or self._viewport[0] != key else self._viewport[1]
        if self._viewport is None or self._viewport[0] != key or self._viewport[1] > 1:
            try:
                pixels = self._viewport_frame(context, depsgraph, max(1, w // level), max(1, h // level))
            except (export.ExportError, render.RenderError) as exc:
                self.update_stats("Thurston", str(exc))
                return
            self._viewport = (key, max(1, level // 2), pixels)
            if level > 1:
                self.tag_redraw()
        pixels = self._viewport[2]
        ph, pw = pixels.shape[:2]
        buffer = gpu.types.Buffer("FLOAT", pw * ph * 4, pixels.ravel())
        texture = gpu.types.GPUTexture((pw, ph), format="RGBA16F", data=buffer)
        gpu.state.blend_set("ALPHA_PREMULT")
        self.bind_display_space_shader(depsgraph.scene)
        draw_texture_2d(texture, (0, 0), w, h)
        self.unbind_display_space_shader()
        gpu.state.blend_set("NONE")

    def _viewport_frame(self, context, depsgraph, w, h):
        from . import scene as scenes

        bscene = depsgraph.scene
        if isinstance(self._viewport_world, Exception):
            raise self._viewport_world
        space, tracer = self._viewport_world
        region = context.region_data
        if not region.is_perspective:
            raise render.RenderError("the viewport is orthographic; Thurston shows perspective views only")
        view = np.array(region.view_matrix.inverted(), float)
        scale = bscene.thurston.scale
        # the field of view the viewport itself shows (its lens, sensor and camera zoom)
        fov = 2 * np.degrees(np.arctan(1.0 / region.window_matrix[0][0]))
        camera = scenes.Camera(view[:3, 3] / scale, -view[:3, 2], view[:3, 1], float(fov))
        settings = export.render_settings(bscene.thurston, w, h)
        settings.quality = "draft"
        result = render.render(space, None, settings, camera=camera, tracer=tracer)
        rgba = np.ones((h, w, 4), np.float32)
        rgba[..., :3] = np.nan_to_num(result.passes["color"])
        return _flip_rows(rgba)


def _compatible_panels():
    """Blender's own panels that make sense with this engine (as other engines register them)."""
    keep = {"RENDER_PT_format", "RENDER_PT_frame_range", "RENDER_PT_output", "RENDER_PT_dimensions",
            "VIEWLAYER_PT_layer_passes", "VIEWLAYER_PT_layer_passes_data", "VIEWLAYER_PT_layer_passes_aov",
            "DATA_PT_lens", "DATA_PT_camera", "DATA_PT_light", "DATA_PT_EEVEE_light", "MATERIAL_PT_preview"}
    return [getattr(bpy.types, name) for name in keep if hasattr(bpy.types, name)]


def register():
    for panel in _compatible_panels():
        if hasattr(panel, "COMPAT_ENGINES"):
            panel.COMPAT_ENGINES.add(ThurstonRenderEngine.bl_idname)


def unregister():
    for panel in _compatible_panels():
        if hasattr(panel, "COMPAT_ENGINES"):
            panel.COMPAT_ENGINES.discard(ThurstonRenderEngine.bl_idname)


CLASSES = (ThurstonRenderEngine,)
