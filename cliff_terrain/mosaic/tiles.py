"""Orthomosaics larger than memory: read a tiled GeoTIFF in windows, build the relief tile by tile.

A whole farm's orthomosaic has hundreds of megapixels; :class:`cliff_terrain.io.raster.mosaic.MosaicReader`
reads any window of a tiled GeoTIFF, decoding only the TIFF tiles it overlaps.

:func:`relief_tiles` builds the relief in tiles of `tile` x `tile` pixels, each read with an
`overlap` margin on every side and cut back to its own area, so that a plant crossing a tile's
border lies whole in the windows of both tiles and gets the same mask, region and heights in
each, as it would in one piece (plants smaller than the margin). Settings that depend on the whole
image are fixed first, from an overview read with every TIFF tile decoded once: the vegetation
index and its threshold (as :func:`cliff_terrain.photo_heights.segmentation.segment` picks them for the
overview), the watershed's scales and the plateau's canopy height. Tiles are independent: each is
a call of :func:`relief_tile`, ``segment()`` and ``inflate()`` on the tile's window with those
settings, which a Dask task can run as well.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from .._validate import check_float, check_int
from ..errors import CliffTerrainError
from ..io.raster.mosaic import MosaicReader
from ..settings import DEFAULT_EXAGGERATION, DEFAULT_PROFILE

DEFAULT_TILE = 4096
DEFAULT_OVERLAP = 512


@dataclass
class TileWindow:
    """One tile: its own area ``core`` and the area read for it ``window`` (core + overlap, clipped),
    both (row0, row1, col0, col1) in mosaic pixels."""

    core: tuple[int, int, int, int]
    window: tuple[int, int, int, int]


def tile_windows(shape, *, tile=DEFAULT_TILE, overlap=DEFAULT_OVERLAP):
    """Cover a (rows, cols) image with tiles of `tile` pixels, each read with `overlap` around it.

    Examples
    --------
    >>> [w.core for w in tile_windows((50, 70), tile=40, overlap=8)]
    [(0, 40, 0, 40), (0, 40, 40, 70), (40, 50, 0, 40), (40, 50, 40, 70)]
    >>> tile_windows((50, 70), tile=40, overlap=8)[1].window
    (0, 48, 32, 70)
    """
    rows, cols = (int(n) for n in shape)
    tile = check_int("tile", tile, minimum=16)
    overlap = check_int("overlap", overlap, minimum=0)
    out = []
    for r0 in range(0, rows, tile):
        for c0 in range(0, cols, tile):
            r1, c1 = min(rows, r0 + tile), min(cols, c0 + tile)
            window = (
                max(0, r0 - overlap),
                min(rows, r1 + overlap),
                max(0, c0 - overlap),
                min(cols, c1 + overlap),
            )
            out.append(TileWindow((r0, r1, c0, c1), window))
    return out


@dataclass
class MosaicSettings:
    """What every tile shares, fixed from the whole mosaic (see :func:`mosaic_settings`)."""

    index: str
    threshold: float
    min_region: int
    profile: str
    exaggeration: float
    radius: float
    edge_scale: float
    max_height: float | None = None
    soil: float | None = None
    # The mosaic's sample scale (io.raster.photo_samples.sample_scale), so that a tile opened by
    # its path scales its samples as the whole mosaic, without an overview of its own.
    scale: float | None = None


def mosaic_settings(
    reader, *, profile=DEFAULT_PROFILE, exaggeration=DEFAULT_EXAGGERATION, min_region=None, tile=DEFAULT_TILE
):
    """The vegetation index and threshold for the whole mosaic, from its overview.

    Parameters
    ----------
    reader : MosaicReader
    profile, exaggeration
        As in :func:`cliff_terrain.build_relief` (the mosaic is segmented in the vegetation mode,
        so ``"auto"`` is ``"plateau"``). The plateau's canopy height is the overview's typical
        plant radius (:func:`cliff_terrain.photo_heights.inflate.typical_plant_radius`), fixed for every
        tile: a height estimated per tile could cap a plant on one side of a border only.
    min_region : int, optional
        Regions smaller than this many pixels are dropped; default as
        :func:`cliff_terrain.photo_heights.segmentation.segment` picks it for one tile.
    tile : int, optional
        The tile size (for the default `min_region`).

    Returns
    -------
    MosaicSettings
    """
    from scipy import ndimage

    from ..photo_heights.holes import soil_level
    from ..photo_heights.inflate import resolve_profile, typical_plant_radius
    from ..photo_heights.labels import distance_map, label_max
    from ..photo_heights.quaternion import quaternion_filter
    from ..photo_heights.segmentation import segment
    from ..photo_heights.vegetation import blurred_index
    from ..photo_heights.watershed import colour_edges, default_edge_scale

    profile = resolve_profile(profile, "vegetation")
    exaggeration = check_float("exaggeration", exaggeration, minimum=0.0, strict_minimum=True)
    if min_region is None:
        min_region = max(4, int(2e-5 * tile * tile))
    min_region = check_int("min_region", min_region, minimum=0)
    rgb, valid, step = reader.overview()
    seg = segment(rgb, method="vegetation", valid=valid)
    # What split_regions would take from the whole image: the regions' typical radius and the
    # colour edges' scale (distances measured on the overview, in mosaic pixels).
    components, n = ndimage.label(seg.mask)
    if n:
        dmax = step * label_max(distance_map(seg.mask.astype(np.int32)), components)[1:]
        edge_scale = default_edge_scale(dmax, colour_edges(quaternion_filter(rgb)), seg.mask)
        radius = float(np.median(dmax))
    else:
        radius, edge_scale = 3.0, 0.0
    max_height = None
    if profile == "plateau":
        max_height = step * typical_plant_radius(seg.labels) or radius
    # The hole rule's soil level, the same for every tile (each window's own would differ).
    soil = soil_level(blurred_index(rgb, index=seg.index)[0], seg.mask)
    return MosaicSettings(
        seg.index,
        float(seg.threshold),
        min_region,
        profile,
        exaggeration,
        radius,
        edge_scale,
        max_height,
        soil,
        reader.scale,
    )


@dataclass
class TileRelief:
    """The relief of one tile, cut to its own area (``core``)."""

    core: tuple[int, int, int, int]
    mask: np.ndarray
    labels: np.ndarray
    heights: np.ndarray


def relief_tile(reader, window, settings):
    """Mask, regions and heights (in pixels) of one tile, computed on its window and cut to its core.

    Parameters
    ----------
    reader : MosaicReader or str or os.PathLike
        The mosaic, or its path (opened for this tile only: a Dask task can take the path, a
        window and the settings, all of them picklable).
    window : TileWindow
    settings : MosaicSettings

    Returns
    -------
    TileRelief
        ``labels`` are numbered within the tile (0 = ground).
    """
    if isinstance(reader, str | os.PathLike):
        with MosaicReader(reader, scale=settings.scale) as opened:
            return relief_tile(opened, window, settings)
    from ..photo_heights.inflate import inflate
    from ..photo_heights.quaternion import quaternion_filter
    from ..photo_heights.segmentation import segment, vegetation_mask

    wr0, wr1, wc0, wc1 = window.window
    r0, r1, c0, c1 = window.core
    rgb, valid = reader.read(wr0, wr1, wc0, wc1)
    # The mask of the whole window, with what the whole mosaic fixed (threshold, soil) ...
    mask, _ = vegetation_mask(
        rgb,
        index=settings.index,
        valid=valid,
        threshold=settings.threshold,
        min_region=settings.min_region,
        soil=settings.soil,
    )
    # ... then segment() and inflate() only as far as the plants that reach the tile's own area
    # and what their watershed and heights read around them (see _reach): the same labels and
    # heights in the core as on the whole window, on about a third fewer pixels.
    core = (r0 - wr0, r1 - wr0, c0 - wc0, c1 - wc0)
    box = _reach(mask, core, settings) if settings.profile in ("plateau", "circular") else None
    if box is None:
        box = (0, wr1 - wr0, 0, wc1 - wc0)
    b0, b1, d0, d1 = box
    part = (slice(b0, b1), slice(d0, d1))
    seg = segment(
        rgb[part],
        filtered=quaternion_filter(rgb[part]),
        index=settings.index,
        min_region=settings.min_region,
        threshold=settings.threshold,
        radius=settings.radius,
        edge_scale=settings.edge_scale,
        soil=settings.soil,
        mask=mask[part],
    )
    heights = inflate(
        seg.labels,
        profile=settings.profile,
        exaggeration=settings.exaggeration,
        max_height=settings.max_height,
        distance=seg.region_distance,
        mask_distance=seg.distance,
    )
    cut = (slice(core[0] - b0, core[1] - b0), slice(core[2] - d0, core[3] - d0))
    return TileRelief(window.core, mask[core[0] : core[1], core[2] : core[3]], seg.labels[cut], heights[cut])


def _reach(mask, core, settings):
    """The part of a tile's window that its core's labels and heights depend on: (r0, r1, c0, c1).

    The plants (8-connected components of `mask`) that reach the core, with a band around them as
    wide as twice the watershed's marker radius and its blur (4 px) plus a pixel: within it lie the
    nearest ground pixel of every pixel whose distance those plants' markers read (the first pixel
    off a plant on the straight line to a pixel of another is ground), so distances, markers,
    basins and heights there are those of the whole window. The flooding of each component is the
    same; only plants wholly outside the core are left out or cut.
    """
    import cv2

    r0, r1, c0, c1 = core
    rows, cols = mask.shape
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.view(np.uint8), connectivity=8)
    if n <= 1:
        return core
    ring = np.concatenate(
        [labels[r0, c0:c1], labels[r1 - 1, c0:c1], labels[r0:r1, c0], labels[r0:r1, c1 - 1]]
    )
    touching = np.unique(ring)
    touching = touching[touching > 0]
    top, bottom, left, right = r0, r1, c0, c1
    if len(touching):
        box = stats[touching]
        top = min(top, int(box[:, cv2.CC_STAT_TOP].min()))
        left = min(left, int(box[:, cv2.CC_STAT_LEFT].min()))
        bottom = max(bottom, int((box[:, cv2.CC_STAT_TOP] + box[:, cv2.CC_STAT_HEIGHT]).max()))
        right = max(right, int((box[:, cv2.CC_STAT_LEFT] + box[:, cv2.CC_STAT_WIDTH]).max()))
    band = 2 * (int(np.clip(settings.radius, 3, 200)) + 4) + 2
    return max(0, top - band), min(rows, bottom + band), max(0, left - band), min(cols, right + band)


def relief_tiles(reader, *, tile=DEFAULT_TILE, overlap=DEFAULT_OVERLAP, settings=None, client=None, **kwargs):
    """The :class:`TileRelief` of every tile of a mosaic, one at a time (row by row).

    Memory follows the tile (about 1 GB for 4096-pixel tiles with a 512-pixel margin), not the
    mosaic: a caller that keeps only what it needs of each tile (an adaptive mesh, statistics)
    processes a mosaic of any size. Without a `client`, the next tile is computed in a thread while
    the caller works on this one (so two tiles' worth at most).

    Parameters
    ----------
    reader : MosaicReader
    tile, overlap : int, optional
        Tile side and the margin read around it, in mosaic pixels. Plants smaller than `overlap`
        get the same mask, region and heights as in one piece.
    settings : MosaicSettings, optional
        Default :func:`mosaic_settings` of the reader (`kwargs` go to it).
    client : distributed.Client, optional
        Run the tiles as tasks on this Dask client (each task opens the mosaic by its path, so the
        workers must see the same file; :func:`cliff_terrain.season.cluster.local_cluster` makes a
        local one). The tiles still come back one at a time and in order, with at most two per
        worker computed ahead, so memory here stays a few tiles; each worker holds one tile's.
        The client is left open. Tiles not yet taken when the caller stops are cancelled.

    Returns
    -------
    iterator of TileRelief
        Computed as they are taken (the arguments and the overview are checked at the call).

    Examples
    --------
    >>> from distributed import Client  # doctest: +SKIP
    >>> from cliff_terrain.season.cluster import local_cluster  # doctest: +SKIP
    >>> with local_cluster(2) as cluster, Client(cluster) as client, MosaicReader(path) as mosaic:  # doctest: +SKIP
    ...     for part in relief_tiles(mosaic, client=client):
    ...         print(part.core, part.heights.max())
    """
    # Not a generator itself, so that bad arguments and the overview fail here, not at the first tile.
    if client is not None and not callable(getattr(client, "submit", None)):
        raise CliffTerrainError(f"`client` must be a distributed.Client, got {client!r}")
    windows = tile_windows(reader.shape, tile=tile, overlap=overlap)
    if settings is None:
        settings = mosaic_settings(reader, tile=tile, **kwargs)
    if client is None:
        return _one_ahead(relief_tile(reader, window, settings) for window in windows)
    return _tiles_on_dask(client, reader.path, windows, settings)


_END = object()


def _one_ahead(tiles):
    """The items of the iterator `tiles`, each next one computed in a thread while the caller works
    on this one.

    A tile's relief is mostly OpenCV and numpy calls, which release the GIL, so it runs beside what
    the caller does with the previous tile (its TIN, its Blender objects): on two cores the 419 MP
    benchmark's mosaic went from 2.7 to 3.2-3.3 MP/s, its peak memory from 1.5 to 1.8 GB (README,
    "Adaptive mesh and big orthomosaics").
    If the caller stops early, the tile in progress is finished and dropped.
    """
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(1, thread_name_prefix="cliff_terrain_tile") as pool:
        ahead = pool.submit(next, tiles, _END)
        while True:
            tile = ahead.result()  # a tile's exception is raised here, as in a loop
            if tile is _END:
                return
            ahead = pool.submit(next, tiles, _END)
            yield tile


def _tiles_on_dask(client, path, windows, settings):
    """relief_tile(path, window, settings) of each window as Dask tasks, results in order, two per
    worker ahead."""
    from .._dask import in_order

    ahead = 2 * max(1, len(client.scheduler_info().get("workers", {})))
    return in_order(client, relief_tile, ((path, window, settings) for window in windows), ahead=ahead)
