"""Seams between mosaic tiles: welded together, the stitched tiles leave no crack; unstitched, they do."""

from __future__ import annotations

import numpy as np
import pytest

from cliff_terrain import CliffTerrainError
from cliff_terrain.mesh.adaptive import adaptive_mesh
from cliff_terrain.mesh.quads import fan_triangles
from cliff_terrain.mesh.seams import border, seam_triangles, stitch

PIXEL = 0.01  # metres per pixel


def domes(shape, seed):
    """Plants as domes on flat soil, many of them crossing the tile borders."""
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[: shape[0], : shape[1]]
    heights = np.zeros(shape)
    for _ in range(40):
        r, c, radius = rng.uniform(0, shape[0]), rng.uniform(0, shape[1]), rng.uniform(4, 15)
        d2 = (rows - r) ** 2 + (cols - c) ** 2
        heights = np.maximum(heights, np.sqrt(np.clip(radius**2 - d2, 0, None)))
    return (heights * PIXEL).astype(np.float32)


def tiles(heights, size, *, stitched):
    """Each tile's one-sided adaptive mesh in mosaic coordinates (metres, y up), as the Import
    Mosaic operator builds them: the right and bottom borders of each tile kept for the next."""
    n_rows = heights.shape[0]
    right, bottom, meshes = {}, {}, []
    for r0 in range(0, heights.shape[0], size):
        for c0 in range(0, heights.shape[1], size):
            r1, c1 = min(r0 + size, heights.shape[0]), min(c0 + size, heights.shape[1])
            mesh = adaptive_mesh(heights[r0:r1, c0:c1], max_error=0.002, pixel_size=PIXEL, two_sided=False)
            right[(r0, c1)], bottom[(r1, c0)] = border(mesh, "right"), border(mesh, "bottom")
            if stitched:
                neighbours = {"left": right.get((r0, c0)), "top": bottom.get((r0, c0))}
                mesh = stitch(mesh, {k: v for k, v in neighbours.items() if v is not None})
            offset = np.array([c0 * PIXEL, (n_rows - r1) * PIXEL, 0.0])
            meshes.append((mesh, offset))
    return meshes


def open_edges(meshes):
    """Edges used by one face only, after welding vertices at the same place (to 1/1000 pixel)."""
    parts = []
    for mesh, offset in meshes:
        # One-sided: the front's triangles (paired into quads) and the seams' triangles.
        parts.append(
            (mesh.vertices.astype(np.float64) + offset, fan_triangles(mesh.face_sizes, mesh.corner_verts))
        )
    return welded_open_edges(parts, PIXEL)


def welded_open_edges(parts, pixel):
    """``(edges, points)``: the open edges of triangle meshes ``[(world vertices, triangles)]``
    welded at the same place to 1/1000 `pixel`, as pairs of indices into `points`, their
    positions in thousandths of a pixel. Shared by the Blender test of Import Mosaic."""
    keys, faces, start = [], [], 0
    for vertices, triangles in parts:
        keys.append(np.rint(np.asarray(vertices, np.float64) / pixel * 1000).astype(np.int64))
        faces.append(np.asarray(triangles) + start)
        start += len(vertices)
    points, weld = np.unique(np.concatenate(keys), axis=0, return_inverse=True)
    faces = weld.ravel()[np.concatenate(faces)]
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    return unique[counts == 1], points


def cracks(edges, points, width, height):
    """Open edges (from :func:`welded_open_edges`) that a view could see through: neither along
    the outer border of a `width` x `height` pixel mosaic nor vertical (no width)."""
    xy = points[edges.ravel(), :2].reshape(-1, 2, 2) / 1000
    vertical = (xy[:, 0] == xy[:, 1]).all(axis=1)
    along_border = (
        np.isclose(xy[:, :, 0], 0).all(1)
        | np.isclose(xy[:, :, 0], width).all(1)
        | np.isclose(xy[:, :, 1], 0).all(1)
        | np.isclose(xy[:, :, 1], height).all(1)
    )
    return xy[~vertical & ~along_border]


@pytest.mark.parametrize("seed", range(3))
def test_stitched_tiles_close_into_one_surface(seed):
    heights = domes((130, 170), seed)
    size = 50
    edges, points = open_edges(tiles(heights, size, stitched=True))
    assert len(cracks(edges, points, 170, 130)) == 0
    # The vertical open edges are where seams end together: where tiles meet, and where a seam
    # meets the outer border (four or two heights on one vertical line).
    xy = points[edges.ravel(), :2].reshape(-1, 2, 2) / 1000
    vertical = xy[(xy[:, 0] == xy[:, 1]).all(axis=1), 0]
    assert len(vertical) > 0
    assert np.isin(vertical[:, 0], [0, 50, 100, 150, 170]).all()
    assert np.isin(130 - vertical[:, 1], [0, 50, 100, 130]).all()
    # Without the seams the tiles crack where plants cross a border: the test can fail.
    assert len(cracks(*open_edges(tiles(heights, size, stitched=False)), 170, 130)) > 50


def test_stitch_keeps_the_front_and_its_uvs():
    heights = domes((60, 80), 7)
    left = adaptive_mesh(heights[:, :40], max_error=0.002, pixel_size=PIXEL, two_sided=False)
    right = adaptive_mesh(heights[:, 40:], max_error=0.002, pixel_size=PIXEL, two_sided=False)
    stitched = stitch(right, {"left": border(left, "right")})
    n = right.n_faces
    assert stitched.n_front_faces == right.n_front_faces
    np.testing.assert_array_equal(stitched.corner_verts[: right.corner_verts.size], right.corner_verts)
    np.testing.assert_array_equal(stitched.face_sizes[:n], right.face_sizes)
    assert (stitched.face_sizes[n:] == 3).all()
    np.testing.assert_array_equal(stitched.vertices[: right.n_vertices], right.vertices)
    theirs, ours = border(left, "right"), border(right, "left")
    assert stitched.n_faces - n == len(theirs.t) + len(ours.t) - 2
    # The seam's vertices sit on this tile's left side; its UVs are the texture's left column.
    seam_uv = stitched.uvs[right.corner_verts.size :]
    assert (seam_uv[:, 0] == 0).all() and (0 <= seam_uv[:, 1]).all() and (seam_uv[:, 1] <= 1).all()
    assert (stitched.vertices[right.n_vertices :, 0] == 0).all()


def test_seam_triangles_cover_the_strip_once():
    rng = np.random.default_rng(1)
    t_a = np.concatenate([[0.0], np.sort(rng.uniform(0, 10, 7)), [10.0]])
    t_b = np.concatenate([[0.0], np.sort(rng.uniform(0, 10, 4)), [10.0]])
    tri = seam_triangles(len(t_a), t_a, len(t_b), t_b)
    # Drawn as a strip (first polyline at z = 0, second at z = 1), the areas add up to the strip's.
    pts = np.concatenate([np.stack([t_a, np.zeros_like(t_a)], 1), np.stack([t_b, np.ones_like(t_b)], 1)])
    p = pts[tri]
    u, v = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    area = 0.5 * np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])  # numpy 2 has no 2-D np.cross
    assert area.sum() == pytest.approx(10.0) and len(tri) == len(t_a) + len(t_b) - 2


def test_misaligned_neighbours_are_refused():
    heights = np.zeros((20, 30), np.float32)
    a = adaptive_mesh(heights[:10], max_error=0.01, two_sided=False)
    b = adaptive_mesh(heights[:, :10], max_error=0.01, two_sided=False)
    with pytest.raises(
        CliffTerrainError, match="the left neighbour's border runs from 0 to 10, this tile's from 0 to 20"
    ):
        stitch(b, {"left": border(a, "right")})
    with pytest.raises(
        CliffTerrainError, match="`side` must be one of 'left', 'right', 'top', 'bottom', got 'north'"
    ):
        border(a, "north")
