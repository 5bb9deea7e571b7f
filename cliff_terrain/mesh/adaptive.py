"""The adaptive relief mesh: a TIN of the heights within a vertical error, framed out to the pixel
corners, with walls and base as :func:`cliff_terrain.mesh.grid.grid_mesh` has them (still no bpy).
"""

from __future__ import annotations

import numpy as np

from .._validate import check_float
from ..errors import CliffTerrainError
from .grid import with_edges
from .quads import pair_triangles
from .tin import triangulate


def adaptive_mesh(heights, *, max_error, pixel_size=1.0, two_sided=True, base_depth=None):
    """Build the relief mesh of a height grid as a TIN whose vertical error is at most `max_error`.

    The front is a triangulated irregular network (:func:`cliff_terrain.mesh.tin.triangulate`) with
    its vertices at pixel *centres*, so the surface is within `max_error` of every pixel's height
    at that pixel's centre (:func:`cliff_terrain.mesh.tin.tin_error` measures it). A frame half a
    pixel wide, level with the TIN's border vertices, takes the front out to the pixel corners of
    the image's border, so the mesh covers the image exactly as :func:`grid_mesh` does; the front
    UVs are planar (u = x / width, v = y / height), so a top view still shows every pixel of the
    texture. Walls, base and back UVs (u > 1) follow the outer border as in :func:`grid_mesh`.
    Level front triangles (bare soil, a plateau's top) are in ``flat_faces`` with the walls and
    base: shaded smooth, a large level triangle would take the slope of the plant rims it touches.
    Neighbouring triangles of the same shading whose normals agree are joined into quads that
    Blender splits back into the same two triangles (:func:`cliff_terrain.mesh.quads.pair_triangles`):
    about half the faces, two thirds of the corners.

    Parameters
    ----------
    heights : (rows, cols) array
        Height of each pixel, in the same unit as `pixel_size`.
    max_error : float
        Largest vertical distance between the front and a pixel centre's height (> 0, the unit
        of `heights`).
    pixel_size, two_sided, base_depth
        As in :func:`grid_mesh`.

    Returns
    -------
    MeshArrays
        Front faces are the TIN's and the frame's triangles, most of them paired into quads
        (``MeshArrays.front_triangles()`` gives the triangles back); ``grid_shape`` is the
        height grid's shape. Two-sided, the solid is watertight.

    Examples
    --------
    >>> import numpy as np
    >>> mesh = adaptive_mesh(np.zeros((100, 150)), max_error=0.01, two_sided=False)
    >>> mesh.n_faces  # two triangles, the frame's four strips and four corners, paired
    10
    >>> len(mesh.front_triangles())
    18
    """
    heights = np.asarray(heights)
    if heights.ndim != 2 or min(heights.shape) < 1:
        raise CliffTerrainError(f"`heights` must be a non-empty 2-D array, got shape {heights.shape}")
    pixel_size = check_float("pixel_size", pixel_size, minimum=0.0, strict_minimum=True)
    rows, cols = heights.shape
    if base_depth is None:
        base_depth = 0.02 * max(rows, cols) * pixel_size
    base_depth = check_float("base_depth", base_depth, minimum=0.0, strict_minimum=True)
    if not isinstance(two_sided, bool | np.bool_):
        raise CliffTerrainError(f"`two_sided` must be True or False, got {two_sided!r}")
    return tin_mesh(
        triangulate(heights, max_error=max_error),
        pixel_size=pixel_size,
        two_sided=bool(two_sided),
        base_depth=base_depth,
    )


def tin_mesh(tin, *, pixel_size=1.0, two_sided=True, base_depth=None):
    """The relief mesh of a :class:`cliff_terrain.mesh.tin.Tin` (see :func:`adaptive_mesh`)."""
    rows, cols = (int(n) for n in tin.shape)
    if base_depth is None:
        base_depth = 0.02 * max(rows, cols) * pixel_size
    n_tin = len(tin.z)
    # Positions in pixels: x = col + 0.5, y = rows - (row + 0.5) (y up, the image's top row highest).
    x_in = tin.cols.astype(np.float64) + 0.5
    y_in = rows - (tin.rows.astype(np.float64) + 0.5)

    # The border of the TIN, side by side, counter-clockwise from above, each from corner to corner:
    # bottom (last row) left to right, right (last column) bottom to top, top (row 0) right to
    # left, left (column 0) top to bottom.
    def side(on_side, key):
        idx = np.flatnonzero(on_side)
        return idx[np.argsort(key[idx], kind="stable")].astype(np.int64)

    sides = [
        side(tin.rows == rows - 1, tin.cols),
        side(tin.cols == cols - 1, -tin.rows),
        side(tin.rows == 0, -tin.cols),
        side(tin.cols == 0, tin.rows),
    ]
    # Each side's vertices projected half a pixel outwards onto the image's border.
    proj_x = [x_in[sides[0]], np.full(len(sides[1]), float(cols)), x_in[sides[2]], np.zeros(len(sides[3]))]
    proj_y = [np.zeros(len(sides[0])), y_in[sides[1]], np.full(len(sides[2]), float(rows)), y_in[sides[3]]]
    counts = [len(s) for s in sides]
    proj_start = n_tin + np.concatenate([[0], np.cumsum(counts)])
    projections = [np.arange(proj_start[k], proj_start[k + 1]) for k in range(4)]
    corner_start = int(proj_start[4])
    # Outer corners after each side: bottom-right, top-right, top-left, bottom-left.
    outer = corner_start + np.arange(4)
    corner_x = np.array([cols, cols, 0, 0], dtype=np.float64)
    corner_y = np.array([0, rows, rows, 0], dtype=np.float64)
    n_front_vertices = corner_start + 4

    x = np.concatenate([x_in, *proj_x, corner_x])
    y = np.concatenate([y_in, *proj_y, corner_y])
    z_in = tin.z.astype(np.float32)
    ends = np.array([s[-1] for s in sides])
    z = np.concatenate([z_in, *(z_in[s] for s in sides), z_in[ends]])

    # Front triangles: the TIN's, turned counter-clockwise seen from +z (rows grow downwards).
    faces = [tin.triangles[:, ::-1].astype(np.int64)]
    for k in range(4):
        a, p = sides[k], projections[k]
        # Strip between the side and its projection: quads p_i, p_i+1, a_i+1, a_i.
        faces.append(np.stack([p[:-1], p[1:], a[1:]], axis=1))
        faces.append(np.stack([p[:-1], a[1:], a[:-1]], axis=1))
        # Corner square after the side: its last projection, the outer corner, the next side's
        # first projection, the inner corner.
        q, inner = projections[(k + 1) % 4][0], a[-1]
        faces.append(np.array([[p[-1], outer[k], q], [p[-1], q, inner]]))
    triangles = np.concatenate(faces)

    # Level triangles (bare soil, a plateau's top) are shaded flat: smooth shading would spread
    # the slope of a plant's rim, through the normals of the rim's vertices, over every large
    # level triangle that touches it (a grid's level quads are a pixel wide; a TIN's are not).
    tri_z = z[triangles]
    level_tri = (tri_z[:, 0] == tri_z[:, 1]) & (tri_z[:, 1] == tri_z[:, 2])
    # Triangles of the same shading whose normals agree are paired into quads, which Blender
    # draws as the same two triangles (cliff_terrain.mesh.quads): about half the faces.
    front_sizes, front, first = pair_triangles(
        triangles, np.stack([x, y, z / pixel_size], axis=1), groups=level_tri
    )
    level = level_tri[first]
    n_front = len(front_sizes)
    n_front_corners = len(front)
    u_vertex = (x / cols).astype(np.float32)
    v_vertex = (y / rows).astype(np.float32)
    if not two_sided:
        vertices = np.stack([x * pixel_size, y * pixel_size, z], axis=1)
        face_sizes = front_sizes
        corner_verts = front
        uvs = np.stack([u_vertex[corner_verts], v_vertex[corner_verts]], axis=1)
        return with_edges(vertices, face_sizes, corner_verts, uvs, n_front, (rows, cols), level)

    # The outer border ring, counter-clockwise from the bottom-left corner (as border_ring).
    ring = np.concatenate(
        [
            outer[3:4],
            projections[0],
            outer[0:1],
            projections[1],
            outer[1:2],
            projections[2],
            outer[2:3],
            projections[3],
        ]
    ).astype(np.int32)
    n_ring = len(ring)
    base_idx = np.arange(n_front_vertices, n_front_vertices + n_ring, dtype=np.int32)
    nxt = np.roll(np.arange(n_ring), -1)
    walls = np.stack([ring, base_idx, base_idx[nxt], ring[nxt]], axis=1)
    corner_verts = np.concatenate([front, walls.ravel(), base_idx[::-1]]).astype(np.int32)
    face_sizes = np.concatenate([front_sizes, np.full(n_ring, 4, np.int32), np.array([n_ring], np.int32)])
    x = np.concatenate([x, x[ring]])
    y = np.concatenate([y, y[ring]])
    z = np.concatenate([z, np.full(n_ring, -base_depth, np.float32)])
    vertices = np.stack([x * pixel_size, y * pixel_size, z], axis=1)

    uvs = np.empty((corner_verts.size, 2), dtype=np.float32)
    uvs[:n_front_corners, 0] = u_vertex[front]
    uvs[:n_front_corners, 1] = v_vertex[front]
    # Back UVs: the front UV of the vertex (or of the border vertex a base vertex sits under), u + 1;
    # the left border moves in by half a texel so that u > 1 holds for every back corner.
    back = corner_verts[n_front_corners:]
    front_vertex = np.where(
        back >= n_front_vertices, ring[np.clip(back - n_front_vertices, 0, n_ring - 1)], back
    )
    uvs[n_front_corners:, 0] = np.maximum(u_vertex[front_vertex], np.float32(0.5 / cols)) + 1.0
    uvs[n_front_corners:, 1] = v_vertex[front_vertex]
    flat = np.concatenate([level, np.ones(n_ring + 1, dtype=bool)])  # the walls and base too
    return with_edges(vertices, face_sizes, corner_verts, uvs, n_front, (rows, cols), flat)


def choose_mesh(mesh, shape):
    """The mesh a build makes of a processing grid of `shape`, and why: ``(mesh, rule)``.

    ``"grid"`` and ``"adaptive"`` are taken as given. ``"auto"`` is the adaptive mesh wherever it
    builds at least as fast as the grid end to end (core and Blender): grids of fewer than
    ``settings.AUTO_GRID_BELOW_PIXELS`` pixels (1.5 MP) get the grid, larger ones the adaptive mesh.

    Examples
    --------
    >>> choose_mesh("grid", (100, 100))
    ('grid', 'given')
    >>> choose_mesh("auto", (1000, 750))
    ('grid', 'auto: grid (0.75 MP < 1.5 MP, where the grid builds at least as fast)')
    >>> choose_mesh("auto", (2000, 1500))
    ('adaptive', 'auto: adaptive (3 MP >= 1.5 MP, where it builds faster than the grid)')
    """
    from ..settings import AUTO_GRID_BELOW_PIXELS

    if mesh != "auto":
        return mesh, "given"
    if AUTO_GRID_BELOW_PIXELS is None:
        return "adaptive", "auto: adaptive (not slower than the grid at any size measured)"
    pixels = int(shape[0]) * int(shape[1])
    size = f"{pixels / 1e6:.2g} MP"
    limit = f"{AUTO_GRID_BELOW_PIXELS / 1e6:g} MP"
    if pixels < AUTO_GRID_BELOW_PIXELS:
        return "grid", f"auto: grid ({size} < {limit}, where the grid builds at least as fast)"
    return "adaptive", f"auto: adaptive ({size} >= {limit}, where it builds faster than the grid)"
