"""Affine georeference maths: pixel (col, row) <-> map (x, y), GDAL's convention.

``(col, row) = (0, 0)`` is the top-left *corner* of the top-left pixel, pixel centres are at
``(col + 0.5, row + 0.5)``::

    x = t[0, 0] * col + t[0, 1] * row + t[0, 2]
    y = t[1, 0] * col + t[1, 1] * row + t[1, 2]

given as a 2x3 array or a 3x3 one whose last row is (0, 0, 1).
"""

from __future__ import annotations

import numpy as np

from ...errors import CliffTerrainError


def as_affine(transform):
    """A pixel (col, row) -> map (x, y) transform as a 3x3 float64 array (see the module's docs)."""
    t = np.asarray(transform, dtype=np.float64)
    if t.shape == (2, 3):
        t = np.vstack([t, [0.0, 0.0, 1.0]])
    if t.shape != (3, 3) or not np.all(np.isfinite(t)) or not np.allclose(t[2], [0.0, 0.0, 1.0]):
        raise CliffTerrainError(f"`transform` must be a finite 2x3 or 3x3 affine matrix, got shape {t.shape}")
    if abs(np.linalg.det(t[:2, :2])) < 1e-300:
        raise CliffTerrainError("`transform` must be invertible, got a singular matrix")
    return t


def affine_inverse(transform):
    """The inverse of a 3x3 affine transform (see :func:`as_affine`), in closed form.

    Not ``np.linalg.inv``: LAPACK's inverse wakes OpenBLAS's thread pool, whose threads then spin
    for about 0.1 CPU-s on the other cores, taking them from a parallel season's other workers.

    Examples
    --------
    >>> t = as_affine([[0.5, 0.0, 100.0], [0.0, -0.5, 200.0]])
    >>> (affine_inverse(t) @ t).round(12).tolist()
    [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    """
    t = as_affine(transform)
    (a, b, c), (d, e, f) = t[0], t[1]
    det = a * e - b * d
    linear = np.array([[e, -b], [-d, a]]) / det
    inverse = np.eye(3)
    inverse[:2, :2] = linear
    inverse[:2, 2] = -(linear @ [c, f])
    return inverse


def apply_affine(transform, points):
    """(n, 2) points mapped by an affine transform (2x3 or 3x3): map -> pixel with the inverse.

    Examples
    --------
    >>> t = as_affine([[0.5, 0.0, 100.0], [0.0, -0.5, 200.0]])
    >>> apply_affine(affine_inverse(t), np.array([[101.0, 199.0]])).tolist()
    [[2.0, 2.0]]
    """
    t = np.asarray(transform, dtype=np.float64)
    return np.asarray(points, dtype=np.float64) @ t[:2, :2].T + t[:2, 2]


def grid_bounds(transform, shape):
    """(xmin, ymin, xmax, ymax) on the map of a (rows, cols) grid's corners."""
    rows, cols = shape
    corners = np.array([[0, 0, 1], [cols, 0, 1], [0, rows, 1], [cols, rows, 1]], dtype=np.float64)
    xy = corners @ np.asarray(transform)[:2].T
    return float(xy[:, 0].min()), float(xy[:, 1].min()), float(xy[:, 0].max()), float(xy[:, 1].max())


def pixel_size(transform):
    """(x, y) ground size of a pixel: the lengths of the transform's column and row steps."""
    t = np.asarray(transform, dtype=np.float64)
    return float(np.hypot(*t[:2, 0])), float(np.hypot(*t[:2, 1]))
