"""How an operator reports a failure: the core's own message for bad input, the exception's name for a bug."""

import re
import traceback

from ..scene.datablocks import remove_datablocks


def report_failure(operator, exc):
    """Report `exc` on `operator` as an ERROR and return CANCELLED.

    A :class:`CliffTerrainError` (a bad photo, file or setting) is reported with its message; any
    other exception is a bug: its traceback goes to the console and the report names it (Blender
    turns the ERROR report into a RuntimeError for scripts, so nothing fails silently).
    """
    from ..cliff_terrain.errors import CliffTerrainError

    if isinstance(exc, CliffTerrainError):
        operator.report({"ERROR"}, as_labelled(str(exc), operator))
    else:
        traceback.print_exc()
        operator.report({"ERROR"}, f"Cliff Terrain failed: {type(exc).__name__}: {exc}")
    return {"CANCELLED"}


def as_labelled(message, operator):
    """`message` with the core's parameter names, backticked (`height_source`), as the sidebar's
    labels of the properties that set them (Height Source): the user set a field, not a Python name
    (as the command line names its options)."""
    import bpy

    sources = [operator.bl_rna.properties]
    settings = getattr(getattr(bpy.context, "scene", None), "cliff_terrain", None)
    if settings is not None:
        sources.append(settings.bl_rna.properties)

    def label(match):
        for properties in sources:
            prop = properties.get(match.group(1))
            if prop is not None and prop.name:
                return prop.name
        return match.group(0)

    return re.sub(r"`(\w+)`", label, message)


def cancel_build(operator, exc, created):
    """Remove every datablock in `created` (what a failed build made), report `exc` as
    :func:`report_failure` does and return CANCELLED."""
    remove_datablocks(created)
    return report_failure(operator, exc)
