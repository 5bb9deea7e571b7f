"""The vectorized reductions the ground and the windowed measure run on, against plain references.

Each replaced a slower formulation (numpy's per-group ``nanpercentile``, a reduction over reshaped
short axes, gathers for a surface already on the orthophoto's grid, the whole grid's normal
equations at once): the numbers must be the references' own.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from cliff_terrain.errors import CliffTerrainError
from cliff_terrain.io.raster.bilinear import bilinear
from cliff_terrain.io.raster.blocks import reduce_blocks
from cliff_terrain.io.raster.geotiff import geotiff_tags
from cliff_terrain.measure.ground_detail import _local_quadratic
from cliff_terrain.measure.percentiles import nan_percentile
from cliff_terrain.measure.window_reading import SurfaceWindows


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("q", [0.0, 2.0, 25.0, 50.0, 97.5, 100.0])
def test_nan_percentile_is_numpys_nanpercentile(dtype, q):
    rng = np.random.default_rng(3)
    values = (100 + 10 * rng.normal(size=(400, 169))).astype(dtype)
    values[rng.random(values.shape) < 0.3] = np.nan
    values[:7] = np.nan  # all-NaN groups
    values[7:9, 1:] = np.nan  # one value left
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        expected = np.nanpercentile(values, q, axis=-1)
    got = nan_percentile(values, q)
    np.testing.assert_array_equal(got.astype(np.float32), expected.astype(np.float32))
    assert np.isnan(got[:7]).all()


def test_nan_percentile_refuses_a_percentile_outside_0_100():
    with pytest.raises(CliffTerrainError, match=r"`q` must be in \[0, 100\], got 101.0"):
        nan_percentile(np.zeros((2, 3)), 101)


def block_means_by_loop(values, factor, weights):
    """Each block's weighted mean and count, one block at a time (float64)."""
    rows, cols = weights.shape
    nr, nc = -(-rows // factor), -(-cols // factor)
    means = np.full((nr, nc, *values.shape[2:]), np.nan)
    counts = np.zeros((nr, nc))
    for i in range(nr):
        for j in range(nc):
            block = (slice(i * factor, (i + 1) * factor), slice(j * factor, (j + 1) * factor))
            w = weights[block]
            counts[i, j] = w.sum()
            if w.any():
                means[i, j] = values[block][w].astype(np.float64).mean(axis=0)
    return means, counts


@pytest.mark.parametrize("factor", [2, 3, 7])
def test_block_means_of_a_photo_are_exact_and_of_heights_within_float_rounding(factor):
    rng = np.random.default_rng(factor)
    shape = (61, 45)  # not whole blocks: the last ones are padded
    rgb = rng.integers(0, 256, (*shape, 3), dtype=np.uint8)
    weights = rng.random(shape) < 0.6
    heights = (250 + rng.random(shape)).astype(np.float32)
    heights[rng.random(shape) < 0.1] = np.nan
    means, counts = reduce_blocks(rgb, factor, weights)
    ref_means, ref_counts = block_means_by_loop(rgb, factor, weights)
    np.testing.assert_array_equal(counts, ref_counts)
    # Integer sums are exact in float32: the means are the float32 of the exact means' quotient.
    sums = np.nan_to_num(ref_means) * ref_counts[..., None]
    with np.errstate(invalid="ignore", divide="ignore"):
        exact = (np.rint(sums).astype(np.float32) / ref_counts[..., None].astype(np.float32)).astype(
            np.float32
        )
    np.testing.assert_array_equal(means, exact)
    usable = weights & np.isfinite(heights)
    means, counts = reduce_blocks(heights, factor, usable)
    ref_means, ref_counts = block_means_by_loop(heights, factor, usable)
    np.testing.assert_array_equal(counts, ref_counts)
    np.testing.assert_allclose(means, ref_means, rtol=0, atol=1e-4)  # float32 sums of ~250 m


def general_bilinear(source, y, x):
    """The bilinear written out as its four weighted neighbours, in float64: NaN where a neighbour
    that carries weight is NaN, a neighbour of weight 0 not read."""
    rows, cols = source.shape
    source = source.astype(np.float64)
    y0, x0 = np.floor(y).astype(int), np.floor(x).astype(int)
    fy, fx = (y - y0)[:, None], (x - x0)[None, :]
    y1, x1 = np.minimum(y0 + 1, rows - 1), np.minimum(x0 + 1, cols - 1)
    total = np.zeros((y.size, x.size))
    for rows_k, wy in ((y0, 1 - fy), (y1, fy)):
        for cols_k, wx in ((x0, 1 - fx), (x1, fx)):
            weight = wy * wx
            with np.errstate(invalid="ignore"):
                total += np.where(weight > 0, weight * source[np.ix_(rows_k, cols_k)], 0.0)
    return total.astype(np.float32)


@pytest.mark.parametrize("window", [(0, 40, 0, 50), (5, 39, 7, 49), (39, 40, 49, 50), (10, 20, 0, 1)])
def test_a_surface_on_the_orthophotos_own_grid_is_read_as_the_bilinear_reads_it(tmp_path, window):
    import tifffile

    rng = np.random.default_rng(0)
    dsm = (200 + rng.random((40, 50))).astype(np.float32)
    dsm[rng.random(dsm.shape) < 0.05] = np.nan
    transform = np.array([[0.1, 0.0, 500000.0], [0.0, -0.1, 4000000.0], [0.0, 0.0, 1.0]])
    path = tmp_path / "dsm.tif"
    tifffile.imwrite(path, dsm, extratags=geotiff_tags(transform, 32616, nodata=float("nan")))
    surface = SurfaceWindows(path)
    try:
        r0, r1, c0, c1 = window
        got = surface.on_grid(transform, r0, r1, c0, c1)
    finally:
        surface.close()
    expected = general_bilinear(dsm, np.arange(r0, r1, dtype=float), np.arange(c0, c1, dtype=float))
    np.testing.assert_array_equal(got, expected)
    # On its own grid a surface is its own pixels, as the whole raster's copy is: beside its no-data
    # too (a neighbour of weight 0 is not read; OpenCV's NaN x 0 dropped them).
    np.testing.assert_array_equal(got, dsm[r0:r1, c0:c1])
    # Fractional coordinates still take the general path.
    y, x = np.arange(0, 20) * 0.5 + 0.25, np.arange(0, 30) * 0.75
    # (rows first, then columns, in float32: the same to its rounding)
    np.testing.assert_allclose(bilinear(dsm, y, x), general_bilinear(dsm, y, x), rtol=2e-7, atol=0)


def test_the_local_quadratic_solved_band_by_band_is_the_weighted_least_squares_fit():
    # Several bands (rows x cols > the band's pixels); the reference solves the damped normal
    # equations of a few pixels directly, from the Gaussian-weighted sums over the evidence.
    from cliff_terrain.measure import ground_detail

    rng = np.random.default_rng(1)
    rows, cols = 300, 200
    rr, cc = np.mgrid[:rows, :cols].astype(np.float64)
    values = (0.002 * (rr - 150) ** 2 / 10 + 0.01 * cc + 0.02 * rng.normal(size=(rows, cols))).astype(
        np.float32
    )
    weight = (rng.random((rows, cols)) < 0.4).astype(np.float32)
    sigma = 1.2
    assert rows * cols > ground_detail._BAND_PIXELS
    estimate, _ = _local_quadratic(values, weight, sigma)
    radius = int(np.ceil(3 * sigma))
    for r, c in [(0, 0), (150, 100), (299, 57), (81, 199), (222, 13)]:
        dy, dx = np.mgrid[-radius : radius + 1, -radius : radius + 1]
        inside = (r + dy >= 0) & (r + dy < rows) & (c + dx >= 0) & (c + dx < cols)
        dy, dx = dy[inside], dx[inside]
        g = np.exp(-0.5 * ((dy / sigma) ** 2 + (dx / sigma) ** 2)) * weight[r + dy, c + dx]
        u, v = -dx / sigma, -dy / sigma  # the filters' offsets in sigmas (correlation: minus)
        basis = np.stack([u**a * v**b for a, b in ground_detail._QUADRATIC_BASIS])
        normal = (basis * g) @ basis.T
        right = (basis * g) @ values[r + dy, c + dx].astype(np.float64)
        normal[np.arange(1, 6), np.arange(1, 6)] += ground_detail._QUADRATIC_DAMPING * max(normal[0, 0], 1e-6)
        normal[0, 0] += 1e-9
        assert estimate[r, c] == pytest.approx(np.linalg.solve(normal, right)[0], abs=2e-4)


@pytest.mark.parametrize("sigma", [0.3, 1.2, 4.0])
def test_the_local_quadratic_in_chunks_on_threads_gives_the_whole_grids_numbers(monkeypatch, sigma):
    # The moments are filtered a chunk of rows at a time with a halo, the chunks on threads: the
    # same bits as one chunk of the whole grid in one thread (the zero border only at its edges).
    from cliff_terrain import _threads
    from cliff_terrain.measure import ground_detail

    rng = np.random.default_rng(2)
    rows, cols = 157, 90
    values = rng.normal(size=(rows, cols)).astype(np.float32)
    weight = (rng.random((rows, cols)) < 0.3).astype(np.float32)
    monkeypatch.setattr(ground_detail, "_BAND_PIXELS", 10**9)
    monkeypatch.setattr(_threads, "MAX_THREADS", 1)
    whole = _local_quadratic(values, weight, sigma)
    monkeypatch.setattr(ground_detail, "_BAND_PIXELS", 2 * cols)  # bands of 2 rows, many chunks
    monkeypatch.setattr(_threads, "MAX_THREADS", 4)
    monkeypatch.setattr(_threads, "usable_cores", lambda: 4)
    chunked = _local_quadratic(values, weight, sigma)
    for got, expected in zip(chunked, whole, strict=True):
        np.testing.assert_array_equal(got, expected)


@pytest.mark.parametrize("sigma", [0.1, 0.12])
def test_a_window_narrower_than_a_pixel_fits_the_pixel_itself_as_the_systems_do(monkeypatch, sigma):
    # The ground's 0.15 m scale on a 1.4 m grid is 0.1 px: its neighbours weigh e^-50. The fit is
    # then the pixel's own value where it has soil, without the 21 moments and the systems: the
    # same bits as solving them (their couplings fall below float32's precision), and where the
    # pixel has no soil the same nothing (the systems leave 1e-15 of the neighbours' weight).
    from cliff_terrain.measure import ground_detail

    rng = np.random.default_rng(4)
    values = (100 + rng.normal(size=(120, 90))).astype(np.float32)
    weight = (rng.random(values.shape) < 0.4).astype(np.float32)
    weight[weight > 0] = rng.choice([0.25, 0.5, 1.0], size=int(weight.sum())).astype(np.float32)
    moments = ground_detail._moments
    monkeypatch.setattr(ground_detail, "_moments", None)  # the shortcut makes no moments
    short = _local_quadratic(values, weight, sigma)
    monkeypatch.setattr(ground_detail, "_moments", moments)
    monkeypatch.setattr(ground_detail, "_NEGLIGIBLE_WEIGHT", 0.0)  # always the moments and systems
    solved = _local_quadratic(values, weight, sigma)
    soil = weight > 0
    np.testing.assert_array_equal(short[0][soil], solved[0][soil])
    np.testing.assert_array_equal(short[1][soil], solved[1][soil])
    np.testing.assert_array_equal(short[0][soil], values[soil])  # the pixel itself
    assert np.abs(solved[1][~soil]).max() < 1e-12 and not short[1][~soil].any()
    # There the value weighs by that fraction (detail_above's confidence): nothing either way.
    assert np.abs(solved[0][~soil] * solved[1][~soil]).max() < 1e-12
    # A wider window (0.3 px: neighbours weigh 0.004) is solved, not shortened.
    monkeypatch.setattr(ground_detail, "_NEGLIGIBLE_WEIGHT", 1e-12)
    monkeypatch.setattr(ground_detail, "_moments", None)
    with pytest.raises(TypeError):
        _local_quadratic(values, weight, 0.3)


def test_a_dsm_resampled_whole_takes_the_exact_bilinear_weights_the_windows_take(tmp_path):
    import tifffile

    from cliff_terrain.io.raster.geotiff import GeoRaster, resample

    rng = np.random.default_rng(1)
    dsm = (200 + rng.random((40, 50))).astype(np.float32)
    dsm[rng.random(dsm.shape) < 0.05] = np.nan
    source = np.array([[0.1, 0.0, 500000.0], [0.0, -0.1, 4000000.0], [0.0, 0.0, 1.0]])
    # A finer grid, shifted by a fraction of a pixel: every coordinate fractional.
    target = np.array([[0.037, 0.0, 500000.013], [0.0, -0.037, 3999999.991], [0.0, 0.0, 1.0]])
    shape = (100, 130)
    got = resample(GeoRaster(dsm, source, 32616, None, "dsm.tif"), transform=target, shape=shape)
    # The reference, written out: each target pixel centre in map units, then in source pixels.
    x = (500000.013 + (np.arange(shape[1]) + 0.5) * 0.037 - 500000.0) / 0.1 - 0.5
    y = (4000000.0 - (3999999.991 - (np.arange(shape[0]) + 0.5) * 0.037)) / 0.1 - 0.5
    inside_y, inside_x = (y >= 0) & (y <= 39), (x >= 0) & (x <= 49)
    expected = np.full(shape, np.nan, np.float32)
    expected[np.ix_(inside_y, inside_x)] = general_bilinear(dsm, y[inside_y], x[inside_x])
    np.testing.assert_array_equal(np.isnan(got), np.isnan(expected))
    # float32 sums of heights of 200 m: their rounding, where OpenCV's 1/32-pixel coordinates were
    # up to 1/64 of a pixel's rise off (about 8 mm of a 1 m rise).
    np.testing.assert_allclose(got, expected, rtol=0, atol=6e-5)
    # ... and the windows read the same numbers, to the bit.
    path = tmp_path / "dsm.tif"
    tifffile.imwrite(path, dsm, extratags=geotiff_tags(source, 32616, nodata=float("nan")))
    surface = SurfaceWindows(path)
    try:
        np.testing.assert_array_equal(surface.on_grid(target, 0, shape[0], 0, shape[1]), got)
        np.testing.assert_array_equal(surface.on_grid(target, 17, 60, 9, 101), got[17:60, 9:101])
    finally:
        surface.close()
