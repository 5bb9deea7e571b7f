"""A new relief framed in the window's 3D views, as Blender's Add menu would and then some."""

import bpy


def show_relief(context, obj):
    """Show a new relief in every 3D view of the window: each view frames it (View Selected, then
    fitted into the part of the view that the toolbar and sidebar do not cover), and Solid shading
    shows the photo (Texture colour) so the user does not meet a grey slab. Nothing to do without a
    window (background mode, scripts).
    """
    screen = context.screen
    if bpy.app.background or screen is None:
        return
    view_prefs = context.preferences.view
    smooth = view_prefs.smooth_view
    view_prefs.smooth_view = 0  # the view settles now, so it can be refined below
    try:
        for area in screen.areas:
            if area.type != "VIEW_3D":
                continue
            space = area.spaces.active
            if space.shading.type == "SOLID":
                space.shading.color_type = "TEXTURE"
            regions = {region.type: region for region in area.regions}
            region = regions.get("WINDOW")
            if region is None or space.region_3d is None:
                continue
            rv3d = space.region_3d
            distance = rv3d.view_distance
            # World units per pixel at the view's centre, from the matrices of the last redraw.
            per_pixel = _world_per_pixel(region, rv3d)
            with context.temp_override(area=area, region=region, space_data=space):
                bpy.ops.view3d.view_selected(use_all_regions=False)
            if context.preferences.system.use_region_overlap and per_pixel:
                _fit_visible_part(space, regions, region, rv3d, per_pixel * rv3d.view_distance / distance)
    finally:
        view_prefs.smooth_view = smooth


def _world_per_pixel(region, rv3d):
    from bpy_extras.view3d_utils import region_2d_to_location_3d

    centre = (region.width / 2, region.height / 2)
    a = region_2d_to_location_3d(region, rv3d, centre, rv3d.view_location)
    b = region_2d_to_location_3d(region, rv3d, (centre[0] + 100, centre[1]), rv3d.view_location)
    return (b - a).length / 100 if a is not None and b is not None else None


def _fit_visible_part(space, regions, region, rv3d, per_pixel):
    """Zoom out and pan so the framed relief sits in the view's uncovered middle: with region overlap,
    the toolbar and the sidebar are drawn over the 3D view's left and right edges."""
    from mathutils import Vector

    left = regions["TOOLS"].width if "TOOLS" in regions and space.show_region_toolbar else 0
    right = regions["UI"].width if "UI" in regions and space.show_region_ui else 0
    visible = region.width - left - right
    if visible < 0.3 * region.width:
        return
    factor = region.width / visible
    rv3d.view_distance *= factor
    # Move the view right, so the relief moves left into the middle of the uncovered part.
    shift = 0.5 * (right - left) * per_pixel * factor
    rv3d.view_location += (rv3d.view_rotation @ Vector((1.0, 0.0, 0.0))) * shift
