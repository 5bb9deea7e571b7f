"""Plot polygons from a trial layout: columns x rows of plots, placed on the map, numbered, joined to
the field book.

A layout is laid out in its own frame: ``u`` runs across the columns (a plot's *width*), ``v`` along
them (its *length*); column ``c`` spans ``u`` in ``[column_offsets[c], column_offsets[c] + width]``,
row ``r`` spans ``v`` in ``[row_offsets[r], row_offsets[r] + length]``, in metres. A placement maps
that frame onto the map: four corners (the grid's outer corners, as a breeder clicks them; the plots
follow the quadrilateral bilinearly), or an origin and an angle (a rigid grid; the angle is the
direction of ``u``, counter-clockwise from the map's x axis, and ``v`` points 90 degrees further).
:mod:`cliff_terrain.measure.plot_fit` snaps a placement to the crop.

The result is a :class:`cliff_terrain.io.vector.plot_polygons.PlotSet` whose attributes are ``plot`` (the plot number),
``column`` and ``row`` (1-based, counted from the `start` corner) and the field book's columns: the
plot tables read it unchanged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._validate import check_choice, check_float, check_int
from ..errors import CliffTerrainError
from ..io.vector.plot_polygons import PlotSet

NUMBERINGS = ("rows", "columns", "serpentine")
STARTS = ("top-left", "top-right", "bottom-left", "bottom-right")


@dataclass(frozen=True)
class Layout:
    """Plot sizes and the offsets of the columns and rows in the grid's own frame (metres)."""

    columns: int
    rows: int
    width: float
    length: float
    column_offsets: np.ndarray
    row_offsets: np.ndarray

    @property
    def extent(self):
        """(across, along): the grid's size from its first plot's outer edge to its last one's."""
        return float(self.column_offsets[-1] + self.width), float(self.row_offsets[-1] + self.length)


@dataclass(frozen=True)
class Placement:
    """Where the grid's frame lies on the map: the map (x, y) of its corners (u, v) =
    (0, 0), (U, 0), (U, V), (0, V) with (U, V) the layout's extent, in that order."""

    corners: np.ndarray

    @classmethod
    def rigid(cls, origin, angle_deg, extent):
        """The rectangle of `extent` (U, V) with its (0, 0) corner at `origin`, u at `angle_deg`."""
        u_axis, v_axis = axes(angle_deg)
        o = np.asarray(origin, dtype=np.float64)
        across, along = extent
        return cls(
            np.array([o, o + across * u_axis, o + across * u_axis + along * v_axis, o + along * v_axis])
        )

    @property
    def angle(self):
        """Direction of u (degrees counter-clockwise from the map's x axis), from the corners."""
        c = self.corners
        u = (c[1] - c[0]) + (c[2] - c[3])
        return math.degrees(math.atan2(u[1], u[0]))

    def to_map(self, s, t):
        """Map (x, y) of normalised grid coordinates `s` (across, 0-1) and `t` (along, 0-1)."""
        s, t = np.asarray(s, dtype=np.float64)[..., None], np.asarray(t, dtype=np.float64)[..., None]
        c = self.corners
        return (1 - s) * (1 - t) * c[0] + s * (1 - t) * c[1] + s * t * c[2] + (1 - s) * t * c[3]


def axes(angle_deg):
    """Unit vectors u (at `angle_deg` from the map's x axis) and v (90 degrees counter-clockwise)."""
    a = math.radians(angle_deg)
    return np.array([math.cos(a), math.sin(a)]), np.array([-math.sin(a), math.cos(a)])


def grid_layout(columns, rows, *, plot_size, pitch=None, alleys=None, extent=None):
    """The offsets of a grid's columns and rows from its size and spacing.

    Parameters
    ----------
    columns, rows : int
        Plots across and along the columns (>= 1).
    plot_size : (float, float)
        (width, length) of a plot in metres: width across the columns, length along them.
    pitch : (float, float), optional
        Distance from one column (row) to the next, start to start.
    alleys : (float or sequence, float or sequence), optional
        The gaps between columns and between rows: one value, or one per gap for uneven alleys.
    extent : (float, float), optional
        The grid's size (across, along) from first to last plot's outer edge; spreads the columns
        (rows) evenly over it when neither `pitch` nor `alleys` is given (the placement's corners).

    Without any of the three the plots touch.

    Returns
    -------
    Layout

    Examples
    --------
    >>> layout = grid_layout(3, 2, plot_size=(1.0, 4.0), alleys=([0.5, 1.0], 2.0))
    >>> layout.column_offsets.tolist(), layout.row_offsets.tolist(), layout.extent
    ([0.0, 1.5, 3.5], [0.0, 6.0], (4.5, 10.0))
    """
    columns = check_int("columns", columns, minimum=1)
    rows = check_int("rows", rows, minimum=1)
    width, length = _pair("plot_size", plot_size)
    width = check_float("plot width", width, minimum=0.0, strict_minimum=True)
    length = check_float("plot length", length, minimum=0.0, strict_minimum=True)
    if pitch is not None and alleys is not None:
        raise CliffTerrainError(f"give `pitch` or `alleys`, not both (got {pitch} and {alleys})")
    offsets = []
    for axis, n, size in ((0, columns, width), (1, rows, length)):
        name = "column" if axis == 0 else "row"
        if pitch is not None:
            step = check_float(f"{name} pitch", _pair("pitch", pitch)[axis], minimum=size)
            gaps = np.full(n - 1, step - size)
        elif alleys is not None:
            gaps = _gaps(_pair("alleys", alleys)[axis], n - 1, name)
        elif extent is not None:
            span = float(_pair("extent", extent)[axis])
            # Clicked corners are off by a little: plots that touch may seem to overlap by that much.
            if span < n * size - 0.5 * size:
                raise CliffTerrainError(
                    f"{n} {name}s of {size:g} m do not fit in the {span:.3g} m the corners span; "
                    "check --grid and --plot-size"
                )
            gaps = np.full(n - 1, max(0.0, (span - n * size) / (n - 1)) if n > 1 else 0.0)
        else:
            gaps = np.zeros(n - 1)
        offsets.append(np.concatenate([[0.0], np.cumsum(size + gaps)]))
    return Layout(columns, rows, width, length, offsets[0], offsets[1])


def _pair(name, value):
    if isinstance(value, str | bytes) or not hasattr(value, "__len__") or len(value) != 2:
        raise CliffTerrainError(f"`{name}` must be a pair (across, along), got {value!r}")
    return value[0], value[1]


def _gaps(value, n, name):
    values = np.atleast_1d(np.asarray(value, dtype=np.float64))
    if values.size == 1:
        values = np.full(n, float(values[0]))
    if values.size != n:
        raise CliffTerrainError(f"{name} alleys: {n} gaps between the {name}s, got {values.size} values")
    if not np.all(np.isfinite(values)) or (values < 0).any():
        raise CliffTerrainError(f"{name} alleys must be finite and >= 0, got {values.tolist()}")
    return values


def placement_from_corners(corners, extent=None):
    """A placement from four map points in any order: the grid's outer corners.

    The corners are ordered around their centre; the first side is taken as the u (across)
    direction when its length fits the layout's `extent` ratio better than the other side's.

    Raises
    ------
    CliffTerrainError
        Not four distinct points forming a convex quadrilateral.
    """
    points = np.asarray(corners, dtype=np.float64)
    if points.shape != (4, 2) or not np.all(np.isfinite(points)):
        raise CliffTerrainError(f"`corners` must be four map points (x, y), got {np.shape(corners)}")
    centre = points.mean(axis=0)
    order = np.argsort(np.arctan2(points[:, 1] - centre[1], points[:, 0] - centre[0]))
    quad = points[order]  # counter-clockwise
    cross = []
    for i in range(4):
        a, b, c = quad[i], quad[(i + 1) % 4], quad[(i + 2) % 4]
        cross.append((b[0] - a[0]) * (c[1] - b[1]) - (b[1] - a[1]) * (c[0] - b[0]))
    sides = np.hypot(*np.diff(np.vstack([quad, quad[:1]]), axis=0).T)
    if min(cross) <= 1e-9 * max(sides.max() ** 2, 1e-300) or sides.min() <= 1e-9 * sides.max():
        raise CliffTerrainError(
            f"`corners` {points.round(3).tolist()} do not form a convex quadrilateral (collinear, repeated, crossed or concave)"
        )
    if extent is not None:
        across, along = extent
        first, second = 0.5 * (sides[0] + sides[2]), 0.5 * (sides[1] + sides[3])
        # Start with the side whose length ratio matches the layout's (across / along).
        if abs(math.log(first / second) - math.log(across / along)) > abs(
            math.log(second / first) - math.log(across / along)
        ):
            quad = np.roll(quad, -1, axis=0)
    return Placement(quad)


def plot_polygons(layout, placement, *, buffer=(0.0, 0.0)):
    """Plot rings (5 map points, closed) in (row, column) order, each trimmed by `buffer` (across, along)."""
    across, along = layout.extent
    bu, bv = _pair("buffer", buffer)
    bu = check_float("buffer across", bu, minimum=0.0)
    bv = check_float("buffer along", bv, minimum=0.0)
    if 2 * bu >= layout.width or 2 * bv >= layout.length:
        raise CliffTerrainError(
            f"`buffer` ({bu:g}, {bv:g}) m trims the whole plot of {layout.width:g} x {layout.length:g} m"
        )
    rings = []
    for r in range(layout.rows):
        v0 = layout.row_offsets[r] + bv
        v1 = layout.row_offsets[r] + layout.length - bv
        for c in range(layout.columns):
            u0 = layout.column_offsets[c] + bu
            u1 = layout.column_offsets[c] + layout.width - bu
            s = np.array([u0, u1, u1, u0, u0]) / across
            t = np.array([v0, v0, v1, v1, v0]) / along
            rings.append(placement.to_map(s, t))
    return rings


def numbered(layout, placement, *, numbering="serpentine", start="top-left"):
    """Plot numbers, columns and rows (1-based, from the `start` corner) of the (row, column)-ordered plots.

    `start` names the corner of plot 1 as seen on the map, north up: "top" is the larger y,
    "left" the smaller x. ``"rows"`` numbers along each row first, ``"columns"`` along each column
    first, ``"serpentine"`` along the rows, turning back at each row's end.
    """
    check_choice("numbering", numbering, NUMBERINGS)
    check_choice("start", start, STARTS)
    top, left = start.split("-")
    want = np.array([-1.0 if left == "left" else 1.0, 1.0 if top == "top" else -1.0])
    centre = placement.to_map(0.5, 0.5)
    # The grid's corner farthest towards the wanted map corner holds plot 1.
    corners = {(fc, fr): placement.to_map(float(fc), float(fr)) for fc in (0, 1) for fr in (0, 1)}
    flip_c, flip_r = max(corners, key=lambda k: float(want @ (corners[k] - centre)))
    n_c, n_r = layout.columns, layout.rows
    out = []
    for r in range(n_r):
        for c in range(n_c):
            col = n_c - c if flip_c else c + 1
            row = n_r - r if flip_r else r + 1
            if numbering == "rows":
                number = (row - 1) * n_c + col
            elif numbering == "columns":
                number = (col - 1) * n_r + row
            else:
                number = (row - 1) * n_c + (col if row % 2 == 1 else n_c + 1 - col)
            out.append((number, col, row))
    return out


def plot_grid(
    columns,
    rows,
    *,
    plot_size,
    corners=None,
    origin=None,
    angle=0.0,
    pitch=None,
    alleys=None,
    numbering="serpentine",
    start="top-left",
    buffer=0.0,
    field_book=None,
    crs=None,
):
    """Plot polygons of a trial from its layout: columns x rows of plots, placed and numbered.

    Parameters
    ----------
    columns, rows : int
        Plots across and along the columns.
    plot_size : (float, float)
        (width, length) in metres: width across the columns, length along them.
    corners : (4, 2) array, optional
        The grid's four outer corners in map coordinates, in any order. Spreads the plots evenly
        between them unless `pitch` or `alleys` is given.
    origin : (float, float), optional
        Without corners: the map (x, y) of the grid's (u, v) = (0, 0) corner. One of the two is needed.
    angle : float, optional
        Without corners: the direction of u (across the columns), degrees counter-clockwise from
        the map's x axis. 0: columns run south-north.
    pitch, alleys : optional
        See :func:`grid_layout`.
    numbering : {"serpentine", "rows", "columns"}, optional
    start : {"top-left", "top-right", "bottom-left", "bottom-right"}, optional
        The corner of plot 1 on the map (north up).
    buffer : float or (float, float), optional
        Trimmed from each side of every plot (across, along), metres.
    field_book : list of dict, optional
        Rows joined to the plots by ``plot`` (plot number) or by ``column`` and ``row``; see
        :func:`cliff_terrain.io.vector.plot_files.read_field_book`.
    crs : int, optional
        EPSG code of the map coordinates.

    Returns
    -------
    PlotSet
        In plot-number order; attributes ``plot``, ``column``, ``row`` and the field book's.

    Examples
    --------
    >>> plots = plot_grid(2, 2, plot_size=(1.0, 3.0), origin=(100.0, 200.0), alleys=(0.5, 1.0),
    ...                   numbering="rows", start="bottom-left")
    >>> [(a["plot"], a["column"], a["row"]) for a in plots.attributes]
    [(1, 1, 1), (2, 2, 1), (3, 1, 2), (4, 2, 2)]
    >>> plots.polygons[1][0][:4].tolist()
    [[101.5, 200.0], [102.5, 200.0], [102.5, 203.0], [101.5, 203.0]]
    """
    layout, placement = place_grid(
        columns,
        rows,
        plot_size=plot_size,
        corners=corners,
        origin=origin,
        angle=angle,
        pitch=pitch,
        alleys=alleys,
    )
    return plots_from(
        layout, placement, numbering=numbering, start=start, buffer=buffer, field_book=field_book, crs=crs
    )


def place_grid(columns, rows, *, plot_size, corners=None, origin=None, angle=0.0, pitch=None, alleys=None):
    """``(Layout, Placement)`` of a grid; the parameters are :func:`plot_grid`'s.

    With corners and no spacing the plots spread evenly between the corners; with a spacing the
    corners only place and orient the grid, whose size is then the layout's.
    """
    if corners is None and origin is None:
        raise CliffTerrainError("place the grid: give `corners` (four map points) or `origin` and `angle`")
    if corners is not None and origin is not None:
        raise CliffTerrainError("give `corners` or `origin`, not both")
    if corners is not None:
        rough = grid_layout(columns, rows, plot_size=plot_size, pitch=pitch, alleys=alleys)
        placement = placement_from_corners(corners, rough.extent)
        c = placement.corners
        span = (0.5 * (np.hypot(*(c[1] - c[0])) + np.hypot(*(c[2] - c[3]))),
                0.5 * (np.hypot(*(c[3] - c[0])) + np.hypot(*(c[2] - c[1]))))  # fmt: skip
        layout = grid_layout(columns, rows, plot_size=plot_size, pitch=pitch, alleys=alleys, extent=span)
        if pitch is not None or alleys is not None:
            # The spacing is given: the corners place and orient the grid, its size is the layout's.
            placement = Placement.rigid(c[0], placement.angle, layout.extent)
    else:
        origin = np.asarray(origin, dtype=np.float64)
        if origin.shape != (2,) or not np.all(np.isfinite(origin)):
            raise CliffTerrainError(f"`origin` must be a map point (x, y), got {origin.tolist()}")
        angle = check_float("angle", angle)
        layout = grid_layout(columns, rows, plot_size=plot_size, pitch=pitch, alleys=alleys)
        placement = Placement.rigid(origin, angle, layout.extent)
    return layout, placement


def plots_from(
    layout, placement, *, numbering="serpentine", start="top-left", buffer=0.0, field_book=None, crs=None
):
    """The numbered :class:`PlotSet` of a layout at a placement (see :func:`plot_grid`)."""
    if np.ndim(buffer) == 0:
        buffer = (buffer, buffer)
    rings = plot_polygons(layout, placement, buffer=buffer)
    ids = numbered(layout, placement, numbering=numbering, start=start)
    attributes = [{"plot": n, "column": c, "row": r} for n, c, r in ids]
    fields = ("plot", "column", "row")
    if field_book is not None:
        from ..io.vector.plot_files import join_field_book

        extra, book_fields = join_field_book(attributes, field_book)
        attributes = [{**a, **e} for a, e in zip(attributes, extra, strict=True)]
        fields = fields + tuple(book_fields)
    order = np.argsort([a["plot"] for a in attributes], kind="stable")
    return PlotSet([[rings[i]] for i in order], [attributes[i] for i in order], fields, crs, "plot grid")


def parse_pair(text, name, *, count=2):
    """``"AxB"`` or ``"A,B"`` as floats (the command line's sizes and points)."""
    if isinstance(text, str):
        text = text.strip()  # the command line's negative coordinates come with a leading space
    parts = text.replace("x", ",").replace("X", ",").split(",") if isinstance(text, str) else text
    try:
        values = [float(p) for p in parts]
    except (TypeError, ValueError):
        raise CliffTerrainError(f"`{name}` must be {count} numbers like 1.5x6, got {text!r}") from None
    if len(values) != count or not all(math.isfinite(v) for v in values):
        raise CliffTerrainError(f"`{name}` must be {count} numbers like 1.5x6, got {text!r}")
    return values
