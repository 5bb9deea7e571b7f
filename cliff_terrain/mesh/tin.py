"""Triangulated irregular networks (TINs) of a height raster with a bounded vertical error.

A TIN here has its vertices at pixel *centres* of the raster: vertex ``k`` sits at
``(rows[k], cols[k])`` (integers) with height ``z[k]``, the raster's value there (or, for vertices
added on the borders of the blocks it is built in, the surface's, within the bound). Its triangles
cover the rectangle spanned by the outermost pixel centres. :func:`triangulate` builds one by greedy
insertion (Garland and Heckbert's algorithm, as implemented by ``pydelatin``), adding the pixel
of largest error until every pixel centre lies within `max_error` of the surface, in tiles of
about 128 pixels joined into one conforming TIN; :func:`cliff_terrain.mesh.tin_sample.tin_error` measures that error
independently, exactly, at every pixel centre.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .._validate import check_float
from ..errors import CliffTerrainError

# pydelatin compares errors in single precision: asking it for slightly less than `max_error` keeps
# the bound in double precision (measured errors stay below max_error; see tests/test_tin.py).
_FLOAT32_MARGIN = 1.0 - 1e-5


class Tin(NamedTuple):
    """A triangulated irregular network over a raster's pixel centres.

    Attributes
    ----------
    rows, cols : (n_vertices,) int32
        Pixel of each vertex.
    z : (n_vertices,) float32
        Height of each vertex: the raster's value at its pixel, except for vertices added on
        blocks' borders (see :func:`triangulate`), which take the height of the border edge they
        split, within the bound of the raster's.
    triangles : (n_triangles, 3) int32
        Vertex indices, counter-clockwise in (col, row) coordinates, i.e. clockwise when seen with
        the image's top row up (the mesh flips them into counter-clockwise seen from +z).
    shape : tuple of int
        (rows, cols) of the raster.
    """

    rows: np.ndarray
    cols: np.ndarray
    z: np.ndarray
    triangles: np.ndarray
    shape: tuple[int, int]


def triangulate(heights, *, max_error):
    """A TIN of `heights` whose vertical error at every pixel centre is at most `max_error`.

    Parameters
    ----------
    heights : (rows, cols) array
        Finite heights per pixel.
    max_error : float
        Largest vertical distance allowed between the TIN and a pixel's height, in the unit of
        `heights` (> 0).

    Returns
    -------
    Tin
        With at least the four corner pixels as vertices. Rasters of one row or one column are
        not triangulated: every pixel is a vertex and there are no triangles.

    Notes
    -----
    Greedy insertion runs in blocks of about 128 x 128 pixel centres, each with its own corners
    (4x faster on a 12 MP raster than in one piece, for up to 3 % more triangles). Two
    neighbouring blocks' borders are a pixel apart. Each position that has a vertex on one border
    gets one on the other too, on the border edge there and at its height (the block's surface
    does not change), and triangles zipped between the two borders, vertex for vertex, join the blocks:
    they hold no pixel centre of their own, so the bound still holds at every pixel centre, and
    none reaches further along the strip than a step of its borders. A flat raster stays two
    triangles.

    Examples
    --------
    >>> import numpy as np
    >>> tin = triangulate(np.zeros((50, 80)), max_error=0.1)
    >>> len(tin.z), len(tin.triangles)
    (4, 2)
    """
    heights = np.asarray(heights)
    if heights.ndim != 2 or min(heights.shape) < 1:
        raise CliffTerrainError(f"`heights` must be a non-empty 2-D array, got shape {heights.shape}")
    max_error = check_float("max_error", max_error, minimum=0.0, strict_minimum=True)
    heights = np.ascontiguousarray(heights, dtype=np.float32)
    if not np.isfinite(heights).all():
        raise CliffTerrainError("`heights` must be finite, got NaN or infinity")
    n_rows, n_cols = heights.shape
    if min(n_rows, n_cols) < 2:
        # A line of pixel centres has no area to triangulate: keep every pixel.
        rows, cols = np.indices(heights.shape, dtype=np.int32).reshape(2, -1)
        return Tin(rows, cols, heights.ravel().copy(), np.empty((0, 3), np.int32), (n_rows, n_cols))
    from .._deps import import_optional

    Delatin = import_optional("pydelatin", feature="the adaptive mesh").Delatin
    if heights.min() == heights.max():  # a flat field (no plant): its corners, not a block's each
        row_edges, col_edges = np.array([0, n_rows]), np.array([0, n_cols])
    else:
        row_edges, col_edges = _tile_edges(n_rows), _tile_edges(n_cols)
    tile_rows, tile_cols, tile_triangles = [], [], []
    n_vertices = 0
    for r0, r1 in zip(row_edges[:-1], row_edges[1:], strict=True):
        for c0, c1 in zip(col_edges[:-1], col_edges[1:], strict=True):
            rows, cols, triangles = _tile_tin(Delatin, heights[r0:r1, c0:c1], max_error * _FLOAT32_MARGIN)
            tile_rows.append(rows + r0)
            tile_cols.append(cols + c0)
            tile_triangles.append(triangles + n_vertices)
            n_vertices += len(rows)
    rows, cols = (np.concatenate(parts).astype(np.int32) for parts in (tile_rows, tile_cols))
    z = heights[rows, cols]
    rows, cols, z, triangles = _align_borders(
        rows, cols, z, np.concatenate(tile_triangles), row_edges, col_edges
    )
    triangles = np.concatenate([triangles, *_tile_joins(rows, cols, row_edges, col_edges)])
    # Counter-clockwise in (col, row): a positive cross product of the two edges.
    c0, c1, c2 = (cols[triangles[:, k]].astype(np.int64) for k in range(3))
    r0, r1, r2 = (rows[triangles[:, k]].astype(np.int64) for k in range(3))
    clockwise = (c1 - c0) * (r2 - r0) - (r1 - r0) * (c2 - c0) < 0
    triangles[clockwise] = triangles[clockwise][:, ::-1]
    return Tin(rows, cols, z, triangles, (n_rows, n_cols))


# Greedy insertion costs more per point on a large raster than on a small one: in tiles of about
# 128 pixels it runs 4x faster on a 12 MP relief (1.44 -> 0.36 s) and 1.3x on a 1 MP one, for
# up to 3 % more triangles with the borders matched (bench/bench_adaptive_mesh.py). Tiles are
# blocks of pixel centres, joined by strips a pixel wide (see _tile_joins).
_TILE = 128


def _tile_edges(n):
    """Starts of about-_TILE-long blocks of range(n), and n: each block at least 2 long (n >= 2)."""
    blocks = max(1, round(n / _TILE))
    return np.linspace(0, n, blocks + 1).round().astype(np.int64)


def _tile_tin(Delatin, heights, max_error):
    """One tile's TIN: (rows, cols, triangles) in the tile's pixels, its 4 corners among the vertices."""
    n_rows, n_cols = heights.shape
    if heights.min() == heights.max():  # flat (bare soil): its corners
        rows = np.array([0, 0, n_rows - 1, n_rows - 1], np.int32)
        cols = np.array([0, n_cols - 1, 0, n_cols - 1], np.int32)
        return rows, cols, np.array([[0, 2, 1], [1, 2, 3]], np.int32)
    tin = Delatin(np.ascontiguousarray(heights), height=n_rows, width=n_cols, max_error=max_error)
    xy = np.asarray(tin.vertices)[:, :2]
    cols = np.rint(xy[:, 0]).astype(np.int32)
    # pydelatin's y grows upwards from the raster's last row.
    rows = (n_rows - 1 - np.rint(xy[:, 1])).astype(np.int32)
    return rows, cols, np.asarray(tin.triangles).astype(np.int32)


def _tile_joins(rows, cols, row_edges, col_edges):
    """Triangles that join TINs of neighbouring tiles into one conforming TIN.

    Neighbouring tiles' border vertices lie on two lines of pixel centres a pixel apart (a tile
    ends at row r - 1, the next starts at row r). The strip between two such lines holds no pixel
    centre, so triangles zipped along it from both borders' vertices keep every pixel centre
    within its own tile's triangles (on a border line, the strip's edges are the tile's own), and
    share every edge with a tile: no T-junction. The sides have vertices at the same positions
    (:func:`_align_borders`), so the strip is quads a pixel wide, two triangles each. Where four
    tiles meet, the 1-pixel square between their corners is two triangles.
    """
    joins = []
    for _, vertex, side, strip, position in _strip_sides(rows, cols, row_edges, col_edges):
        joins.append(_zip_strips(strip, position, side, vertex))
    # Squares where four tiles meet: the corners around pixel corner (r, c) of each inner cut.
    r_cuts, c_cuts = row_edges[1:-1], col_edges[1:-1]
    if len(r_cuts) and len(c_cuts):
        n_cols = int(cols.max()) + 1
        key = rows.astype(np.int64) * n_cols + cols
        order = np.argsort(key)
        r, c = (a.ravel() for a in np.meshgrid(r_cuts, c_cuts, indexing="ij"))

        def vertex_at(r, c):
            return order[np.searchsorted(key, r * n_cols + c, sorter=order)]

        a, b = vertex_at(r - 1, c - 1), vertex_at(r - 1, c)
        d, e = vertex_at(r, c - 1), vertex_at(r, c)
        joins.append(np.concatenate([np.stack([a, d, b], 1), np.stack([b, d, e], 1)]).astype(np.int32))
    return joins


def _strip_sides(rows, cols, row_edges, col_edges):
    """The vertices along both sides of every strip between neighbouring tiles.

    Yields, for the strips across the row cuts (vertices along the columns) and then those across
    the column cuts (vertices along the rows), ``"row"`` or ``"col"`` and arrays of (vertex, side,
    strip, position): a vertex on the last line of a tile, before a cut, is side 0 of the strip at
    that cut and tile column (row); one on the first line after it, side 1.
    """
    for axis, inner, outer, in_edges, across in (
        ("row", rows, cols, row_edges, col_edges),
        ("col", cols, rows, col_edges, row_edges),
    ):
        cuts = in_edges[1:-1]
        if len(cuts) == 0:
            continue
        # Per line: the cut it ends a tile before (side 0), or starts a tile after (side 1); -1 if none.
        cut_before = np.full(int(in_edges[-1]) + 1, -1, np.int64)
        cut_after = cut_before.copy()
        cut_before[cuts - 1] = np.arange(len(cuts))
        cut_after[cuts] = np.arange(len(cuts))
        before, after = np.flatnonzero(cut_before[inner] >= 0), np.flatnonzero(cut_after[inner] >= 0)
        vertex = np.concatenate([before, after])
        side = np.concatenate([np.zeros(len(before), np.int64), np.ones(len(after), np.int64)])
        cut = np.concatenate([cut_before[inner[before]], cut_after[inner[after]]])
        segment_of = np.searchsorted(across, outer[vertex], side="right") - 1
        strip = cut * (len(across) - 1) + segment_of
        yield axis, vertex, side, strip, outer[vertex].astype(np.int64)


def _align_borders(rows, cols, z, triangles, row_edges, col_edges):
    """Give both sides of every strip between tiles vertices at the same positions.

    A strip zipped between sides with different vertices has triangles that reach from one
    side's vertex far along the other: a plant's rim vertex on one side spreads half its height
    along the strip, a steep sliver that renders as a dark line along the tiles' border. So each
    position that one side has and the other lacks becomes a vertex on the other side too, on
    that side's border edge, with the edge's interpolated height: it splits the edge's triangle
    into a fan in the same plane, so the surface, and its bound, are unchanged.

    Returns (rows, cols, z, triangles) with the new vertices after the old ones.
    """
    n = len(rows)
    new_rows, new_cols, new_z, new_start, new_end, new_where = [], [], [], [], [], []
    for axis, vertex, side, strip, position in _strip_sides(rows, cols, row_edges, col_edges):
        # One key per (strip, side): every position of the strip, lacking on that side, is
        # searched among that side's own positions.
        key = strip * 2 + side
        order = np.lexsort((position, key))
        key, position, vertex = key[order], position[order], vertex[order]
        both = np.unique(strip[order] * (1 << 32) + position)
        strip_of, pos = both >> 32, both & ((1 << 32) - 1)
        have = key * (1 << 32) + position  # sorted
        for lacking in (0, 1):
            combined = (strip_of * 2 + lacking) * (1 << 32) + pos
            at = np.searchsorted(have, combined)
            present = (at < len(have)) & (have[np.minimum(at, len(have) - 1)] == combined)
            missing = ~present
            if not missing.any():
                continue
            # The side's vertices before and after each missing position (a strip's ends are
            # tile corners, on both sides, so both exist and lie on the same key).
            hi = at[missing]
            lo = hi - 1
            u, v = vertex[lo], vertex[hi]
            p = pos[missing]
            t = (p - position[lo]) / (position[hi] - position[lo])
            z_new = z[u] + t * (z[v].astype(np.float64) - z[u])
            line = rows[u] if axis == "row" else cols[u]
            new_rows.append(line if axis == "row" else p)
            new_cols.append(p if axis == "row" else line)
            new_z.append(z_new)
            new_start.append(u)
            new_end.append(v)
            new_where.append(p)
    if not new_rows:
        return rows, cols, z, triangles
    rows = np.concatenate([rows, *[np.asarray(a, np.int32) for a in new_rows]])
    cols = np.concatenate([cols, *[np.asarray(a, np.int32) for a in new_cols]])
    z = np.concatenate([z, *[np.asarray(a, z.dtype) for a in new_z]])
    start, end, where = (np.concatenate(a) for a in (new_start, new_end, new_where))
    added = n + np.arange(len(start))
    return rows, cols, z, _split_edges(triangles, start, end, where, added)


def _split_edges(triangles, start, end, where, added):
    """Split border edges (start, end) at new vertices `added` (at positions `where` along them,
    `start` at the lower position): each edge's one triangle becomes a fan from its third vertex,
    in the same orientation. A triangle with new vertices on two edges (a tile's corner) is split
    at one edge, then its fan's triangle at the other."""
    # Only triangles with two corners among the edges' ends can hold one: a few per cent of them.
    n_vertices = int(max(triangles.max(), end.max(), start.max(), added.max())) + 1
    end_vertex = np.zeros(n_vertices, bool)
    end_vertex[start], end_vertex[end] = True, True
    candidate = end_vertex[triangles].sum(axis=1) >= 2
    rest, triangles = triangles[~candidate], triangles[candidate]
    while len(start):
        a = triangles.astype(np.int64)
        # Every directed edge of every triangle: corner k to corner k + 1.
        directed = (a * n_vertices + np.roll(a, -1, axis=1)).ravel()
        sort = np.argsort(directed)
        forward, at_forward = _find_sorted(directed, sort, start.astype(np.int64) * n_vertices + end)
        backward, at_backward = _find_sorted(directed, sort, end.astype(np.int64) * n_vertices + start)
        if not np.all(forward | backward):
            raise AssertionError("a tile's border edge has no triangle")  # an internal invariant
        at = np.where(forward, at_forward, at_backward)
        tri, corner = at // 3, at % 3
        # One edge per triangle in this pass: the edge of its first new vertex.
        edge = start.astype(np.int64) * n_vertices + end
        order = np.lexsort((where * np.where(forward, 1, -1), edge, tri))
        tri, corner, edge, added_o = tri[order], corner[order], edge[order], added[order]
        first_of_tri = np.r_[True, tri[1:] != tri[:-1]]
        chosen_edge = np.maximum.accumulate(np.where(first_of_tri, np.arange(len(tri)), 0))
        now = edge == edge[chosen_edge]
        later = order[~now]
        tri, corner, added_o = tri[now], corner[now], added_o[now]
        walk_from, walk_to = a[tri, corner], a[tri, (corner + 1) % 3]
        apex = a[tri, (corner + 2) % 3]
        group_start = np.r_[True, tri[1:] != tri[:-1]]
        group_end = np.r_[tri[1:] != tri[:-1], True]
        # The fan along the walk: (previous, new, apex) for each new vertex, then (last new, end, apex).
        previous = np.where(group_start, walk_from, np.r_[0, added_o[:-1]])
        fan = np.stack([previous, added_o, apex], axis=1)
        last = np.stack([added_o[group_end], walk_to[group_end], apex[group_end]], axis=1)
        keep = np.ones(len(triangles), bool)
        keep[tri] = False
        triangles = np.concatenate([triangles[keep], fan.astype(np.int32), last.astype(np.int32)])
        start, end, where, added = start[later], end[later], where[later], added[later]
    return np.concatenate([rest, triangles])


def _find_sorted(values, sort, keys):
    """Where each key is in `values` (`sort` its argsort): (found, index)."""
    at = sort[np.minimum(np.searchsorted(values, keys, sorter=sort), len(values) - 1)]
    return values[at] == keys, at


def _zip_strips(strip, position, side, vertex):
    """Zip the two sides of many strips into triangles.

    Each strip has two sides (0 and 1), each a line of vertices sorted by `position`, both
    starting and ending at the same positions. Walking along the strip, each vertex after the
    first of each side makes a triangle with the last vertex seen on each side.
    """
    order = np.lexsort((side, position, strip))
    strip, side, vertex = strip[order], side[order], vertex[order]
    n = len(vertex)
    at = np.arange(n)
    last_0 = np.maximum.accumulate(np.where(side == 0, at, 0))
    last_1 = np.maximum.accumulate(np.where(side == 1, at, 0))
    # The first two entries of a strip are its sides' first vertices (side 0 first: equal
    # positions sort by side); every later entry is a step.
    first = np.ones(n, bool)
    first[2:] = (strip[2:] != strip[1:-1]) | (strip[2:] != strip[:-2])
    step = np.flatnonzero(~first)
    prev = step - 1
    triangles = np.stack([vertex[last_0[prev]], vertex[last_1[prev]], vertex[step]], axis=1)
    return triangles.astype(np.int32)


def default_max_error(*, height_source="inflated", units="px", pixel_size=1.0, dsm_noise=None):
    """The adaptive mesh's default maximum vertical error for a relief, and the rule that chose it.

    No height detail finer than the data is kept. Heights from a shape prior (``"inflated"``,
    ``"calibrated"``) carry no information below the photo's resolution: half a pixel, in height
    units. Measured heights (a DSM's canopy height) carry the DSM's noise: the larger of
    ``DEFAULT_MAX_ERROR_FLOOR_M`` (1 cm) and `dsm_noise`.

    Parameters
    ----------
    height_source : {"inflated", "calibrated", "measured"}, optional
        Where the heights come from (see :func:`cliff_terrain.build.build_relief`).
    units : {"px", "m"}, optional
        ``"m"`` when the ground sampling distance is known.
    pixel_size : float, optional
        Size of one processing pixel in `units`.
    dsm_noise : float, optional
        Measured heights: the DSM's noise in metres (the robust spread of the soil's residual
        around the ground, :func:`cliff_terrain.measure.canopy.dsm_noise`); None: unknown.

    Returns
    -------
    value : float
        In `units`.
    rule : str
        Which rule chose it, with its numbers (recorded in ``metrics.json`` and the relief's record).

    Examples
    --------
    >>> default_max_error()
    (0.5, 'half a pixel (inflated heights, no scale: 0.5 px)')
    >>> default_max_error(height_source="measured", units="m", pixel_size=0.02, dsm_noise=0.013)
    (0.013, 'DSM noise 1.3 cm (robust spread of soil residuals)')
    """
    from ..settings import DEFAULT_MAX_ERROR_FLOOR_M, DEFAULT_MAX_ERROR_PIXELS

    pixel_size = check_float("pixel_size", pixel_size, minimum=0.0, strict_minimum=True)
    if height_source == "measured":
        if dsm_noise is not None and dsm_noise > DEFAULT_MAX_ERROR_FLOOR_M:
            noise = float(dsm_noise)
            return noise, f"DSM noise {100 * noise:.2g} cm (robust spread of soil residuals)"
        known = "" if dsm_noise is None else f"; DSM noise {100 * float(dsm_noise):.2g} cm"
        return DEFAULT_MAX_ERROR_FLOOR_M, f"1 cm floor (measured heights{known})"
    value = DEFAULT_MAX_ERROR_PIXELS * pixel_size
    if units == "m":
        return value, f"half a pixel ({height_source} heights, {100 * pixel_size:.2g} cm pixels)"
    return value, f"half a pixel ({height_source} heights, no scale: {value:g} px)"
