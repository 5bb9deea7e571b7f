"""Property-based tests: build_relief on random images and settings never fails in a foreign way."""

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cliff_terrain import CliffTerrainError, build_relief

images = st.builds(
    lambda rows, cols, seed, kind: _image(rows, cols, seed, kind),
    rows=st.integers(1, 48),
    cols=st.integers(1, 48),
    seed=st.integers(0, 2**32 - 1),
    kind=st.sampled_from(["noise", "blobs", "uniform", "float"]),
)


def _image(rows, cols, seed, kind):
    rng = np.random.default_rng(seed)
    if kind == "uniform":
        return np.full((rows, cols, 3), rng.integers(0, 256, 3), np.uint8)
    if kind == "float":
        return rng.random((rows, cols, 3))
    img = rng.integers(0, 256, (rows, cols, 3), dtype=np.uint8)
    if kind == "blobs":  # green discs on brown: something to segment
        img[:] = (130, 95, 60)
        rr, cc = np.mgrid[:rows, :cols]
        for _ in range(rng.integers(0, 5)):
            r, c, rad = rng.integers(0, rows), rng.integers(0, cols), rng.integers(1, 12)
            img[(rr - r) ** 2 + (cc - c) ** 2 <= rad**2] = (50, 140, 40)
    return img


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    image=images,
    max_size=st.one_of(st.integers(-5, 64), st.floats(allow_nan=True)),
    segmentation=st.sampled_from(["vegetation", "paper", "nope"]),
    profile=st.sampled_from(["circular", "poisson", "cone"]),
    exaggeration=st.one_of(st.floats(-1, 5), st.just(1.0), st.just(float("nan"))),
    gsd=st.one_of(st.none(), st.floats(-0.1, 0.1)),
    two_sided=st.booleans(),
)
def test_build_relief_only_raises_its_own_error_and_returns_sane_arrays(
    image, max_size, segmentation, profile, exaggeration, gsd, two_sided
):
    try:
        relief = build_relief(
            image,
            max_size=max_size,
            segmentation=segmentation,
            profile=profile,
            exaggeration=exaggeration,
            gsd=gsd,
            two_sided=two_sided,
        )
    except CliffTerrainError:
        return
    h = relief.heights
    assert np.all(np.isfinite(h)) and h.min() >= 0
    mesh = relief.mesh
    assert np.all(np.isfinite(mesh.vertices))
    assert mesh.corner_verts.min() >= 0 and mesh.corner_verts.max() < mesh.n_vertices
    assert mesh.face_sizes.sum() == mesh.corner_verts.size and mesh.face_sizes.min() >= 3
    assert mesh.edges.max() < mesh.n_vertices and mesh.corner_edges.max() < len(mesh.edges)
    front = mesh.uvs[: 4 * mesh.n_front_faces]
    back = mesh.uvs[4 * mesh.n_front_faces :]
    assert front.min() >= 0 and front.max() <= 1
    if back.size:
        assert (
            back[:, 0].min() > 1 and back[:, 0].max() <= 2 and back[:, 1].min() >= 0 and back[:, 1].max() <= 1
        )
