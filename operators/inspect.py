"""Inspecting a relief: Probe Height (click a plant, read its height) and the viewport's colour bar.

The values come from :mod:`scene.probe` (the relief's own rasters); the colours from
:mod:`scene.colour_by` (the scene's ``color_by``).
"""

import bpy

from ..scene.probe import PROBE_KEY, forget_reliefs
from ..scene.record import is_relief
from .reports import report_failure

HINT = "Click the relief to read its height · Esc or right-click: done"


class CLIFF_TERRAIN_OT_probe_height(bpy.types.Operator):
    """Click the relief to read the height there, the ground, and the plant's p50/p90 and area.
    From a script: location=(x, y) in world coordinates"""

    bl_idname = "cliff_terrain.probe_height"
    bl_label = "Probe Height"
    bl_options = {"REGISTER"}

    location: bpy.props.FloatVectorProperty(
        name="Location",
        description="World (x, y) to read (a vertical line through it meets the relief)",
        size=2,
    )

    @classmethod
    def poll(cls, context):
        if not any(is_relief(obj) for obj in context.scene.objects):
            cls.poll_message_set("Build a relief first")
            return False
        return True

    # ---- scripted: location=(x, y) ----

    def execute(self, context):
        from ..scene.probe import hit_from_above

        candidates = [context.active_object] if is_relief(context.active_object) else []
        candidates += [obj for obj in context.visible_objects if is_relief(obj) and obj not in candidates]
        for obj in candidates:
            local = hit_from_above(obj, self.location)
            if local is not None:
                return self.read(obj, local)
        self.report({"ERROR"}, f"no relief under ({self.location[0]:.3f}, {self.location[1]:.3f})")
        return {"CANCELLED"}

    def read(self, obj, local):
        """Probe `obj` at a local point: store the values on it, report them; FINISHED or CANCELLED."""
        from ..scene.probe import probe, probe_lines

        try:
            values = probe(obj, local)
        except Exception as exc:
            return report_failure(self, exc)
        obj[PROBE_KEY] = values
        self.lines = probe_lines(values)
        self.report({"INFO"}, f"{obj.name}: " + "; ".join(self.lines))
        return {"FINISHED"}

    # ---- interactive: a modal tool ----

    def invoke(self, context, event):
        if context.area is None or context.area.type != "VIEW_3D":
            self.report({"ERROR"}, "Probe Height runs in a 3D Viewport")
            return {"CANCELLED"}
        context.window_manager.modal_handler_add(self)
        context.area.header_text_set(HINT)
        context.window.cursor_modal_set("EYEDROPPER")
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type in {"ESC", "RIGHTMOUSE"} and event.value == "PRESS":
            return self.finish(context)
        if event.type == "LEFTMOUSE" and event.value == "PRESS":
            found = self.under_mouse(context, event)
            if found is None:
                context.area.header_text_set(f"No relief there · {HINT}")
                return {"RUNNING_MODAL"}
            if self.read(*found) == {"FINISHED"}:
                text = " · ".join(self.lines)
                context.area.header_text_set(f"{text} · Esc: done")
                context.workspace.status_text_set(text)
                for area in context.screen.areas:
                    area.tag_redraw()  # the sidebar shows the values too
            return {"RUNNING_MODAL"}
        return {"PASS_THROUGH"}  # navigation and everything else as usual

    def under_mouse(self, context, event):
        """(relief, local point) under the mouse in the 3D view's main region, or None."""
        from bpy_extras.view3d_utils import region_2d_to_origin_3d, region_2d_to_vector_3d

        from ..scene.probe import hit_along

        region = next((r for r in context.area.regions if r.type == "WINDOW"), None)
        rv3d = context.area.spaces.active.region_3d
        if region is None or rv3d is None:
            return None
        point = (event.mouse_x - region.x, event.mouse_y - region.y)
        origin = region_2d_to_origin_3d(region, rv3d, point)
        direction = region_2d_to_vector_3d(region, rv3d, point)
        best = None
        for obj in context.visible_objects:
            if not is_relief(obj):
                continue
            local = hit_along(obj, origin, direction)
            if local is not None:
                distance = ((obj.matrix_world @ local) - origin).length
                if best is None or distance < best[0]:
                    best = (distance, obj, local)
        return None if best is None else best[1:]

    def finish(self, context):
        context.area.header_text_set(None)
        context.workspace.status_text_set(None)
        context.window.cursor_modal_restore()
        return {"FINISHED"}


# ---- The colour bar: the legend of Colour By, drawn over the 3D view ----

_BAR = {"handle": None}


def legend_of(context):
    """The legend of the first visible relief that shows colours (not its photo), or None."""
    from ..scene.colour_by import LEGEND_KEY

    for obj in context.visible_objects:
        legend = obj.get(LEGEND_KEY) if is_relief(obj) else None
        if legend:
            return legend
    return None


def tick_labels(legend):
    """Three labels (bottom, middle, top) of a legend, in cm under 1 m, m above, or px / %."""
    low, high, unit = float(legend["low"]), float(legend["high"]), legend["unit"]
    values = (low, 0.5 * (low + high), high)
    if unit == "m" and max(abs(low), abs(high)) < 1.0:
        return [f"{v * 100:.0f}" for v in values], "cm"
    if unit == "m":
        return [f"{v:.2f}" for v in values], "m"
    return [f"{v:.3g}" for v in values], unit


def colour_bar_box(area, region, preferences):
    """(x, y, width, height) of the colour bar in the view's region pixels (origin bottom-left): at the
    lower left, clear of the toolbar, tall enough to read and never more than half the view."""
    scale = preferences.system.ui_scale
    toolbar = next((r.width for r in area.regions if r.type == "TOOLS"), 0) if area else 0
    x0 = (toolbar if preferences.system.use_region_overlap else 0) + 16 * scale
    height = max(60 * scale, min(220 * scale, 0.45 * region.height))
    return x0, 40 * scale, 14 * scale, height


def draw_colour_bar():
    """POST_PIXEL: a vertical viridis bar at the view's lower left, labelled, sized by the UI scale."""
    context = bpy.context
    if context.region is None or context.region_data is None:
        return
    legend = legend_of(context)
    if legend is None:
        return
    import blf
    import gpu
    from gpu_extras.batch import batch_for_shader

    from ..cliff_terrain.figures.legends import HEIGHT_COLOURS

    scale = context.preferences.system.ui_scale
    x0, y0, width, height = colour_bar_box(context.area, context.region, context.preferences)
    positions, colours, indices = [], [], []
    for k, (t, r, g, b) in enumerate(HEIGHT_COLOURS):
        y = y0 + t * height
        positions += [(x0, y), (x0 + width, y)]
        colours += [(r, g, b, 1.0)] * 2
        if k:
            a = 2 * (k - 1)
            indices += [(a, a + 1, a + 3), (a, a + 3, a + 2)]
    shader = gpu.shader.from_builtin("SMOOTH_COLOR")
    batch = batch_for_shader(shader, "TRIS", {"pos": positions, "color": colours}, indices=indices)
    shader.bind()
    batch.draw(shader)
    labels, unit = tick_labels(legend)
    font = 0
    blf.size(font, 11 * scale)
    blf.enable(font, blf.SHADOW)
    blf.shadow(font, 3, 0.0, 0.0, 0.0, 1.0)
    blf.color(font, 1.0, 1.0, 1.0, 1.0)
    for label, t in zip(labels, (0.0, 0.5, 1.0), strict=True):
        _, text_height = blf.dimensions(font, label)
        blf.position(font, x0 + width + 6 * scale, y0 + t * height - text_height / 2, 0)
        blf.draw(font, label)
    blf.position(font, x0, y0 + height + 8 * scale, 0)
    blf.draw(font, f"{legend['title']} ({unit})")
    blf.disable(font, blf.SHADOW)


CLASSES = (CLIFF_TERRAIN_OT_probe_height,)


# The shortcut of Probe Height in the 3D Viewport (Preferences > Keymap lists it under Add-ons).
SHORTCUT = {"type": "P", "value": "PRESS", "ctrl": True, "alt": True}
_KEYMAPS = []


@bpy.app.handlers.persistent
def _forget_reliefs(*_args):
    """A newly opened file: the cached relief is another file's (about 1 GB for a large one)."""
    forget_reliefs()


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.app.handlers.load_post.append(_forget_reliefs)
    if not bpy.app.background:
        _BAR["handle"] = bpy.types.SpaceView3D.draw_handler_add(draw_colour_bar, (), "WINDOW", "POST_PIXEL")
    keyconfig = bpy.context.window_manager.keyconfigs.addon  # None in background mode
    if keyconfig is not None:
        keymap = keyconfig.keymaps.new(name="3D View", space_type="VIEW_3D")
        _KEYMAPS.append(
            (keymap, keymap.keymap_items.new(CLIFF_TERRAIN_OT_probe_height.bl_idname, **SHORTCUT))
        )


def unregister():
    for keymap, item in reversed(_KEYMAPS):
        keymap.keymap_items.remove(item)
    _KEYMAPS.clear()
    if _BAR["handle"] is not None:
        bpy.types.SpaceView3D.draw_handler_remove(_BAR["handle"], "WINDOW")
        _BAR["handle"] = None
    if _forget_reliefs in bpy.app.handlers.load_post:
        bpy.app.handlers.load_post.remove(_forget_reliefs)
    forget_reliefs()
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
