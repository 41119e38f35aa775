"""Render on Cluster: the saved .blend sent to a Ray cluster by `thurston render-blend --cluster`
in a child process of the user's thurston install (Ray is never imported into Blender), its
progress line in the status bar, Esc stopping it as Ctrl-C does (the frames finished are kept for
the next run), and the last frame loaded into an image when it is done."""

from __future__ import annotations

import signal
import subprocess
import threading

import bpy

from ..blender import export, farm_command, results


class THURSTON_OT_farm_render(bpy.types.Operator):
    bl_idname = "thurston.farm_render"
    bl_label = "Render on Cluster"
    bl_description = (
        "Render the saved .blend file's frame (or animation) on a Ray cluster with the thurston "
        "command's render-blend --cluster, into the output folder, and load the result"
    )
    bl_options = {"REGISTER"}

    animation: bpy.props.BoolProperty(name="Animation", default=False)

    _process = None
    _lines: list[str]
    _timer = None

    def execute(self, context):
        try:
            argv, self._last = farm_command.command(context.scene, self.animation)
        except export.ExportError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self._lines = []
        try:
            self._process = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        except OSError as exc:
            self.report({"ERROR"}, f"cannot start {argv[0]!r}: {exc.strerror or exc}")
            return {"CANCELLED"}
        reader = threading.Thread(target=self._read, daemon=True)
        reader.start()
        if bpy.app.background:
            self._process.wait()
            reader.join()
            return self._conclude(context)
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.2, window=context.window)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def _read(self):
        for line in self._process.stdout:
            self._lines.append(line.rstrip())

    def modal(self, context, event):
        if event.type == "ESC":
            self._process.send_signal(signal.SIGINT)  # as Ctrl-C: every task cancelled, finished frames kept
            return {"RUNNING_MODAL"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        progress = next((line for line in reversed(self._lines) if line.startswith("farm:")), "farm: starting")
        context.workspace.status_text_set(f"Thurston {progress} (Esc to stop)")
        if self._process.poll() is None:
            return {"RUNNING_MODAL"}
        context.window_manager.event_timer_remove(self._timer)
        context.workspace.status_text_set(None)
        return self._conclude(context)

    def _conclude(self, context):
        if self._process.returncode in (130, -2):  # stopped (Esc): SIGINT, as Ctrl-C
            self.report(
                {"WARNING"}, "Render on Cluster stopped: the frames finished are kept, run it again for the rest"
            )
            return {"CANCELLED"}
        if self._process.returncode != 0:
            said = [line.removeprefix("thurston: error: ") for line in self._lines if line.startswith("thurston:")]
            self.report({"ERROR"}, f"Render on Cluster: {said[-1] if said else 'the thurston command failed'}")
            return {"CANCELLED"}
        image = bpy.data.images.load(str(self._last), check_existing=True)
        image.reload()
        results.show_image(context, image)
        self.report({"INFO"}, f"Render on Cluster: {self._last}")
        return {"FINISHED"}


CLASSES = (THURSTON_OT_farm_render,)
