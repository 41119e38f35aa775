"""The panel in the render properties, and a presets menu for its settings."""
import bpy

from .. import guide, properties



class THURSTON_MT_presets(bpy.types.Menu):
    bl_label = "Thurston Presets"
    preset_subdir = properties.PRESET_SUBDIR
    preset_operator = "script.execute_preset"
    draw = bpy.types.Menu.draw_preset


class THURSTON_PT_render(bpy.types.Panel):
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
        col = layout.column()
        col.prop(s, "space")
        if s.space_id == properties.FILE:
            col.prop(s, "space_file")
        elif properties.space_missing(s):
            col.label(text=f"No preset {s.space_id!r}: its file is gone; choose another space", icon="ERROR")
        col.prop(s, "scale")
        col.operator("thurston.domain_guide", icon="MESH_ICOSPHERE")
        if guide.camera_outside(context.scene):
            box = layout.box()
            box.label(text="The camera is outside the domain", icon="ERROR")
            box.operator("thurston.camera_inside", icon="CAMERA_DATA")

        col = layout.column(heading="Accuracy")
        col.prop(s, "quality")
        col.prop(s, "tolerance")
        col.prop(s, "max_distance")
        col.prop(s, "max_crossings")
        col = layout.column()
        col.prop(s, "shading")
        col.prop(s, "fog")
        col.prop(s, "passes")
        col.prop(s, "save_path")
        col.prop(s, "overwrite")
        col.prop(s, "panorama_width")

        row = layout.row(align=True)
        row.operator("thurston.render_view", icon="RENDER_STILL")
        row.operator("thurston.bake_panorama", icon="WORLD")
        row.operator("thurston.preview", icon="HIDE_OFF")

        st = s.stats
        if st.valid:
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


CLASSES = (THURSTON_MT_presets, THURSTON_PT_render)
