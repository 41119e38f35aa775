"""The THURSTON render engine: F12 renders each view layer through the tracer into the Combined pass
and the passes its view layer enables (export.BLENDER_PASSES); the viewport in rendered mode draws
progressively refined frames."""
from __future__ import annotations

import numpy as np
import bpy

from . import export, render

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
        for p in export.BLENDER_PASSES:
            if export.pass_enabled(renderlayer, p):
                self.register_pass(scene, renderlayer, p.name, len(p.chan_id), p.chan_id, p.type)

    def render(self, depsgraph):
        """One view layer (Blender calls this once per layer, each with its own depsgraph): the
        render region only, the layer's passes, and every note in the render report."""
        bscene = depsgraph.scene
        w, h = export.resolution(bscene)
        try:
            job = export.RenderJob(bscene, depsgraph, w, h, camera_object=self.camera_override,
                                   region=export.border_region(bscene, w, h))
        except (export.ExportError, render.RenderError) as exc:
            self.report({"ERROR"}, f"Thurston: {exc}")
            return
        except Exception as exc:  # RenderEngine.render swallows exceptions: report instead
            self.report({"ERROR"}, f"Thurston render failed: {exc}")
            return

        def progress(done, total):
            self.update_progress(done / max(total, 1))
            for listener in progress_listeners:
                listener(done, total)
            return not self.test_break()

        job.run(progress)
        if isinstance(job.error, render.Cancelled):
            return
        if job.error is not None:  # RenderEngine.render swallows exceptions: report instead
            self.report({"ERROR"}, f"Thurston render failed: {job.error}")
            return
        for message in job.messages():
            self.report({"WARNING"}, f"Thurston: {message}")
        export.store_stats(bscene.thurston, job)
        self.update_stats("Thurston", job.result.summary())
        self.write_result(job, depsgraph.view_layer.name)

    def write_result(self, job, layer_name):
        _, _, w, h = job.settings.window
        # with a render region, Blender's result rectangle is relative to the region
        out = self.begin_result(0, 0, w, h, layer=layer_name)
        layer = out.layers[0]
        rgba = np.concatenate([np.nan_to_num(job.result.passes["color"]), job.result.passes["alpha"][..., None]], axis=-1)
        values = {"Combined": rgba, **export.pass_values(job)}
        for rp in layer.passes:
            a = values.get(rp.name)
            if a is not None:
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


# Blender's panels that are not generic (Blender's generic panels list BLENDER_RENDER) but that a user of
# this engine needs: material slots and surface, the world's surface, the view layer's passes.
_SHARED_PANELS = ("EEVEE_MATERIAL_PT_context_material", "EEVEE_MATERIAL_PT_surface", "EEVEE_WORLD_PT_surface",
                  "VIEWLAYER_PT_layer_passes", "VIEWLAYER_PT_layer_passes_aov", "DATA_PT_EEVEE_light")


def _walk(cls):
    for sub in cls.__subclasses__():
        yield sub
        yield from _walk(sub)


def compatible_panels():
    """Blender's own Properties panels shown under this engine, as other engines register them: the
    generic ones (all that list BLENDER_RENDER, but Freestyle's, which the tracer does not draw) and
    _SHARED_PANELS."""
    panels = {}
    for panel in _walk(bpy.types.Panel):
        engines = getattr(panel, "COMPAT_ENGINES", None)
        if engines is None or getattr(panel, "bl_space_type", "") != "PROPERTIES":
            continue
        if ("BLENDER_RENDER" in engines and "freestyle" not in panel.__name__.lower()) or panel.__name__ in _SHARED_PANELS:
            panels[panel.__name__] = panel
    return list(panels.values())


def register():
    for panel in compatible_panels():
        panel.COMPAT_ENGINES.add(ThurstonRenderEngine.bl_idname)


def unregister():
    for panel in compatible_panels():
        panel.COMPAT_ENGINES.discard(ThurstonRenderEngine.bl_idname)


CLASSES = (ThurstonRenderEngine,)
