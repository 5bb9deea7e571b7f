"""How an operator reports a failure: the core's own message for bad input, the exception's name for a bug."""

import traceback


def report_failure(operator, exc):
    """Report `exc` on `operator` as an ERROR and return CANCELLED.

    A :class:`CliffTerrainError` (a bad photo, file or setting) is reported with its message; any
    other exception is a bug: its traceback goes to the console and the report names it (Blender
    turns the ERROR report into a RuntimeError for scripts, so nothing fails silently).
    """
    from ..cliff_terrain.errors import CliffTerrainError

    if isinstance(exc, CliffTerrainError):
        operator.report({"ERROR"}, str(exc))
    else:
        traceback.print_exc()
        operator.report({"ERROR"}, f"Cliff Terrain failed: {type(exc).__name__}: {exc}")
    return {"CANCELLED"}
