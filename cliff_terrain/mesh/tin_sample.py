"""A TIN measured and sampled on its raster: the exact vertical error at every pixel centre, the
surface at every pixel centre, a relief's front on the half-pixel lattice.
"""

from __future__ import annotations

import numpy as np

from ..errors import CliffTerrainError
from .tin import Tin

# Pixel/triangle pairs tested at once by the rasteriser (about 100 MB of temporaries).
_CHUNK = 2_000_000


def tin_error(heights, tin):
    """The vertical error of `tin` at every pixel centre of `heights`, measured exactly.

    Every pixel centre is located in the triangles that contain it by integer arithmetic (edge
    functions on integer coordinates), and the TIN's height there is interpolated linearly in
    double precision; where a centre lies on an edge shared by two triangles, the larger error
    counts.

    Parameters
    ----------
    heights : (rows, cols) array
        The raster the TIN approximates.
    tin : Tin
        From :func:`triangulate` (or any TIN over the same raster's pixel centres).

    Returns
    -------
    (rows, cols) float64 array
        ``|TIN - heights|`` per pixel; NaN where no triangle covers the pixel centre (only for a
        TIN that does not cover the raster, or one of a single row or column: there every pixel
        centre is a vertex, error 0).

    Examples
    --------
    >>> import numpy as np
    >>> from cliff_terrain.mesh.tin import triangulate
    >>> h = np.add.outer(np.arange(4.0), np.arange(5.0))  # a plane: two triangles fit exactly
    >>> bool(np.nanmax(tin_error(h, triangulate(h, max_error=0.01))) < 1e-12)
    True
    """
    heights = np.asarray(heights, dtype=np.float64)
    if heights.shape != tuple(tin.shape):
        raise CliffTerrainError(f"`heights` must have the TIN's shape {tin.shape}, got {heights.shape}")
    error = np.full(heights.shape, np.nan)
    if len(tin.triangles) == 0:
        error[tin.rows, tin.cols] = np.abs(heights[tin.rows, tin.cols] - tin.z)
        return error
    flat_error = error.ravel()
    z = tin.z.astype(np.float64)
    for pixel, tri, weights in _covered_pixels(tin.rows, tin.cols, tin.triangles, heights.shape):
        surface = (weights * z[tin.triangles[tri]]).sum(axis=1)
        # Unbuffered, so a pixel on a shared edge keeps the larger error; fmax: NaN (not yet
        # covered) loses to any number.
        np.fmax.at(flat_error, pixel, np.abs(surface - heights.ravel()[pixel]))
    return error


def sample_tin(tin, values=None):
    """The TIN's surface (or another per-vertex value) at every pixel centre of its raster.

    Parameters
    ----------
    tin : Tin
    values : (n_vertices,) array, optional
        Per-vertex values to interpolate instead of ``tin.z``.

    Returns
    -------
    (rows, cols) float64 array
        NaN where no triangle covers the pixel centre.
    """
    z = np.asarray(tin.z if values is None else values, dtype=np.float64)
    out = np.full(tin.shape, np.nan)
    if len(tin.triangles) == 0:
        out[tin.rows, tin.cols] = z
        return out
    flat = out.ravel()
    for pixel, tri, weights in _covered_pixels(tin.rows, tin.cols, tin.triangles, tin.shape):
        flat[pixel] = (weights * z[tin.triangles[tri]]).sum(axis=1)
    return out


def sample_front(vertices, triangles, grid_shape):
    """A relief's front triangles sampled on the half-pixel lattice of its height grid.

    Parameters
    ----------
    vertices : (n, 3) array
        Positions (x, y, z) of a relief mesh (any scale): the front spans the bounding box of the
        triangles' vertices, x with the columns, y up from the last row.
    triangles : (m, 3) int array
        The front's triangles, with every vertex on a pixel centre or a pixel corner (as
        :func:`cliff_terrain.mesh.adaptive.adaptive_mesh` and a grid split into triangles have).
    grid_shape : tuple of int
        (rows, cols) of the height grid.

    Returns
    -------
    (2 * rows + 1, 2 * cols + 1) float64 array
        z at the lattice points: ``[::2, ::2]`` are the pixel corners, ``[1::2, 1::2]`` the pixel
        centres. NaN where no triangle covers a point.
    """
    rows, cols = (int(n) for n in grid_shape)
    vertices = np.asarray(vertices, dtype=np.float64)
    triangles = np.asarray(triangles)
    used = vertices[np.unique(triangles)]
    (x0, y0), (x1, y1) = used[:, :2].min(axis=0), used[:, :2].max(axis=0)
    lattice_c = np.rint((vertices[:, 0] - x0) / (x1 - x0) * 2 * cols).astype(np.int32)
    lattice_r = np.rint((y1 - vertices[:, 1]) / (y1 - y0) * 2 * rows).astype(np.int32)
    tin = Tin(lattice_r, lattice_c, vertices[:, 2], triangles, (2 * rows + 1, 2 * cols + 1))
    return sample_tin(tin)


def _covered_pixels(rows, cols, triangles, shape):
    """Yield (flat pixel index, triangle index, (n, 3) barycentric weights) for every pixel centre
    inside (or on the border of) each triangle, in chunks of about `_CHUNK` candidates.

    Vertices are at integer (row, col); the inside test uses exact int64 edge functions.
    """
    r = rows.astype(np.int64)[triangles]
    c = cols.astype(np.int64)[triangles]
    r_lo, r_hi = r.min(axis=1), r.max(axis=1)
    c_lo, c_hi = c.min(axis=1), c.max(axis=1)
    box_rows, box_cols = r_hi - r_lo + 1, c_hi - c_lo + 1
    box = box_rows * box_cols
    area = (c[:, 1] - c[:, 0]) * (r[:, 2] - r[:, 0]) - (r[:, 1] - r[:, 0]) * (c[:, 2] - c[:, 0])
    n_cols = int(shape[1])
    start = 0
    ends = np.cumsum(box)
    while start < len(triangles):
        # Whole triangles per chunk, at least one.
        stop = max(int(np.searchsorted(ends, (ends[start - 1] if start else 0) + _CHUNK, "right")), start + 1)
        sel = np.arange(start, stop)
        counts = box[sel]
        tri = np.repeat(sel, counts)
        # Position of each candidate inside its triangle's bounding box.
        offset = np.arange(int(counts.sum()), dtype=np.int64) - np.repeat(np.cumsum(counts) - counts, counts)
        pr = r_lo[tri] + offset // box_cols[tri]
        pc = c_lo[tri] + offset % box_cols[tri]
        # Edge functions: twice the signed areas of the sub-triangles opposite each vertex.
        w0 = (c[tri, 2] - c[tri, 1]) * (pr - r[tri, 1]) - (r[tri, 2] - r[tri, 1]) * (pc - c[tri, 1])
        w1 = (c[tri, 0] - c[tri, 2]) * (pr - r[tri, 2]) - (r[tri, 0] - r[tri, 2]) * (pc - c[tri, 2])
        w2 = area[tri] - w0 - w1
        a = area[tri]
        inside = np.where(a > 0, (w0 >= 0) & (w1 >= 0) & (w2 >= 0), (w0 <= 0) & (w1 <= 0) & (w2 <= 0))
        inside &= a != 0
        tri, pr, pc = tri[inside], pr[inside], pc[inside]
        weights = np.stack([w0[inside], w1[inside], w2[inside]], axis=1) / a[inside][:, None].astype(
            np.float64
        )
        yield pr * n_cols + pc, tri, weights
        start = stop
