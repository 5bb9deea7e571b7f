"""Property-based tests: build_relief on random images and settings never fails in a foreign way."""

from collections import Counter

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


EXAMPLES = 200


def _mostly(valid, invalid):
    """A setting drawn from `valid` nine times in ten, else from `invalid` (so that most calls
    build a relief to check, and every refusal is still tried)."""
    return st.tuples(st.integers(0, 9), valid, invalid).map(lambda t: t[2] if t[0] == 0 else t[1])


# How the generated calls ended: "built" a relief or "refused" with a CliffTerrainError.
OUTCOMES = Counter()


@settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    image=images,
    max_size=_mostly(st.integers(16, 64), st.one_of(st.integers(-5, 15), st.floats(allow_nan=True))),
    segmentation=_mostly(st.sampled_from(["vegetation", "paper"]), st.just("nope")),
    profile=_mostly(st.sampled_from(["circular", "poisson"]), st.just("cone")),
    exaggeration=_mostly(
        st.one_of(st.floats(0.01, 5), st.just(1.0)), st.one_of(st.floats(-1, 0), st.just(float("nan")))
    ),
    gsd=_mostly(st.one_of(st.none(), st.floats(1e-4, 0.1)), st.floats(-0.1, 0)),
    two_sided=st.booleans(),
)
def _build_relief_only_raises_its_own_error_and_returns_sane_arrays(
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
            mesh="grid",  # the UV layout checked below is the grid's
        )
    except CliffTerrainError:
        OUTCOMES["refused"] += 1
        return
    OUTCOMES["built"] += 1
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


def test_build_relief_only_raises_its_own_error_and_returns_sane_arrays():
    OUTCOMES.clear()
    _build_relief_only_raises_its_own_error_and_returns_sane_arrays()
    print(f"build_relief on generated input: {dict(OUTCOMES)}")
    # Both outcomes are exercised: a floor of reliefs built and checked, and of calls refused.
    assert OUTCOMES["built"] >= EXAMPLES // 10 and OUTCOMES["refused"] >= EXAMPLES // 10, dict(OUTCOMES)
