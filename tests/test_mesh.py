"""Mesh arrays: topology, orientation, UV conventions and affine transforms."""

import numpy as np
import pytest

from cliff_terrain import CliffTerrainError, grid_mesh
from cliff_terrain.mesh.grid import corner_heights


def _signed_volume(mesh):
    v = mesh.vertices.astype(np.float64)
    total = 0.0
    for start, size in zip(mesh.face_offsets, mesh.face_sizes, strict=True):
        p = v[mesh.corner_verts[start : start + size]]
        # Fan triangulation; exact for planar polygons.
        total += np.einsum("ij,ij->i", np.repeat(p[:1], size - 2, 0), np.cross(p[1:-1], p[2:])).sum() / 6.0
    return total


def test_one_sided_grid_counts_positions_and_uvs():
    heights = np.arange(6, dtype=np.float32).reshape(2, 3)
    mesh = grid_mesh(heights, pixel_size=0.5, two_sided=False)
    assert mesh.vertices.shape == (12, 3)
    assert mesh.n_faces == mesh.n_front_faces == 6
    assert np.all(mesh.face_sizes == 4)
    # Vertex (row 0, col 0) is the image's top-left corner: largest y.
    assert mesh.vertices[0].tolist()[:2] == [0.0, 1.0]
    assert mesh.vertices[-1].tolist()[:2] == [1.5, 0.0]
    # Front UVs are the vertex position over the extent, v = 1 at the top row.
    xy = mesh.vertices[mesh.corner_verts, :2]
    np.testing.assert_allclose(mesh.uvs, xy / [1.5, 1.0], atol=1e-6)
    # An open sheet: its border edges belong to one face only.
    counts = mesh.edge_face_counts()
    assert counts.min() == 1 and counts.max() == 2


def test_two_sided_is_watertight_outward_and_marks_back_uvs():
    rng = np.random.default_rng(0)
    heights = rng.uniform(0, 3, (7, 9)).astype(np.float32)
    mesh = grid_mesh(heights, base_depth=1.0)
    assert np.all(mesh.edge_face_counts() == 2)
    # Outward normals give a positive volume: the grid's volume above the base.
    vol = _signed_volume(mesh)
    assert vol > 0
    # Volume of the solid = base slab + the relief's volume (trapezoid rule on corner heights).
    zc = corner_heights(heights).astype(np.float64)
    relief = (0.25 * (zc[:-1, :-1] + zc[:-1, 1:] + zc[1:, :-1] + zc[1:, 1:])).sum()
    # Bilinear quads split into triangles are not exactly bilinear; a loose bound keeps it honest.
    expected = 7 * 9 * 1.0 + relief
    assert vol == pytest.approx(expected, rel=0.02)
    front = mesh.uvs[: mesh.n_front_faces * 4]
    back = mesh.uvs[mesh.n_front_faces * 4 :]
    assert front[:, 0].min() >= 0 and front[:, 0].max() <= 1
    assert back[:, 0].min() > 1 and back[:, 0].max() <= 2
    assert back[:, 1].min() >= 0 and back[:, 1].max() <= 1
    # Every back corner maps to the texture point of its own (x, y), shifted by 1 in u.
    xy = mesh.vertices[mesh.corner_verts[mesh.n_front_faces * 4 :], :2]
    # (the left edge is moved in by half a texel so that u > 1 holds strictly)
    expected = xy / [9.0, 7.0]
    expected[:, 0] = np.maximum(expected[:, 0], 0.5 / 9)
    np.testing.assert_allclose(back - [1.0, 0.0], expected, atol=1e-6)
    base = mesh.vertices[(7 + 1) * (9 + 1) :]
    assert np.all(base[:, 2] == -1.0)


def test_corner_heights_average_neighbours():
    h = np.array([[0, 4], [8, 12]], dtype=np.float32)
    zc = corner_heights(h)
    assert zc.shape == (3, 3)
    assert zc[1, 1] == 6.0 and zc[0, 0] == 0.0 and zc[2, 2] == 12.0 and zc[0, 1] == 2.0


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"heights": np.zeros(3)}, r"`heights` must be a non-empty 2-D array, got shape \(3,\)"),
        ({"heights": np.full((2, 2), np.nan)}, "`heights` must be finite"),
        ({"heights": np.zeros((2, 2)), "pixel_size": 0}, r"`pixel_size` must be > 0.0, got 0.0"),
        ({"heights": np.zeros((2, 2)), "base_depth": -1}, r"`base_depth` must be > 0.0, got -1.0"),
    ],
)
def test_grid_mesh_rejects_bad_arguments(kwargs, match):
    heights = kwargs.pop("heights")
    with pytest.raises(CliffTerrainError, match=match):
        grid_mesh(heights, **kwargs)


@pytest.mark.parametrize("two_sided", [False, True])
def test_edges_are_each_pair_of_consecutive_corners_once(two_sided):
    mesh = grid_mesh(np.random.default_rng(3).uniform(0, 2, (6, 8)), two_sided=two_sided)
    cv = mesh.corner_verts
    nxt = np.arange(1, cv.size + 1)
    nxt[mesh.face_offsets + mesh.face_sizes - 1] = mesh.face_offsets
    pairs = np.sort(np.column_stack([cv, cv[nxt]]), axis=1)
    # Derived independently: the distinct undirected corner pairs.
    expected = np.unique(pairs, axis=0)
    got = np.sort(mesh.edges, axis=1)
    assert len(got) == len(expected)
    np.testing.assert_array_equal(np.unique(got, axis=0), expected)
    # corner_edges points every corner at the edge to the next corner.
    np.testing.assert_array_equal(got[mesh.corner_edges], pairs)


@pytest.mark.parametrize("two_sided", [False, True])
@pytest.mark.parametrize("shape", [(1, 1), (2, 3), (7, 5), (31, 64)])
def test_grid_sizes_are_those_of_the_built_mesh(shape, two_sided):
    from cliff_terrain.mesh.grid import grid_sizes, grid_topology

    mesh = grid_topology(shape, two_sided=two_sided)
    sizes = grid_sizes(shape, two_sided=two_sided)
    assert sizes.n_vertices == mesh.n_vertices
    assert sizes.n_edges == mesh.edges.shape[0] == mesh.edge_face_counts().size
    assert sizes.n_faces == mesh.n_faces
    assert sizes.n_corners == mesh.corner_verts.size == int(mesh.face_sizes.sum())
    assert sizes.n_front_faces == mesh.n_front_faces == shape[0] * shape[1]
    with pytest.raises(
        CliffTerrainError, match=r"`shape` must be \(rows, cols\) with both >= 1, got \(0, 4\)"
    ):
        grid_sizes((0, 4))


@pytest.mark.parametrize(("n_vertices", "n_keys"), [(1, 3), (10, 5), (1_000, 900_000), (300_000, 1_300_000)])
def test_edges_sorted_out_in_ranges_of_vertices_are_numpys_unique(n_vertices, n_keys):
    """Big meshes find their edges by ranges of the lower vertex, on threads: np.unique's result."""
    from cliff_terrain.mesh.grid import _unique_inverse

    rng = np.random.default_rng(n_keys)
    a, b = rng.integers(0, n_vertices, (2, n_keys))
    keys = np.minimum(a, b) * n_vertices + np.maximum(a, b)
    unique, inverse = np.unique(keys, return_inverse=True)
    got_unique, got_inverse = _unique_inverse(keys, n_vertices)
    np.testing.assert_array_equal(got_unique, unique)
    np.testing.assert_array_equal(got_inverse, inverse.ravel())
    assert got_inverse.dtype == np.int32
