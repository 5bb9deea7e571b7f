"""Heights: the circular and Poisson profiles against closed-form solutions."""

import numpy as np
import pytest

from cliff_terrain import CliffTerrainError, distance_map, inflate


def _ellipse(a, b, shape=(121, 161)):
    rr, cc = np.mgrid[: shape[0], : shape[1]]
    r0, c0 = (shape[0] - 1) / 2, (shape[1] - 1) / 2
    inside = ((rr - r0) / b) ** 2 + ((cc - c0) / a) ** 2 <= 1.0
    return inside, rr - r0, cc - c0


@pytest.mark.parametrize("profile", ["circular", "poisson"])
def test_disc_becomes_a_hemisphere(profile):
    disc, dr, dc = _ellipse(40, 40)
    h = inflate(disc.astype(np.int32), profile=profile)
    radial = np.hypot(dr, dc)
    expected = np.sqrt(np.maximum(40.0**2 - radial**2, 0.0))
    core = radial < 35  # the last pixels of a digital disc are off by the rasterisation
    np.testing.assert_allclose(h[core], expected[core], atol=1.2)
    assert h[~disc].max() == 0.0


def test_poisson_profile_matches_closed_form_on_an_ellipse():
    # laplace(h) = -4 on an ellipse with h = 0 on its edge: h = k (1 - x^2/a^2 - y^2/b^2),
    # k = 2 / (1/a^2 + 1/b^2).
    a, b = 70.0, 35.0
    inside, dr, dc = _ellipse(a, b)
    k = 2.0 / (1.0 / a**2 + 1.0 / b**2)
    expected = np.sqrt(np.maximum(k * (1 - (dc / a) ** 2 - (dr / b) ** 2), 0.0))
    h = inflate(inside.astype(np.int32), profile="poisson")
    core = (dc / a) ** 2 + (dr / b) ** 2 < 0.8
    np.testing.assert_allclose(h[core], expected[core], rtol=0.03, atol=0.5)
    # The circular profile of the same ellipse peaks at its half-width, with a crease along the
    # long axis; the Poisson profile is taller there and smooth.
    hc = inflate(inside.astype(np.int32), profile="circular")
    assert hc.max() == pytest.approx(b, abs=1.0)
    assert h.max() > hc.max()


def test_circular_profile_follows_the_formula_per_region():
    labels = np.zeros((30, 60), np.int32)
    labels[5:25, 5:25] = 1  # a 20 px square
    labels[10:16, 35:55] = 2  # a 6 px wide strip
    d = distance_map(labels)
    h = inflate(labels)
    for k in (1, 2):
        sel = labels == k
        dmax = d[sel].max()
        np.testing.assert_allclose(h[sel], np.sqrt(dmax**2 - (dmax - d[sel]) ** 2), rtol=1e-5)
    assert h[labels == 1].max() == pytest.approx(10.0, abs=0.01)
    assert h[labels == 2].max() == pytest.approx(3.0, abs=0.01)


def test_touching_regions_get_separate_domes():
    labels = np.zeros((40, 80), np.int32)
    labels[5:35, 5:40] = 1
    labels[5:35, 40:75] = 2
    for profile in ("circular", "poisson"):
        h = inflate(labels, profile=profile)
        ridge = h[20]
        # A valley where the two regions meet, peaks inside each.
        assert ridge[39:41].min() < 0.5 * ridge[5:40].max()
        assert ridge[5:40].max() > 10 and ridge[40:75].max() > 10


def test_border_is_not_ground_and_full_frame_still_rises():
    labels = np.zeros((20, 40), np.int32)
    labels[:, :10] = 1  # cut by the left edge
    h = inflate(labels)
    assert h[:, 0].min() > 0  # the plant keeps its height at the frame
    full = inflate(np.ones((20, 30), np.int32), profile="poisson")
    assert full.max() > 5 and np.all(np.isfinite(full))


def test_exaggeration_scales_heights():
    disc, _, _ = _ellipse(20, 20, shape=(50, 50))
    h1 = inflate(disc.astype(int))
    h3 = inflate(disc.astype(int), exaggeration=3.0)
    np.testing.assert_allclose(h3, 3 * h1, rtol=1e-6)


def test_flat_ground_stays_flat():
    assert inflate(np.zeros((10, 10), np.int32)).max() == 0.0


@pytest.mark.parametrize(
    ("args", "kwargs", "match"),
    [
        ((np.zeros(5, int),), {}, r"`labels` must be a 2-D array, got shape \(5,\)"),
        ((np.zeros((3, 3)),), {}, "`labels` must hold integers, got dtype float64"),
        (
            (np.zeros((3, 3), int),),
            {"profile": "square"},
            "`profile` must be one of 'auto', 'circular', 'poisson', 'plateau', got 'square'",
        ),
        ((np.zeros((3, 3), int),), {"exaggeration": 0}, r"`exaggeration` must be > 0.0, got 0.0"),
        ((np.zeros((3, 3), int),), {"exaggeration": float("nan")}, "`exaggeration` must be finite, got nan"),
    ],
)
def test_inflate_rejects_bad_arguments(args, kwargs, match):
    with pytest.raises(CliffTerrainError, match=match):
        inflate(*args, **kwargs)
