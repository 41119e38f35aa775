"""The add-on's panels: the settings in Render Properties (under the Thurston engine only), its film
and view layer passes, and the operators in the 3D viewport's sidebar (under any engine)."""

import bpy

from ..blender import domain_guide, export, properties

ENGINE = "THURSTON"


class THURSTON_MT_presets(bpy.types.Menu):
    bl_label = "Thurston Presets"
    preset_subdir = properties.PRESET_SUBDIR
    preset_operator = "script.execute_preset"
    draw = bpy.types.Menu.draw_preset


class _UnderThurston:
    @classmethod
    def poll(cls, context):
        return context.engine == ENGINE


def draw_space(layout, context):
    """The space, its scale and the fixes that keep the camera and the scene in the domain."""
    s = context.scene.thurston
    col = layout.column()
    col.prop(s, "space")
    if s.space_id == export.FILE:
        col.prop(s, "space_file")
    elif s.space_id == export.NAMED:
        col.prop(s, "space_name")
    elif properties.space_missing(s):
        col.label(text=f"No preset {s.space_id!r}: its file is gone; choose another space", icon="ERROR")
    row = col.row(align=True)
    row.prop(s, "scale")
    row.operator("thurston.fit_scale", text="", icon="FULLSCREEN_ENTER")
    col.operator("thurston.domain_guide", icon="MESH_ICOSPHERE")
    if domain_guide.camera_outside(context.scene):
        box = layout.box()
        if export.camera_animated(context.scene.camera):  # its animation would put it back
            box.label(text="The camera is outside the domain (animated: the render is the same)", icon="INFO")
        else:
            box.label(text="The camera is outside the domain", icon="ERROR")
            box.operator("thurston.camera_inside", icon="CAMERA_DATA")


def draw_renders(layout):
    row = layout.row(align=True)
    row.operator("thurston.render_view", icon="RENDER_STILL")
    row.operator("thurston.bake_panorama", icon="WORLD")
    row.operator("thurston.preview", icon="HIDE_OFF")


class THURSTON_PT_render(_UnderThurston, bpy.types.Panel):
    bl_label = "Thurston"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "render"

    def draw_header_preset(self, context):
        row = self.layout.row(align=True)
        row.menu(THURSTON_MT_presets.__name__, text=THURSTON_MT_presets.bl_label)
        row.operator("thurston.add_preset", text="", icon="ADD")
        row.operator("thurston.add_preset", text="", icon="REMOVE").remove_active = True

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        s = context.scene.thurston
        draw_space(layout, context)
        col = layout.column(heading="Accuracy")
        col.prop(s, "quality")
        col.prop(s, "use_denoising")
        col.prop(s, "tolerance")
        col.prop(s, "max_distance")
        col.prop(s, "max_crossings")
        col = layout.column()
        col.prop(s, "shading")
        col.prop(s, "fog")
        col.prop(s, "light_reach")
        col.prop(s, "light_samples")
        col.prop(s, "light_paths")
        col.prop(s, "light_map")
        col.prop(s, "bounces")
        col.prop(s, "threads")
        col.prop(s, "passes")
        col.prop(s, "save_path")
        col.prop(s, "overwrite")
        col.prop(s, "panorama_width")
        col.prop(s, "panorama_stereo")
        draw_renders(layout)
        col = layout.column(heading="Cluster")
        col.prop(s, "farm_address")
        col.prop(s, "farm_command")
        row = col.row(align=True)
        row.operator("thurston.farm_render", icon="NETWORK_DRIVE").animation = False
        row.operator("thurston.farm_render", text="Animation on Cluster", icon="RENDER_ANIMATION").animation = True
        draw_last_render(layout, s.stats)


def draw_last_render(layout, st):
    if not st.valid:
        return
    box = layout.box()
    box.label(text="Last render")
    grid = box.grid_flow(columns=2, even_columns=True)
    grid.label(text=f"Time: {st.seconds:.2f} s")
    grid.label(text=f"Rays: {st.rays:,}")
    grid.label(text=f"Crossings/ray: {st.crossings_per_ray:.2f}")
    grid.label(text=f"Chords/ray: {st.chords_per_ray:.2f}")
    grid.label(text=f"Pixel footprint: {st.footprint:.2e}")
    box.label(text=f"Accuracy: {st.bound}")
    grid = box.grid_flow(columns=2, even_columns=True)
    grid.label(text=f"Measured error: {st.measured_error:.1e}")
    grid.label(text=f"Geodesic error: {st.geodesic_error:.1e}")
    grid.label(text="Noise: one sample, not estimated" if st.noise < 0 else f"Noise: {st.noise:.1e}")
    grid.label(text=f"Samples/pixel: mean {st.samples_mean:.2f}, max {st.samples_max}")
    if st.time_limit_reached:
        box.label(text="Time limit reached", icon="TIME")
    for note in st.notes:
        row = box.row()
        row.label(text=note.message, icon="ERROR")
        fix = export.FIXES.get(note.kind)
        if fix:
            row.operator(fix[0], text=fix[1])


class THURSTON_PT_sampling(_UnderThurston, bpy.types.Panel):
    """Sampling, as Cycles has it: the viewport's and the render's, each with adaptive sampling."""

    bl_label = "Sampling"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "render"

    def draw(self, context):
        pass


def draw_sampling(layout, s, prefix: str):
    """Cycles' layout of its Sampling sub-panels: Noise Threshold with its switch, then Max and Min
    Samples (Samples without adaptive sampling); prefix "preview_" for the viewport's."""
    layout.use_property_split = True
    layout.use_property_decorate = False
    adaptive = getattr(s, f"use_{prefix}adaptive_sampling")
    row = layout.column(align=True, heading="Noise Threshold").row(align=True)
    row.prop(s, f"use_{prefix}adaptive_sampling", text="")
    sub = row.row()
    sub.active = adaptive
    sub.prop(s, f"{prefix}adaptive_threshold", text="")
    col = layout.column(align=True)
    col.prop(s, f"{prefix}samples", text="Max Samples" if adaptive else "Samples")
    if adaptive:
        col.prop(s, f"{prefix}adaptive_min_samples", text="Min Samples")
    return col


class THURSTON_PT_sampling_viewport(_UnderThurston, bpy.types.Panel):
    bl_label = "Viewport"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "render"
    bl_parent_id = "THURSTON_PT_sampling"

    def draw(self, context):
        draw_sampling(self.layout, context.scene.thurston, "preview_")


class THURSTON_PT_sampling_render(_UnderThurston, bpy.types.Panel):
    bl_label = "Render"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "render"
    bl_parent_id = "THURSTON_PT_sampling"

    def draw(self, context):
        col = draw_sampling(self.layout, context.scene.thurston, "")
        col.prop(context.scene.thurston, "time_limit")


class THURSTON_PT_film(_UnderThurston, bpy.types.Panel):
    bl_label = "Film"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "render"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        self.layout.use_property_split = True
        self.layout.prop(context.scene.render, "film_transparent", text="Transparent")


class THURSTON_PT_layer_passes(_UnderThurston, bpy.types.Panel):
    """View Layer > Passes > Data: the passes the engine fills (Blender's and the add-on's)."""

    bl_label = "Data"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "view_layer"
    bl_parent_id = "VIEWLAYER_PT_layer_passes"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        col = layout.column(heading="Include", align=True)
        layer = context.view_layer
        for flag, p in {p.flag: p for p in export.BLENDER_PASSES}.items():  # a shared switch once
            col.prop(layer.thurston if p.addon_flag else layer, flag)


class THURSTON_PT_tools(bpy.types.Panel):
    """The add-on's operators, under any render engine: the 3D viewport's sidebar, tab Thurston."""

    bl_label = "Thurston"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Thurston"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        draw_space(layout, context)
        draw_renders(layout)
        draw_last_render(layout, context.scene.thurston.stats)


CLASSES = (
    THURSTON_MT_presets,
    THURSTON_PT_render,
    THURSTON_PT_sampling,
    THURSTON_PT_sampling_viewport,
    THURSTON_PT_sampling_render,
    THURSTON_PT_film,
    THURSTON_PT_layer_passes,
    THURSTON_PT_tools,
)
