"""Triangles paired into quads (cliff_terrain.mesh.quads) are the same triangles, as Blender splits them."""

import numpy as np
import pytest
from scipy.spatial import Delaunay

from cliff_terrain.mesh.quads import MIN_NORMAL_COSINE, fan_triangles, pair_triangles


def _terrain(n=600, seed=4):
    """A Delaunay triangulation (scipy's) of random points on a bumpy surface with level patches."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 50, size=(n, 2))
    z = np.clip(np.sin(xy[:, 0] / 6) * np.cos(xy[:, 1] / 5) * 8, 0, None)  # level where clipped
    triangles = Delaunay(xy).simplices
    vertices = np.column_stack([xy, z])
    p = vertices[triangles]
    (ax, ay), (bx, by) = (p[:, 1, :2] - p[:, 0, :2]).T, (p[:, 2, :2] - p[:, 0, :2]).T
    clockwise = ax * by - ay * bx < 0  # (numpy 2 has no 2-D np.cross)
    triangles[clockwise] = triangles[clockwise][:, ::-1]
    return triangles, vertices


def _canonical(triangles):
    """Each triangle rotated to start at its smallest vertex (orientation kept), as a set."""
    t = np.asarray(triangles)
    shift = np.argmin(t, axis=1)
    rolled = np.stack([t[np.arange(len(t)), (shift + k) % 3] for k in range(3)], axis=1)
    return {tuple(r) for r in rolled.tolist()}


def _blender_flips(v1, v2, v3, v4):
    """Blender's is_quad_flip_v3_first_third_fast (math_geom.cc), in float32: split on 1-3 if true."""
    v1, v2, v3, v4 = (np.asarray(v, np.float32) for v in (v1, v2, v3, v4))
    cross_a = np.cross(v2 - v1, v3 - v1)
    cross_b = np.cross(v4 - v1, v3 - v1)
    return np.einsum("ij,ij->i", cross_a, cross_b) > 0


def test_the_pairs_are_the_triangles_and_blender_splits_each_quad_on_the_shared_edge():
    triangles, vertices = _terrain()
    level = np.ptp(vertices[triangles, 2], axis=1) == 0
    sizes, corners, first = pair_triangles(triangles, vertices, groups=level)
    assert set(np.unique(sizes)) == {3, 4} and sizes.sum() == len(corners)
    back = fan_triangles(sizes, corners)
    assert len(back) == len(triangles)
    assert _canonical(back) == _canonical(triangles)
    # Each face's group is its first triangle's, and both halves of a quad share it.
    np.testing.assert_array_equal(np.ptp(vertices[back, 2], axis=1) == 0, np.repeat(level[first], sizes - 2))

    quads = corners[np.repeat(sizes, sizes) == 4].reshape(-1, 4)
    v = vertices[quads]
    assert not _blender_flips(v[:, 0], v[:, 1], v[:, 2], v[:, 3]).any()
    n1 = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    n2 = np.cross(v[:, 2] - v[:, 0], v[:, 3] - v[:, 0])
    cosine = np.einsum("ij,ij->i", n1, n2) / np.linalg.norm(n1, axis=1) / np.linalg.norm(n2, axis=1)
    assert cosine.min() >= MIN_NORMAL_COSINE - 1e-9
    # Most triangles find a partner.
    assert 2 * len(quads) >= 0.75 * len(triangles)


def test_no_two_lone_neighbours_could_have_been_paired():
    """The matching is maximal: lone triangles left side by side disagree in direction or group."""
    triangles, vertices = _terrain(seed=9)
    level = np.ptp(vertices[triangles, 2], axis=1) == 0
    sizes, corners, first = pair_triangles(triangles, vertices, groups=level)
    lone = first[sizes == 3]
    normals = np.cross(*(vertices[triangles[lone]][:, k] - vertices[triangles[lone]][:, 0] for k in (1, 2)))
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    edges = {}
    for i, t in enumerate(triangles[lone].tolist()):
        for k in range(3):
            edges.setdefault(frozenset((t[k], t[(k + 1) % 3])), []).append(i)
    for shared in (e for e in edges.values() if len(e) == 2):
        i, j = shared
        assert level[lone[i]] != level[lone[j]] or normals[i] @ normals[j] < MIN_NORMAL_COSINE


def test_a_folded_pair_stays_two_triangles():
    # A roof ridge folded by 90 degrees: the halves' normals are 90 degrees apart.
    vertices = np.array([[0, 0, 0], [1, 0, 1], [1, 1, 1], [0, 1, 0], [2, 0, 0], [2, 1, 0]], float)
    triangles = np.array([[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 2]])
    sizes, corners, _ = pair_triangles(triangles, vertices)
    # Each slope is one quad; across the ridge nothing is joined.
    assert sizes.tolist() == [4, 4]
    assert _canonical(fan_triangles(sizes, corners)) == _canonical(triangles)
    sizes, _, _ = pair_triangles(triangles, vertices, groups=[0, 1, 0, 1])
    assert sizes.tolist() == [3, 3, 3, 3]


def test_the_pairing_is_the_same_for_the_same_seed():
    triangles, vertices = _terrain(seed=2)
    a = pair_triangles(triangles, vertices)
    b = pair_triangles(triangles, vertices)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)


def _bumpy_grid(rows, cols):
    """A grid of pixel centres, two triangles per cell, over domes and level soil."""
    r, c = np.mgrid[:rows, :cols]
    z = np.clip(np.sin(r / 7.0) * np.cos(c / 9.0) * 6, 0, None)
    vertices = np.column_stack([c.ravel(), -r.ravel(), z.ravel()]).astype(float)
    v = np.arange(rows * cols).reshape(rows, cols)
    a, b, d, e = v[:-1, :-1].ravel(), v[:-1, 1:].ravel(), v[1:, :-1].ravel(), v[1:, 1:].ravel()
    # Each cell's two triangles side by side: consecutive triangles are neighbours, as a TIN's blocks are.
    triangles = np.stack([np.stack([a, d, b], 1), np.stack([b, d, e], 1)], axis=1).reshape(-1, 3)
    return triangles, vertices


def test_a_big_mesh_pairs_in_parts_the_same_on_any_number_of_threads(monkeypatch):
    """Above 1.5 PART_TRIANGLES triangles the matching runs in parts of consecutive triangles:
    each part as pair_triangles pairs it alone, no quad across two parts, whatever the cores."""
    import cliff_terrain._threads as threads
    from cliff_terrain.mesh.quads import PART_TRIANGLES, _pair_part

    triangles, vertices = _bumpy_grid(300, 700)  # 418 k triangles: three parts
    level = np.ptp(vertices[triangles, 2], axis=1) == 0
    sizes, corners, first = pair_triangles(triangles, vertices, groups=level)
    assert _canonical(fan_triangles(sizes, corners)) == _canonical(triangles)
    parts = round(len(triangles) / PART_TRIANGLES)
    assert parts == 3
    size = -(-len(triangles) // parts)
    cuts = [0, size, 2 * size, len(triangles)]
    expected = [
        pair_triangles(triangles[a:b], vertices, groups=level[a:b])
        for a, b in zip(cuts[:-1], cuts[1:], strict=True)
    ]
    np.testing.assert_array_equal(sizes, np.concatenate([e[0] for e in expected]))
    np.testing.assert_array_equal(corners, np.concatenate([e[1] for e in expected]))
    np.testing.assert_array_equal(
        first, np.concatenate([e[2] + a for e, a in zip(expected, cuts[:-1], strict=True)])
    )
    # Only pairs across the two cuts are lost: nearly as many quads as one matching of the whole.
    whole = _pair_part(triangles, tuple(vertices.T.copy()), level, MIN_NORMAL_COSINE, 0)[0]
    assert (whole == 4).sum() > 0.8 * len(triangles) / 2
    assert (sizes == 4).sum() >= 0.998 * (whole == 4).sum()
    monkeypatch.setattr(threads, "usable_cores", lambda: 1)
    for x, y in zip(pair_triangles(triangles, vertices, groups=level), (sizes, corners, first), strict=True):
        np.testing.assert_array_equal(x, y)


def test_fan_triangles_refuses_other_polygons():
    with pytest.raises(ValueError, match="3 or 4 corners"):
        fan_triangles(np.array([5]), np.arange(5))
