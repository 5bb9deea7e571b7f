"""The DSM's lowest surfaces, block by block: the naive baseline and the field's own lowest surface.

A low percentile of the DSM in blocks of a few metres, interpolated bilinearly between the block
centres: every block of a crop field holds some alley, furrow or gap, and a field is smooth at
the block's scale (the idea of PMF, SMRF and the cloth simulation, reduced to a block percentile:
see :mod:`cliff_terrain.measure.ground`). The naive peer takes it as it is; the lowest surface
first removes the field's own plane, on which a block's lowest pixels lie at its downhill edge.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .percentiles import nan_percentile
from .robust_plane import robust_plane

DEFAULT_BLOCK_M = 5.0
# The baseline's percentile: low enough to reach the soil of a block that is mostly canopy.
BASELINE_PERCENTILE = 2.0


def naive_block_ground(dsm, *, pixel_size, block_m=DEFAULT_BLOCK_M, percentile=5.0):
    """The peer: a low percentile of the DSM alone in blocks, bilinearly interpolated (no segmentation).

    What one does without knowing which pixels are soil: with ``percentile=2`` and 5 m blocks it
    is the naive baseline every estimate is compared with, and the ``"baseline"`` candidate of
    :func:`cliff_terrain.measure.ground.fit_ground`.

    Examples
    --------
    >>> dsm = np.full((100, 100), 10.0, np.float32); dsm[::3, ::3] = 9.0   # soil under 1 m leaves
    >>> float(naive_block_ground(dsm, pixel_size=0.1, percentile=2)[50, 50])
    9.0
    """
    dsm = np.asarray(dsm, dtype=np.float32)
    levels, block = _block_percentiles(dsm, pixel_size=pixel_size, block_m=block_m, percentile=percentile)
    return _bilinear(levels, block, dsm.shape)


def _bilinear(levels, block, shape):
    """Block `levels` (NaN: a block without data, which takes the median level) interpolated
    bilinearly between the block centres onto a raster of `shape`."""
    import cv2

    if np.isnan(levels).any():
        fill = np.nanmedian(levels) if np.isfinite(levels).any() else 0.0
        levels = np.where(np.isnan(levels), fill, levels).astype(np.float32)
    rows, cols = shape
    nb_r, nb_c = levels.shape
    big = cv2.resize(levels, (nb_c * block, nb_r * block), interpolation=cv2.INTER_LINEAR)
    return np.ascontiguousarray(big[:rows, :cols])


def _block_percentiles(dsm, *, pixel_size, block_m, percentile):
    """(levels, block px): the `percentile` of `dsm` in each block, NaN where a block has no data."""
    dsm = np.asarray(dsm, dtype=np.float32)
    rows, cols = dsm.shape
    # A block larger than the raster is the raster: one level either way, and padding to the
    # block's own size would take memory in proportion to its area (a 1 km block: gigabytes).
    block = max(2, min(round(block_m / pixel_size), max(rows, cols)))
    nb_r, nb_c = -(-rows // block), -(-cols // block)
    pad = np.full((nb_r * block, nb_c * block), np.nan, np.float32)
    pad[:rows, :cols] = dsm
    blocks = pad.reshape(nb_r, block, nb_c, block).transpose(0, 2, 1, 3).reshape(nb_r, nb_c, -1)
    return nan_percentile(blocks, percentile).astype(np.float32), block  # nanpercentile's, vectorized


def lowest_surface(dsm, *, pixel_size, block_m=DEFAULT_BLOCK_M):
    """The DSM's lowest surface: its `BASELINE_PERCENTILE` in blocks above the field's tilt, bilinear.

    The naive peer's block percentile, taken after the field's own plane is removed (the plane
    of the block percentiles themselves, so that plants do not lift it) and added back: on a
    slope a block's lowest pixels lie at its downhill edge, below the soil at its centre by the
    slope times half a block, more than any microrelief. Held flat beyond the outer block
    centres: extending a border block's noisy level linearly was tried and measured worse on a
    real potato trial (day 100: RMSE 2.2 -> 2.3 cm with colour, 2.4 -> 4.5 cm without).
    :func:`block_levels` gives its parts, and the same surface from the blocks that show soil.
    """
    return block_levels(dsm, pixel_size=pixel_size, block_m=block_m).surface()


def block_levels(dsm, *, pixel_size, block_m=DEFAULT_BLOCK_M):
    """:class:`BlockLevels` of `dsm`: the parts of :func:`lowest_surface`."""
    dsm = np.asarray(dsm, dtype=np.float32)
    plane = _field_plane(dsm, pixel_size=pixel_size, block_m=block_m)
    levels, block = _block_percentiles(
        dsm - plane, pixel_size=pixel_size, block_m=block_m, percentile=BASELINE_PERCENTILE
    )
    return BlockLevels(levels, block, plane, block_count(np.isfinite(dsm), block))


def block_count(mask, block):
    """True pixels of `mask` in each `block` x `block` block (edge blocks cut by the raster)."""
    rows, cols = mask.shape
    nr, nc = -(-rows // block), -(-cols // block)
    padded = np.zeros((nr * block, nc * block), np.uint16)
    padded[:rows, :cols] = mask
    return padded.reshape(nr, block, nc, block).sum(axis=(1, 3), dtype=np.int64)


@dataclass(eq=False, frozen=True)
class BlockLevels:
    """Each block's `BASELINE_PERCENTILE` above the field's plane (NaN: a block without data), the
    block in pixels and the plane: :meth:`surface` is :func:`lowest_surface`.

    A block's lowest pixels are the ground only where the block holds soil (the assumption of the
    block percentile): given the `soil` pixels, a block where less than the percentile's share of
    its pixels with data is soil takes the level of the blocks around it that hold some
    (normalized convolution from one block's scale up, about the soil blocks' median level:
    :func:`~cliff_terrain.measure.ground_detail.evidence_offset`, relative to the plane through the
    soil blocks' levels), not its own, which is its canopy's: a closed potato canopy's 1.9 m blocks
    (a strip 5.6 m wide cut along a real trial's edge) stood 8 cm above the ground, and every plot
    in the strip read that much low.

    Examples
    --------
    A 1 m canopy covering four 0.5 m blocks (0.1 m pixels) of a bare field: alone, the blocks take
    its top; given the soil, the level of the soil around them.

    >>> dsm = np.zeros((40, 40), np.float32); dsm[15:25, 15:25] = 1.0
    >>> levels = block_levels(dsm, pixel_size=0.1, block_m=0.5)
    >>> float(levels.surface()[20, 20]), float(levels.surface(soil=dsm == 0)[20, 20])
    (1.0, 0.0)
    """

    levels: np.ndarray
    block: int
    plane: np.ndarray
    data: np.ndarray  # each block's pixels with data (its percentile's pixels)

    def surface(self, soil=None):
        """The lowest surface, from the blocks that hold `soil` when it is given."""
        levels = self.levels if soil is None else self._soil_levels(soil)
        return (_bilinear(levels, self.block, self.plane.shape) + self.plane).astype(np.float32)

    def _soil_levels(self, soil):
        from ..errors import CliffTerrainError
        from .ground_detail import evidence_offset

        soil = np.asarray(soil, dtype=bool)
        if soil.shape != self.plane.shape:
            raise CliffTerrainError(
                f"`soil` must have the surface's shape {self.plane.shape}, got {soil.shape}"
            )
        count = block_count(soil, self.block)  # soil is among the pixels with data (the evidence is)
        has = np.isfinite(self.levels)
        # The percentile reaches the soil when the soil is at least its share of the block's data.
        holds = has & (100 * count >= BASELINE_PERCENTILE * self.data)
        if holds.all() or not holds.any():
            return self.levels
        # Filled about the soil blocks' own plane, not the field's: the field's plane goes through
        # every block's level, and a closed canopy's blocks tilt and lift it (on a real closed potato
        # canopy's 5.6 m edge strip the filled blocks stood 4 cm high at the strip's inner side).
        tilt = self._soil_tilt(holds)
        levels = self.levels + tilt
        # From one block's scale up, around the soil blocks' median level (beyond every scale, that
        # level).
        centre = np.float32(np.median(levels[holds]))
        around = centre + evidence_offset(levels - centre, holds, 1.0, widen=True, valid=has)
        return np.where(holds | ~has, self.levels, around - tilt).astype(np.float32)

    def _soil_tilt(self, holds):
        """At each block's centre, the field's plane less the plane through the `holds` blocks.

        The soil blocks' levels are relative to the field's plane already: the plane through them
        (robust least squares, as the field's, in block units about their mean centre) is what the
        field's misses. Along a direction in which the soil blocks take fewer than three positions
        (a headland one or two blocks deep) a slope would be their noise extrapolated across the
        field: there the field's slope is kept (0), and with fewer than three soil blocks, all of it.
        """
        if np.count_nonzero(holds) < 3:
            return np.zeros(self.levels.shape, np.float32)
        at = np.stack(np.nonzero(holds)).astype(np.float64)  # the soil blocks' (row, col) indices
        centre = at.mean(axis=1)
        axes = [k for k in (0, 1) if np.unique(at[k]).size >= 3]
        if not axes:
            return np.zeros(self.levels.shape, np.float32)
        design = np.column_stack([np.ones(at.shape[1]), *(at[k] - centre[k] for k in axes)])
        coef = robust_plane(design, self.levels[holds].astype(np.float64))
        grid = np.indices(self.levels.shape, dtype=np.float64)
        # Less the plane, not its offset: the fill is about the soil blocks' median level anyway.
        return (-sum(c * (grid[k] - centre[k]) for c, k in zip(coef[1:], axes, strict=True))).astype(
            np.float32
        )


def _field_plane(dsm, *, pixel_size, block_m):
    """The plane z = a + b row + c col through the DSM's block percentiles (robust least squares).

    Each block's percentile lies on the ground at its downhill edge, so on a uniform slope the
    levels are the ground shifted by one constant: their plane has the field's slope. A block
    whose level lies more than three robust deviations off the plane (a block of canopy) is
    dropped and the plane fitted again. A block without data has no level and no say: beyond an
    orthomosaic's outline (its no-data corners) a stand-in level flattened the plane, and on a
    10 % slope put the ground 16 cm off at the field's edges (55 cm on 30 %). A block the outline
    cuts still counts at its centre, although its downhill edge lies elsewhere: on a 10 % slope
    the ground stays within 2 cm, on 30 % within 6 cm (refitting the plane until the blocks see no
    slope removed that, but on a curved synthetic field's grey photo it doubled the spread of the
    heights' errors).
    """
    plane = _plane_through_levels(dsm, pixel_size=pixel_size, block_m=block_m)
    return np.zeros(dsm.shape, np.float32) if plane is None else plane


def _plane_through_levels(dsm, *, pixel_size, block_m):
    """One robust plane through the block percentiles of `dsm` at the blocks' centres, or None."""
    levels, block = _block_percentiles(
        dsm, pixel_size=pixel_size, block_m=block_m, percentile=BASELINE_PERCENTILE
    )
    rows, cols = dsm.shape
    # Blocks without data have no level: a stand-in level at their centres would flatten the plane.
    has = np.isfinite(levels)
    if has.sum() < 3:
        return None
    bi, bj = np.nonzero(has)
    centre_r = np.minimum((bi + 0.5) * block, rows) / max(rows, 1)
    centre_c = np.minimum((bj + 0.5) * block, cols) / max(cols, 1)
    z = levels[has].astype(np.float64)
    design = np.column_stack([np.ones(z.size), centre_r, centre_c])
    coef = robust_plane(design, z)
    r = np.arange(rows, dtype=np.float64)[:, None] / max(rows, 1)
    c = np.arange(cols, dtype=np.float64)[None, :] / max(cols, 1)
    return (coef[0] + coef[1] * r + coef[2] * c).astype(np.float32)
