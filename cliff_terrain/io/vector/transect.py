"""Transects (``--transect``): a strip across the field in the photo's pixels, parsed and checked
against the photo's size.

A band of photo rows, or a line across the field with a width; the Blender side turns them into
a side camera (``scene/rig.py``), the figures outline them on the top view.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from ...errors import CliffTerrainError


@dataclass(frozen=True)
class Transect:
    """A strip across the field, in the photo's pixels: from `start` to `end` ((row, col) each, pixel
    corners, so (0, 0) is the photo's top-left corner) and `width` pixels wide, centred on the line.

    The side view of a transect looks at the strip square to its line, from its right-hand side
    (a transect drawn left to right is seen from the south, as the full side view).
    """

    start: tuple
    end: tuple
    width: float
    text: str = ""

    @property
    def length(self):
        return math.hypot(self.end[0] - self.start[0], self.end[1] - self.start[1])

    def corners(self):
        """The strip's four corners (row, col), in order around it."""
        (r0, c0), (r1, c1) = self.start, self.end
        dr, dc = (r1 - r0) / self.length, (c1 - c0) / self.length
        # Unit normal (row, col) to the line; half the width either side.
        nr, nc = -dc * self.width / 2, dr * self.width / 2
        return [(r0 + nr, c0 + nc), (r1 + nr, c1 + nc), (r1 - nr, c1 - nc), (r0 - nr, c0 - nc)]


_NUMBER = r"\s*([-+]?\d+(?:\.\d*)?)\s*"


def parse_transect(text, *, shape, name="transect"):
    """A transect from its text, checked against a photo of `shape` (rows, cols).

    Two forms, in the photo's pixels (rows from the top, columns from the left):

    * ``rows=R0:R1`` -- the band of rows R0 to R1 across the whole field (seen from the south);
    * ``line=R0,C0,R1,C1[,WIDTH]`` -- the line from (R0, C0) to (R1, C1), WIDTH pixels wide
      (default 2 % of the photo's longer side).

    Parameters
    ----------
    text : str
    shape : tuple of int
        (rows, cols) of the photo.
    name : str, optional
        The setting's name in error messages (``--transect`` on the command line).

    Returns
    -------
    Transect

    Examples
    --------
    >>> parse_transect("rows=100:140", shape=(400, 600))
    Transect(start=(120.0, 0.0), end=(120.0, 600.0), width=40.0, text='rows=100:140')
    >>> parse_transect("line=0,0,400,600,10", shape=(400, 600)).width
    10.0
    """
    rows, cols = int(shape[0]), int(shape[1])
    source = str(text).strip()
    kind, _, values = source.partition("=")
    kind = kind.strip().lower()
    if kind == "rows":
        match = re.fullmatch(_NUMBER + ":" + _NUMBER, values)
        if match is None:
            raise CliffTerrainError(
                f"`{name}` must be rows=R0:R1 or line=R0,C0,R1,C1[,WIDTH], got {source!r}"
            )
        r0, r1 = sorted(float(v) for v in match.groups())
        _inside(name, source, [(r0, 0.0), (r1, 0.0)], rows, cols)
        if r1 - r0 <= 0:
            raise CliffTerrainError(f"`{name}` must span at least one row, got {source!r}")
        middle = (r0 + r1) / 2
        return Transect((middle, 0.0), (middle, float(cols)), r1 - r0, source)
    if kind == "line":
        parts = values.split(",")
        if len(parts) not in (4, 5) or not all(re.fullmatch(_NUMBER, p) for p in parts):
            raise CliffTerrainError(
                f"`{name}` must be rows=R0:R1 or line=R0,C0,R1,C1[,WIDTH], got {source!r}"
            )
        r0, c0, r1, c1 = (float(p) for p in parts[:4])
        width = float(parts[4]) if len(parts) == 5 else max(1.0, round(0.02 * max(rows, cols)))
        if width <= 0:
            raise CliffTerrainError(f"`{name}` WIDTH must be > 0, got {source!r}")
        _inside(name, source, [(r0, c0), (r1, c1)], rows, cols)
        if math.hypot(r1 - r0, c1 - c0) < 1.0:
            raise CliffTerrainError(f"`{name}` must be at least one pixel long, got {source!r}")
        return Transect((r0, c0), (r1, c1), width, source)
    raise CliffTerrainError(f"`{name}` must be rows=R0:R1 or line=R0,C0,R1,C1[,WIDTH], got {source!r}")


def _inside(name, source, points, rows, cols):
    for r, c in points:
        if not (0.0 <= r <= rows and 0.0 <= c <= cols):
            raise CliffTerrainError(
                f"`{name}` point (row {r:g}, column {c:g}) is outside the {cols} x {rows} photo "
                f"(rows 0 to {rows}, columns 0 to {cols}), got {source!r}"
            )
