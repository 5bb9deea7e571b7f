"""Triangles paired into quads that Blender draws as the same two triangles, and back (no bpy).

Blender splits a quad ``v0 v1 v2 v3`` on its ``v0-v2`` diagonal unless the two halves are folded
past a right angle (``is_quad_flip_v3_first_third_fast``: their normals point apart), when it takes
``v1-v3``. A pair of adjacent triangles whose normals agree, written with their shared edge as
``v0-v2``, is therefore drawn, shaded and sampled exactly as the two triangles were, in one face
with four corners instead of two faces with six: an adaptive mesh's faces about halve.
"""

from __future__ import annotations

import numpy as np

from .._threads import map_row_bands

# Pairs must agree in direction by at least this cosine (about 25 degrees): far from Blender's
# folding test (cosine 0, in float32), and close enough that a smooth quad's vertex normals (from the
# quad's mean normal) stay those of its two triangles.
MIN_NORMAL_COSINE = 0.9
# Pairs are looked for within parts of about this many consecutive triangles, on threads: a 12 MP
# relief's 490 k triangles pair in 0.20 s in four parts against 0.38-0.56 s in one (smaller sorts
# that stay in the cache, and two cores), for 0.28 % more faces (no pair across a part's end).
PART_TRIANGLES = 131_072


def pair_triangles(triangles, vertices, *, groups=None, min_cosine=MIN_NORMAL_COSINE, seed=0):
    """Pair edge-sharing triangles into quads Blender splits back into the same triangles.

    Parameters
    ----------
    triangles : (n, 3) int array
        Vertex indices of consistently oriented triangles (each shared edge runs opposite ways).
    vertices : (n_vertices, 3) float array
        Positions.
    groups : (n,) array, optional
        Only triangles of the same group are paired (e.g. flat- and smooth-shaded ones).
    min_cosine : float
        Least cosine of the angle between a pair's normals.
    seed : int
        The pairing is a maximal matching with random priorities (the same for the same seed).
        Meshes of more than 1.5 ``PART_TRIANGLES`` triangles are matched in parts of about
        that many consecutive triangles (on threads): two triangles of different parts are not
        paired. The parts depend on the number of triangles only, not on the machine.

    Returns
    -------
    face_sizes : (n_faces,) int32
        3 or 4: the lone triangles and the quads, in the order of their first triangle.
    corner_verts : (sum(face_sizes),) int32
        A quad is ``a, c2, b, c1`` for triangles ``(a, b, c1)`` and ``(b, a, c2)``: shared edge 0-2.
    first : (n_faces,) int64
        Index of each face's first triangle (its group is the face's).

    Examples
    --------
    >>> import numpy as np
    >>> square = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    >>> sizes, corners, first = pair_triangles(np.array([[0, 1, 2], [0, 2, 3]]), square)
    >>> sizes.tolist(), fan_triangles(sizes, corners).tolist()
    ([4], [[2, 3, 0], [2, 0, 1]])
    """
    triangles = np.asarray(triangles, dtype=np.int64)
    n = len(triangles)
    vertices = np.asarray(vertices, dtype=np.float64)
    xyz = tuple(np.ascontiguousarray(vertices[:, k]) for k in range(3))
    groups = None if groups is None else np.asarray(groups)
    parts = max(1, round(n / PART_TRIANGLES))
    if parts == 1:
        return _pair_part(triangles, xyz, groups, min_cosine, seed)
    size = -(-n // parts)
    results = {}

    def part(t0, t1):
        sizes, corners, first = _pair_part(
            triangles[t0:t1], xyz, None if groups is None else groups[t0:t1], min_cosine, seed
        )
        results[t0] = sizes, corners, first + t0

    map_row_bands(part, n, size)
    # In the order of their first triangle, as one part would have them.
    sizes, corners, first = (np.concatenate([results[t0][k] for t0 in sorted(results)]) for k in range(3))
    return sizes, corners, first


def _pair_part(triangles, xyz, groups, min_cosine, seed):
    """:func:`pair_triangles` of `triangles` (int64) with vertex coordinates `xyz` (x, y, z float64)."""
    n = len(triangles)
    x, y, z = xyz
    # Unnormalised normals, component by component (np.cross on a (n, 3, 3) gather costs twice this).
    i0, i1, i2 = (np.ascontiguousarray(triangles[:, k]) for k in range(3))
    ax, ay, az = x[i1] - x[i0], y[i1] - y[i0], z[i1] - z[i0]
    bx, by, bz = x[i2] - x[i0], y[i2] - y[i0], z[i2] - z[i0]
    nx, ny, nz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    lengths = np.sqrt(nx * nx + ny * ny + nz * nz)

    # Each triangle's edge k runs from corner k to corner k+1, opposite corner k+2. A shared edge
    # is two directed edges with the same key, next to each other once sorted.
    a = triangles.ravel()
    b = triangles[:, [1, 2, 0]].ravel()
    keys = np.minimum(a, b) * (int(x.shape[0]) + 1) + np.maximum(a, b)
    order = np.argsort(keys, kind="stable")
    sorted_keys = keys[order]
    same = np.flatnonzero(sorted_keys[1:] == sorted_keys[:-1])
    e1, e2 = order[same], order[same + 1]
    t1, t2 = e1 // 3, e2 // 3
    ok = (a[e1] == b[e2]) & (t1 != t2)
    if groups is not None:
        ok &= groups[t1] == groups[t2]
    e1, t1, t2 = e1[ok], t1[ok], t2[ok]
    # cos(angle) >= min_cosine without normalising: dot >= min_cosine * |n1| |n2|.
    l1, l2 = lengths[t1], lengths[t2]
    dot = nx[t1] * nx[t2] + ny[t1] * ny[t2] + nz[t1] * nz[t2]
    ok = (l1 > 0) & (l2 > 0) & (dot >= min_cosine * (l1 * l2))
    e1, t1, t2 = e1[ok], t1[ok], t2[ok]

    # Maximal matching: each round, an edge whose score is the highest at both its triangles joins
    # them. An edge to a triangle with no other candidate comes first (Karp and Sipser: that
    # choice is never worse), the rest by random priority (which ends in O(log n) rounds).
    partner = np.full(n, -1, dtype=np.int64)
    via = np.full(n, -1, dtype=np.int64)  # the directed edge (of the lower triangle) of each pair
    priority = np.random.default_rng(seed).permutation(len(t1)).astype(np.int64)
    while len(t1):
        degree = np.bincount(t1, minlength=n) + np.bincount(t2, minlength=n)
        score = priority + len(priority) * (np.minimum(degree[t1], degree[t2]) == 1)
        best = np.full(n, -1, dtype=np.int64)
        np.maximum.at(best, t1, score)
        np.maximum.at(best, t2, score)
        won = (best[t1] == score) & (best[t2] == score)
        partner[t1[won]], partner[t2[won]] = t2[won], t1[won]
        via[t1[won]] = e1[won]
        free = (partner[t1] < 0) & (partner[t2] < 0)
        e1, t1, t2, priority = e1[free], t1[free], t2[free], priority[free]

    lone = partner < 0
    lead = lone | (via >= 0)  # each pair written once, at the triangle whose edge was kept
    first = np.flatnonzero(lead)
    sizes = np.where(lone[first], 3, 4).astype(np.int32)
    corners = np.empty((len(first), 4), dtype=np.int64)
    single = lone[first]
    corners[single, :3] = triangles[first[single]]
    # Edge e = 3 t + k of triangle t: a = corner k, b = corner k + 1, c1 = corner k + 2 (flat indices).
    edge = via[first[~single]]
    base = edge - edge % 3
    a_v, b_v = a[edge], b[edge]
    c1 = a[base + (edge + 2) % 3]
    # c2: the corner of the partner that is neither a nor b.
    tri2 = triangles[partner[edge // 3]]
    c2 = tri2.sum(axis=1) - a_v - b_v
    corners[~single] = np.stack([a_v, c2, b_v, c1], axis=1)
    mask = np.arange(4) < sizes[:, None]
    return sizes, corners[mask].astype(np.int32), first.astype(np.int64)


def fan_triangles(face_sizes, corner_verts):
    """(n, 3) triangles of faces of 3 or 4 corners as Blender draws unfolded ones: 0-1-2, 0-2-3.

    Examples
    --------
    >>> fan_triangles(np.array([3, 4]), np.array([0, 1, 2, 3, 4, 5, 6])).tolist()
    [[0, 1, 2], [3, 4, 5], [3, 5, 6]]
    """
    face_sizes = np.asarray(face_sizes)
    corner_verts = np.asarray(corner_verts)
    if len(face_sizes) and not np.isin(face_sizes, (3, 4)).all():
        raise ValueError("only faces of 3 or 4 corners are split here")
    starts = np.zeros(len(face_sizes), dtype=np.int64)
    np.cumsum(face_sizes[:-1], out=starts[1:])
    quads = starts[face_sizes == 4]
    first = np.stack([starts, starts + 1, starts + 2], axis=1)
    second = np.stack([quads, quads + 2, quads + 3], axis=1)
    # Each quad's second triangle right after its first, so triangles follow their faces.
    index = np.concatenate([first, second])
    rank = np.concatenate([np.arange(len(starts)), np.flatnonzero(face_sizes == 4)])
    return corner_verts[index[np.argsort(rank, kind="stable")]]


__all__ = ["MIN_NORMAL_COSINE", "PART_TRIANGLES", "fan_triangles", "pair_triangles"]
