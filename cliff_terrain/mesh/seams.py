"""Seams between the meshes of adjacent mosaic tiles, so that a plant crossing a tile border has no crack.

Each tile of a mosaic gets its own adaptive mesh (:func:`cliff_terrain.mesh.adaptive.adaptive_mesh`), whose
front reaches the tile's border through a frame level with the tile's outermost pixels. Two
neighbours therefore meet along their shared border with different vertices and, where a plant
crosses it, different heights: a slit through which the background shows. :func:`stitch` adds to
a tile's mesh a *seam*: a strip of triangles in the plane of the shared border that joins the
neighbour's border polyline to the tile's own, vertex for vertex, like the grid's step between
two pixels of different height. With the seams of its left and top neighbours added to every
tile, the tiles' fronts close into one surface without holes (``tests/test_seams.py`` welds them
and checks that the only open edges are the mosaic's outer border).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..errors import CliffTerrainError
from .grid import with_edges

SIDES = ("left", "right", "top", "bottom")


class Border(NamedTuple):
    """A tile front's outline along one side: positions along it and heights, in order.

    Attributes
    ----------
    t : (n,) float64
        Position along the side in the mesh's units, from the side's start (its bottom for left
        and right, its left end for top and bottom) to its end, increasing.
    z : (n,) float32
        Height of each vertex.
    index : (n,) int64
        The vertices' indices in the mesh.
    """

    t: np.ndarray
    z: np.ndarray
    index: np.ndarray


def border(mesh, side):
    """The front vertices of a one-sided tile mesh that lie on one side of its rectangle.

    Parameters
    ----------
    mesh : MeshArrays
        A one-sided mesh from :func:`cliff_terrain.mesh.adaptive.adaptive_mesh` (or ``grid_mesh``), whose
        front covers the rectangle from (0, 0) to its largest x and y.
    side : {"left", "right", "top", "bottom"}

    Returns
    -------
    Border

    Examples
    --------
    >>> import numpy as np
    >>> from cliff_terrain.mesh.adaptive import adaptive_mesh
    >>> mesh = adaptive_mesh(np.zeros((4, 6)), max_error=0.1, two_sided=False)
    >>> border(mesh, "left").t.tolist()  # the frame's corners and the projected border pixels
    [0.0, 0.5, 3.5, 4.0]
    """
    if side not in SIDES:
        raise CliffTerrainError(f"`side` must be one of {', '.join(map(repr, SIDES))}, got {side!r}")
    vertices = mesh.vertices
    x, y = vertices[:, 0], vertices[:, 1]
    axis, along = (0, y) if side in ("left", "right") else (1, x)
    coordinate = vertices[:, axis]
    edge = coordinate.min() if side in ("left", "bottom") else coordinate.max()
    index = np.flatnonzero(coordinate == edge)
    index = index[np.argsort(along[index], kind="stable")]
    return Border(along[index].astype(np.float64), vertices[index, 2].copy(), index.astype(np.int64))


def seam_triangles(n_a, t_a, n_b, t_b):
    """Triangles joining two polylines along one line: vertex ``k < n_a`` is the first one's
    ``k``-th vertex, ``n_a + k`` the second one's.

    Both start at the same position and end at the same position (`t_a`, `t_b` increasing); each
    step along either adds one triangle, so the strip has ``n_a + n_b - 2`` triangles and no
    gap.

    Examples
    --------
    >>> seam_triangles(2, [0.0, 2.0], 3, [0.0, 1.0, 2.0]).tolist()
    [[0, 3, 2], [0, 3, 1], [1, 4, 3]]
    """
    t_a, t_b = np.asarray(t_a, np.float64), np.asarray(t_b, np.float64)
    # Every step of either polyline, in order along the line (ties: the first polyline's first).
    steps = np.concatenate([t_a[1:], t_b[1:]])
    order = np.argsort(steps, kind="stable")
    on_a = order < n_a - 1
    i = np.cumsum(on_a) - on_a  # the first polyline's vertex before each step
    j = np.cumsum(~on_a) - ~on_a
    a_i, b_j = i, n_a + j
    return np.where(
        on_a[:, None],
        np.stack([a_i, b_j, a_i + 1], axis=1),  # a step along the first: a_i, b_j, a_i+1
        np.stack([a_i, b_j + 1, b_j], axis=1),  # a step along the second: a_i, b_j+1, b_j
    ).astype(np.int64)


def stitch(mesh, neighbours):
    """`mesh` with seams to its neighbours' borders added (new faces after the existing ones).

    Parameters
    ----------
    mesh : MeshArrays
        A one-sided tile mesh (see :func:`border`), in the tile's own frame. Take the borders
        it shares with later tiles before stitching it: a seam's end vertices lie on the
        adjacent sides too.
    neighbours : dict
        ``{side: Border}``: for each side of this tile that a neighbour shares, the neighbour's
        :func:`border` on that side, with `t` in this tile's frame (the same along a shared
        side when the tiles are aligned) and the same start and end.

    Returns
    -------
    MeshArrays
        The same front (``n_front_faces`` unchanged) and the seam faces after it; their UVs are
        the planar UVs of their vertices, i.e. this tile's texture along the shared side.
    """
    if not neighbours:
        return mesh
    size = mesh.vertices[:, :2].max(axis=0)
    vertices, faces = [mesh.vertices], []
    n = mesh.n_vertices
    for side, theirs in neighbours.items():
        ours = border(mesh, side)
        if not (np.isclose(theirs.t[0], ours.t[0]) and np.isclose(theirs.t[-1], ours.t[-1])):
            raise CliffTerrainError(
                f"the {side} neighbour's border runs from {theirs.t[0]:g} to {theirs.t[-1]:g}, "
                f"this tile's from {ours.t[0]:g} to {ours.t[-1]:g}: the tiles are not aligned"
            )
        # The neighbour's vertices, placed on this tile's side.
        fixed = 0.0 if side in ("left", "bottom") else float(size[0 if side == "right" else 1])
        placed = np.empty((len(theirs.t), 3), np.float32)
        if side in ("left", "right"):
            placed[:, 0], placed[:, 1] = fixed, theirs.t
        else:
            placed[:, 0], placed[:, 1] = theirs.t, fixed
        placed[:, 2] = theirs.z
        local = seam_triangles(len(theirs.t), theirs.t, len(ours.t), ours.t)
        lookup = np.concatenate([n + np.arange(len(theirs.t)), ours.index])
        faces.append(lookup[local])
        vertices.append(placed)
        n += len(placed)
    vertices = np.concatenate(vertices)
    seams = np.concatenate(faces).astype(np.int32)
    corner_verts = np.concatenate([mesh.corner_verts, seams.ravel()])
    face_sizes = np.concatenate([mesh.face_sizes, np.full(len(seams), 3, np.int32)])
    planar = (vertices[seams.ravel(), :2] / size).astype(np.float32)
    uvs = np.concatenate([mesh.uvs, planar])
    flat = np.concatenate([mesh.shaded_flat, np.ones(len(seams), dtype=bool)])  # seams stand on edge: flat
    return with_edges(vertices, face_sizes, corner_verts, uvs, mesh.n_front_faces, mesh.grid_shape, flat)


__all__ = ["SIDES", "Border", "border", "seam_triangles", "stitch"]
