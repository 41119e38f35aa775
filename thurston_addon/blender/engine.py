"""The THURSTON render engine: F12 renders each view layer through the tracer into the Combined pass
and the passes its view layer enables (export.BLENDER_PASSES); the viewport in rendered mode draws
progressively refined frames, then adds samples up to the settings' count."""

from __future__ import annotations

import weakref
from dataclasses import replace

import bpy
import numpy as np

from .. import progressive, render, scenes
from . import export

# Callables (done, total) told of the progress of final renders; batch renders show it on the terminal.
progress_listeners: list = []


def _flip_rows(a):
    return np.ascontiguousarray(a[::-1])  # Blender's rows are bottom-up


class ThurstonRenderEngine(bpy.types.RenderEngine):
    bl_idname = "THURSTON"
    bl_label = "Thurston"
    bl_use_preview = False
    bl_use_postprocess = True
    # panoramic cameras' stereo views are omni-directional (render/stereo.py), as Cycles' spherical stereo
    bl_use_spherical_stereo = True
    bl_use_shading_nodes_custom = False

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._view = progressive.ProgressiveView()
        self._viewport_world = None  # (space, tracer) of the scene as last exported, or the error
        self._scene_version = 0  # counts the exports of the viewport's scene
        self._meshes: dict = {}  # the viewport's meshes as last read (export_scene's `meshes`)
        self._meshes_scale = None
        self._redraw = _redraw_timer(self)

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
        # an animation's error names its frame (render-blend names the frame itself)
        frame = f"frame {bscene.frame_current}: " if self.is_animation else ""
        try:
            job = export.RenderJob(
                bscene, depsgraph, w, h, camera_object=self.camera_override, region=export.border_region(bscene, w, h)
            )
        except (export.ExportError, render.RenderError) as exc:
            self.report({"ERROR"}, f"Thurston: {frame}{exc}")
            return
        except Exception as exc:  # RenderEngine.render swallows exceptions: report instead
            self.report({"ERROR"}, f"Thurston render failed: {frame}{exc}")
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
            self.report({"ERROR"}, f"Thurston render failed: {frame}{job.error}")
            return
        for message in job.messages():
            self.report({"WARNING"}, f"Thurston: {message}")
        export.store_stats(bscene.thurston, job)
        self.update_stats("Thurston", job.summary())
        for view in job.views:  # Stereoscopy's eyes, or the one view
            self.write_result(job, depsgraph.view_layer.name, view)

    def write_result(self, job, layer_name, view=None):
        _, _, w, h = job.settings.window
        # with a render region, Blender's result rectangle is relative to the region
        out = self.begin_result(0, 0, w, h, layer=layer_name, view=view or "")
        layer = out.layers[0]
        values = {"Combined": export.combined(job.results[view].passes), **export.pass_values(job, view)}
        for rp in layer.passes:
            a = values.get(rp.name)
            if a is not None:
                rp.rect.foreach_set(_flip_rows(a).ravel())
        self.end_result(out)

    # --- viewport: traced off the UI thread, coarse to fine, cancelled by any change ---------------
    def view_update(self, context, depsgraph):
        """The depsgraph changed: re-export the scene and build a new tracer, unless only what the
        tracer does not see changed (the camera, the domain guide: the view comes from the region)."""
        if self._viewport_world is not None and not changes_scene(depsgraph):
            return
        bscene = depsgraph.scene
        scale = bscene.thurston.scale
        if changes_meshes(depsgraph) or scale != self._meshes_scale:
            self._meshes.clear()  # else only transforms changed: the meshes read last time serve
        self._meshes_scale = scale
        try:
            space = export.load_space(bscene.thurston)
            scene = export.export_scene(depsgraph, scale, [], meshes=self._meshes)
            settings = export.render_settings(bscene.thurston, 1, 1)  # the size is not used
            scene, _, _ = export.pseudo_colour(space, scene, settings)
            export.check_scale(space, scene, scale)
            reach = render.light_reach_for(space, settings)
            self._viewport_world = (space, render.make_tracer(space, scene, bscene.thurston.threads, reach))
        except (export.ExportError, render.RenderError, scenes.SceneError) as exc:
            self._viewport_world = exc
        self._scene_version += 1
        self.tag_redraw()

    def view_draw(self, context, depsgraph):
        import gpu  # unavailable in background mode, needed only here
        from gpu_extras.presets import draw_texture_2d

        region, view = context.region, context.region_data
        w, h = region.width, region.height
        try:
            job, settings = self._viewport_job(depsgraph.scene, view, w, h)
        except (export.ExportError, render.RenderError) as exc:
            self.update_stats("Thurston", str(exc))
            return
        samples = settings.samples_per_pixel
        adaptive = (settings.noise_threshold, settings.min_samples_per_pixel)
        key = (
            w,
            h,
            tuple(map(tuple, view.view_matrix)),
            tuple(map(tuple, view.window_matrix)),
            self._scene_version,
            samples,
            adaptive,
        )
        self._view.request(key, job, samples, *adaptive)
        if self._view.error is not None:
            self.update_stats("Thurston", f"viewport render failed: {self._view.error}")
        if self._view.busy and not bpy.app.timers.is_registered(self._redraw):
            bpy.app.timers.register(self._redraw, first_interval=0.1)
        frame = self._view.frame
        if frame is None:
            return
        self.update_stats("Thurston", viewport_status(frame, samples))
        pixels = frame.pixels
        ph, pw = pixels.shape[:2]
        buffer = gpu.types.Buffer("FLOAT", pw * ph * 4, pixels.ravel())
        texture = gpu.types.GPUTexture((pw, ph), format="RGBA16F", data=buffer)
        gpu.state.blend_set("ALPHA_PREMULT")
        self.bind_display_space_shader(depsgraph.scene)
        draw_texture_2d(texture, (0, 0), w, h)
        self.unbind_display_space_shader()
        gpu.state.blend_set("NONE")

    def _viewport_job(self, bscene, view, w, h):
        """(trace_frame(level, sample, cancelled), settings) for the progressive view: draft
        accuracy, the settings' bounces, and the viewport's sampling (export.render_settings with
        viewport: its Samples, else F12's, and its adaptive sampling), in the settings' samples per
        pixel, noise threshold and min samples. Everything it needs is read from Blender here, on the
        UI thread; the worker only traces."""
        if isinstance(self._viewport_world, Exception):
            raise self._viewport_world
        space, tracer = self._viewport_world
        if not view.is_perspective:
            raise render.RenderError("the viewport is orthographic; Thurston shows perspective views only")
        inverse = np.array(view.view_matrix.inverted(), float)
        scale = bscene.thurston.scale
        # the field of view the viewport itself shows (its lens, sensor and camera zoom)
        fov = 2 * np.degrees(np.arctan(1.0 / view.window_matrix[0][0]))
        camera = scenes.Camera(inverse[:3, 3] / scale, -inverse[:3, 2], inverse[:3, 1], float(fov))
        # the viewport is not denoised (its frames are single samples)
        settings = replace(
            export.render_settings(bscene.thurston, w, h, transparent=bscene.render.film_transparent, viewport=True),
            denoise=False,
        )
        samples = settings.samples_per_pixel
        # draft accuracy; the samples per pixel stay those chosen (the set count, or the quality's)
        settings = replace(settings, quality="draft", samples=samples)
        _, settings, _ = export.pseudo_colour(space, scenes.Scene(), settings)  # (its note: F12's report)

        def frame(level, sample, cancelled):
            sized = replace(settings, width=max(1, w // level), height=max(1, h // level))
            shifted, one = progressive.one_sample(camera, sized, sample, samples)
            result = render.render(
                space, None, one, camera=shifted, tracer=tracer, progress=lambda done, total: not cancelled()
            )
            return _flip_rows(export.combined(result.passes))

        return frame, settings

    def __del__(self):
        try:  # a frame still being traced for a viewport that is gone
            self._view.cancel()
        except (AttributeError, ReferenceError):  # never set up, or Blender freed the engine first
            pass


def viewport_status(frame, samples: int) -> str:
    """What the viewport shows: its resolution while refining, then the samples (under adaptive
    sampling also their mean per pixel) and their noise."""
    if frame.level > 1:
        return f"viewport: 1/{frame.level} resolution"
    used = "" if frame.samples_mean is None else f" (mean {frame.samples_mean:.2f} per pixel)"
    noise = "" if frame.noise is None else f", noise {frame.noise:.1e}"
    done = frame.samples >= samples or frame.converged
    return f"viewport: sample {frame.samples}/{samples}{used}{noise}" + (" (done)" if done else "")


def changes_meshes(depsgraph) -> bool:
    """Whether the depsgraph's updates may change what a mesh read holds (geometry, materials,
    images), not only where objects are."""
    return any(u.is_updated_geometry or u.is_updated_shading for u in depsgraph.updates)


def changes_scene(depsgraph) -> bool:
    """Whether the depsgraph's updates touch what the tracer sees: objects other than cameras and
    the domain guide, their data, materials, images, the world, the scene's settings."""
    for update in depsgraph.updates:
        data = update.id
        if isinstance(data, bpy.types.Object):
            if data.type == "CAMERA" or data.original.get(export.GUIDE_TAG):
                continue
            return True
        if not isinstance(data, bpy.types.Camera):
            return True
    return False


def _redraw_timer(engine):
    """A timer function that redraws the viewport while its frame is being refined (the worker
    thread must not call into Blender); it holds the engine weakly."""
    ref = weakref.ref(engine)

    def tick():
        alive = ref()
        if alive is not None:
            try:
                alive.tag_redraw()
            except ReferenceError:  # Blender freed the engine
                pass
        return None

    return tick


# Blender's panels that are not generic (Blender's generic panels list BLENDER_RENDER) but that a user of
# this engine needs: material slots and surface, the world's surface, the view layer's passes.
_SHARED_PANELS = (
    "EEVEE_MATERIAL_PT_context_material",
    "EEVEE_MATERIAL_PT_surface",
    "EEVEE_WORLD_PT_surface",
    "VIEWLAYER_PT_layer_passes",
    "VIEWLAYER_PT_layer_passes_aov",
    "DATA_PT_EEVEE_light",
)


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
        if (
            "BLENDER_RENDER" in engines and "freestyle" not in panel.__name__.lower()
        ) or panel.__name__ in _SHARED_PANELS:
            panels[panel.__name__] = panel
    return list(panels.values())


def register():
    for panel in compatible_panels():
        panel.COMPAT_ENGINES.add(ThurstonRenderEngine.bl_idname)


def unregister():
    for panel in compatible_panels():
        panel.COMPAT_ENGINES.discard(ThurstonRenderEngine.bl_idname)


CLASSES = (ThurstonRenderEngine,)
