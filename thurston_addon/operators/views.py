"""Operators: Render View to Image, Bake Panorama, Preview. Each runs synchronously in background
mode (bpy.app.background: no modal handlers tick there) and, in the UI, on a worker thread with
progress in the status bar and Esc to cancel."""

from __future__ import annotations

import threading

import bpy
import numpy as np

from .. import files, images, render
from ..blender import export, results

OVERWRITE_IN_THE_PANEL = "tick Overwrite in the Thurston panel"


def check_save_path(settings):
    if not settings.save_path:
        return None
    return files.check_output(
        bpy.path.abspath(settings.save_path), settings.overwrite, to_replace=OVERWRITE_IN_THE_PANEL
    )


def save_if_asked(settings, job: export.RenderJob, report, passes=None):
    """The panel's save path: the job's passes (or the `passes` given: a stereo panorama's)."""
    out = check_save_path(settings)
    if out is None:
        return
    names = [p.lower() for p in settings.passes] or ["color"]
    images.write(
        out,
        export.blender_passes(passes or job.result.passes, settings.scale),
        names=names,
        metadata={"summary": job.summary()},
        overwrite=settings.overwrite,
        to_replace=OVERWRITE_IN_THE_PANEL,
    )
    report({"INFO"}, f"Saved {out}")


# --- the operators -----------------------------------------------------------------------------------
class _ThurstonRenderOperator(bpy.types.Operator):
    bl_options = {"REGISTER"}
    image_name = "Thurston View"

    _job: export.RenderJob | None = None
    _thread = None
    _timer = None

    def make_job(self, context) -> export.RenderJob:
        raise NotImplementedError

    def finish(self, context, job: export.RenderJob):
        image = results.store_image(self.image_name, job.result.passes)
        results.show_image(context, image)
        save_if_asked(context.scene.thurston, job, self.report)

    def execute(self, context):
        try:
            job = self.make_job(context)
            check_save_path(context.scene.thurston)  # refuse before the render, not after it
        except (export.ExportError, render.RenderError, files.OutputError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        if bpy.app.background:
            job.run()
            return self._conclude(context, job)
        self._job = job
        self._thread = threading.Thread(target=job.run, daemon=True)
        self._thread.start()
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.1, window=context.window)
        wm.modal_handler_add(self)
        wm.progress_begin(0, 100)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        wm = context.window_manager
        if event.type == "ESC":
            self._job.cancelled = True
            return {"RUNNING_MODAL"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}  # the UI stays usable while the worker traces
        wm.progress_update(int(self._job.fraction * 100))
        context.workspace.status_text_set(f"Thurston: {self.bl_label} {self._job.fraction * 100:.0f}% (Esc to cancel)")
        if self._thread.is_alive():
            return {"RUNNING_MODAL"}
        wm.event_timer_remove(self._timer)
        wm.progress_end()
        context.workspace.status_text_set(None)
        return self._conclude(context, self._job)

    def _conclude(self, context, job):
        if isinstance(job.error, render.Cancelled):
            self.report({"WARNING"}, "Thurston render cancelled")
            return {"CANCELLED"}
        if job.error is not None:
            self.report({"ERROR"}, f"Thurston render failed: {job.error}")
            return {"CANCELLED"}
        for message in job.messages():
            self.report({"WARNING"}, message)
        export.store_stats(context.scene.thurston, job)
        try:
            self.finish(context, job)
        except (files.OutputError, OSError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, job.summary())
        return {"FINISHED"}


class THURSTON_OT_render_view(_ThurstonRenderOperator):
    """Render the camera's view inside the space into an image (linear float)"""

    bl_idname = "thurston.render_view"
    bl_label = "Render View to Image"

    def make_job(self, context):
        return export.RenderJob(context.scene, context.evaluated_depsgraph_get(), stereo=None)


class THURSTON_OT_preview(_ThurstonRenderOperator):
    """A quick low-resolution render at preview quality"""

    bl_idname = "thurston.preview"
    bl_label = "Preview"
    image_name = "Thurston Preview"

    def make_job(self, context):
        w, h = export.resolution(context.scene)
        k = max(1, max(w, h) // 320)
        return export.RenderJob(
            context.scene,
            context.evaluated_depsgraph_get(),
            width=max(1, w // k),
            height=max(1, h // k),
            quality="preview",
            stereo=None,
        )


class THURSTON_OT_bake_panorama(_ThurstonRenderOperator):
    """Bake the 360° view from the camera point into an equirectangular image and use it as the World
    background; with Stereo, an omni-directional stereo pair (left eye on top) for headsets"""

    bl_idname = "thurston.bake_panorama"
    bl_label = "Bake Panorama"
    image_name = "Thurston Panorama"
    stereo_image_name = "Thurston Stereo Panorama"

    def make_job(self, context):
        settings = context.scene.thurston
        w = settings.panorama_width
        camera = context.scene.camera
        stereo = export.camera_stereo(camera, settings.scale) if settings.panorama_stereo and camera else None
        job = export.RenderJob(
            context.scene,
            context.evaluated_depsgraph_get(),
            width=w,
            height=max(1, w // 2),
            projection="equirect",
            stereo=stereo,
        )
        # Blender's equirectangular mapping: the image centre looks along +X, the right half of the
        # image towards -Y, up is +Z (world axes)
        job.camera.forward, job.camera.up = np.array([1.0, 0, 0]), np.array([0, 0, 1.0])
        return job

    def finish(self, context, job):
        if job.settings.stereo is None:
            image = results.store_image(self.image_name, job.result.passes)
            results.set_world_panorama(context.scene, image)
            save_if_asked(context.scene.thurston, job, self.report)
            return
        # a stereo pair is for headsets, not a World (which shows one view): an image of its own
        pair = render.side_by_side(*job.results.values(), "top-bottom")
        results.store_image(self.stereo_image_name, pair)
        save_if_asked(context.scene.thurston, job, self.report, pair)


CLASSES = (THURSTON_OT_render_view, THURSTON_OT_preview, THURSTON_OT_bake_panorama)
