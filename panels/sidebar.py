"""3D Viewport > Sidebar > Cliff Terrain: photo, parameters, Build, and (later) Render and Evaluate."""

import os

import bpy

BUILD_OPERATOR = "cliff_terrain.build_relief"
# Operators the render module adds (their own poll greys them out without a relief object).
RENDER_OPERATORS = (
    ("CLIFF_TERRAIN_OT_render_views", "cliff_terrain.render_views", "RENDER_STILL"),
    ("CLIFF_TERRAIN_OT_evaluate", "cliff_terrain.evaluate", "GRAPH"),
)


def relief_info(obj):
    """The build record of a relief object (its ``cliff_terrain`` custom property), or None."""
    if obj is None:
        return None
    return obj.get("cliff_terrain")


class CLIFF_TERRAIN_PT_sidebar(bpy.types.Panel):
    bl_idname = "CLIFF_TERRAIN_PT_sidebar"
    bl_label = "Cliff Terrain"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Cliff Terrain"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        settings = context.scene.cliff_terrain

        col = layout.column()
        col.prop(settings, "filepath")
        col.separator()
        col.prop(settings, "segmentation")
        col.prop(settings, "profile")
        col.prop(settings, "max_size")
        col.prop(settings, "exaggeration")
        col.prop(settings, "gsd")
        col.prop(settings, "two_sided")

        row = layout.row()
        row.scale_y = 1.4
        # Greyed out until the photo exists; the operator then takes its parameters from here.
        row.enabled = bool(settings.filepath) and os.path.isfile(bpy.path.abspath(settings.filepath))
        row.operator(BUILD_OPERATOR, text="Build Relief", icon="MESH_GRID")

        info = relief_info(context.active_object)
        if info is not None:
            box = layout.box()
            box.label(text=f"{context.active_object.name}", icon="OBJECT_DATA")
            units = "m" if info.get("units") == "m" else "normalised units"
            box.label(
                text=f"Grid {info.get('grid_cols')} x {info.get('grid_rows')}, {info.get('regions')} regions"
            )
            box.label(text=f"Max height {info.get('max_height', 0.0):.3g} {info.get('units')} ({units})")

        # ---- Render views and Evaluate (drawn once the render module registers its operators) ----
        layout.separator()
        col = layout.column()
        col.prop(settings, "output_dir")
        for class_name, idname, icon in RENDER_OPERATORS:
            if hasattr(bpy.types, class_name):
                col.operator(idname, icon=icon)
        if settings.psnr or settings.ssim:
            box = layout.box()
            box.label(text=f"PSNR {settings.psnr:.2f} dB", icon="INFO")
            box.label(text=f"SSIM {settings.ssim:.3f}")


CLASSES = (CLIFF_TERRAIN_PT_sidebar,)


# Registered in order, unregistered in reverse (Blender's own helper for exactly this).
register, unregister = bpy.utils.register_classes_factory(CLASSES)
