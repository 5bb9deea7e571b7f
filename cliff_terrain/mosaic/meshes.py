"""A mosaic as meshes: each tile's relief as a one-sided adaptive mesh, joined to its neighbours.

:func:`tile_meshes` takes the tiles of :func:`cliff_terrain.mosaic.tiles.relief_tiles` one at a
time and gives each an adaptive mesh (:func:`cliff_terrain.mesh.adaptive.adaptive_mesh`) in the
units of `pixel_size`, joined to its left and top neighbours by a seam
(:func:`cliff_terrain.mesh.seams.stitch`) so that no crack opens where a plant crosses a border,
with its part of the photo for a texture. The Import Mosaic operator only turns what it yields
into Blender objects.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import check_float
from ..mesh.adaptive import adaptive_mesh
from ..mesh.grid import MeshArrays
from ..mesh.seams import border, stitch
from ..mesh.tin import default_max_error
from .tiles import DEFAULT_OVERLAP, DEFAULT_TILE, TileRelief, relief_tiles


@dataclass
class TileMesh:
    """One tile of a mosaic as a mesh.

    Attributes
    ----------
    core : (row0, row1, col0, col1)
        The tile's own area, in mosaic pixels.
    mesh : MeshArrays
        One-sided, in the units of `pixel_size`, with x from the tile's left edge and y up from its
        bottom edge; the seams to the left and top neighbours are faces after the front.
    rgb : (rows, cols, 3) uint8
        The photo over ``core``.
    relief : TileRelief
        The tile's mask, regions and heights (in pixels).
    """

    core: tuple[int, int, int, int]
    mesh: MeshArrays
    rgb: np.ndarray
    relief: TileRelief


def mosaic_max_error(pixel_size, max_error=None):
    """The bound of a mosaic's tile meshes and the rule that chose it: ``(value, rule)``.

    A value given (> 0) wins; by default the tiles' heights, inflated from the mosaic, keep
    nothing finer than half a mosaic pixel (:func:`cliff_terrain.mesh.tin.default_max_error`).

    Examples
    --------
    >>> mosaic_max_error(0.02)
    (0.01, 'half a pixel (inflated heights, 2 cm pixels)')
    >>> mosaic_max_error(0.02, 0.005)
    (0.005, 'given')
    """
    pixel_size = check_float("pixel_size", pixel_size, minimum=0.0, strict_minimum=True)
    if max_error is not None:
        return check_float("max_error", max_error, minimum=0.0, strict_minimum=True), "given"
    return default_max_error(height_source="inflated", units="m", pixel_size=pixel_size)


def tile_meshes(
    reader,
    *,
    max_error=None,
    pixel_size=1.0,
    tile=DEFAULT_TILE,
    overlap=DEFAULT_OVERLAP,
    settings=None,
    client=None,
    **kwargs,
):
    """The :class:`TileMesh` of every tile of a mosaic, one at a time (row by row).

    Parameters
    ----------
    reader : MosaicReader
    max_error : float, optional
        Largest vertical error of each tile's mesh, in the units of `pixel_size` (> 0); by
        default half a pixel (:func:`mosaic_max_error`).
    pixel_size : float, optional
        Size of a mosaic pixel (the mosaic's GSD for metres); heights are scaled by it too.
    tile, overlap, settings, client, kwargs
        As in :func:`cliff_terrain.mosaic.tiles.relief_tiles`.

    Returns
    -------
    iterator of TileMesh
        Each tile's right and bottom borders are kept until the tile that shares them comes.
    """
    # Not a generator itself, so that bad arguments and the overview fail here, not at the first tile.
    pixel_size = check_float("pixel_size", pixel_size, minimum=0.0, strict_minimum=True)
    max_error, _ = mosaic_max_error(pixel_size, max_error)
    tiles = relief_tiles(reader, tile=tile, overlap=overlap, settings=settings, client=client, **kwargs)
    return _stitched(reader, tiles, max_error, pixel_size)


def _stitched(reader, tiles, max_error, pixel_size):
    right, bottom = {}, {}
    try:
        for part in tiles:
            r0, r1, c0, c1 = part.core
            mesh = adaptive_mesh(
                part.heights * np.float32(pixel_size),
                max_error=max_error,
                pixel_size=pixel_size,
                two_sided=False,
            )
            right[(r0, c1)], bottom[(r1, c0)] = border(mesh, "right"), border(mesh, "bottom")
            shared = {"left": right.pop((r0, c0), None), "top": bottom.pop((r0, c0), None)}
            mesh = stitch(mesh, {side: b for side, b in shared.items() if b is not None})
            rgb, _ = reader.read(r0, r1, c0, c1)
            yield TileMesh(part.core, mesh, rgb, part)
    finally:
        # Closed early (the caller stopped or failed): the tile computed ahead is finished (or its
        # Dask tasks cancelled) now, while the reader is still open.
        tiles.close()
