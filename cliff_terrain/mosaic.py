"""Orthomosaics larger than memory: read a tiled GeoTIFF in windows, build the relief tile by tile.

A whole farm's orthomosaic has hundreds of megapixels. :class:`MosaicReader` reads any window of a
*tiled* GeoTIFF by decoding only the TIFF tiles it overlaps (one at a time), so memory follows the
window, not the image. A striped (untiled) GeoTIFF cannot be read that way; above
`max_striped_pixels` it is refused with the command that tiles it.

:func:`relief_tiles` then builds the relief in tiles of `tile` x `tile` pixels, each read with an
`overlap` margin on every side and cut back to its own area, so that a plant crossing a tile's
border lies whole in the windows of both tiles and gets the same mask, region and heights in
each, as it would in one piece (plants smaller than the margin). Settings that depend on the whole
image are fixed first, from an overview read with every TIFF tile decoded once: the vegetation
index and its threshold (as :func:`cliff_terrain.segmentation.segment` picks them for the
overview). Tiles are independent: each is a call of :func:`relief_tile`, which a Dask task can
run as well.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import cv2
import numpy as np

from ._validate import check_choice, check_float, check_int
from .errors import CliffTerrainError, ImageReadError, ImageTooLargeError

# A striped GeoTIFF is decoded whole: above this many pixels (a 12-bit 150 MP RGB image is 0.9 GB
# decoded) it is refused with the command that tiles it.
MAX_STRIPED_PIXELS = 150_000_000
DEFAULT_TILE = 4096
DEFAULT_OVERLAP = 512
# The overview that fixes the threshold: at most this many pixels.
OVERVIEW_PIXELS = 4_000_000


class MosaicReader:
    """Windows of a GeoTIFF orthomosaic, decoding only the TIFF tiles a window overlaps.

    Parameters
    ----------
    path : str or os.PathLike
        A GeoTIFF (or plain TIFF) with RGB(A) samples, uint8, uint16 or float.
    max_striped_pixels : int, optional
        A striped (untiled) TIFF up to this many pixels is decoded whole and served from memory;
        above it is refused (:class:`ImageTooLargeError`) with how to tile it.

    Examples
    --------
    >>> with MosaicReader(path) as mosaic:  # doctest: +SKIP
    ...     rgb, valid = mosaic.read(0, 512, 0, 512)
    """

    def __init__(self, path, *, max_striped_pixels=MAX_STRIPED_PIXELS):
        import tifffile

        self.path = os.fspath(path)
        max_striped_pixels = check_int("max_striped_pixels", max_striped_pixels, minimum=1)
        if not os.path.isfile(self.path):
            raise ImageReadError(f"mosaic {self.path!r} does not exist")
        try:
            self._tif = tifffile.TiffFile(self.path)
        except (tifffile.TiffFileError, OSError, EOFError) as exc:
            raise ImageReadError(f"cannot read {self.path!r} as a TIFF: {exc}") from None
        page = self._tif.pages[0]
        self._page = page
        self.shape = (int(page.imagelength), int(page.imagewidth))
        self.planar = page.planarconfig == 2 and page.samplesperpixel > 1
        self._nodata = _nodata(page)
        self._whole = None
        if page.is_tiled:
            if self.planar:
                self.close()
                raise ImageReadError(
                    f"mosaic {self.path!r} stores its bands in separate planes; windows need "
                    "pixel-interleaved tiles: gdal_translate -co TILED=YES -co INTERLEAVE=PIXEL IN.tif OUT.tif"
                )
            self.tile_shape = (int(page.tilelength), int(page.tilewidth))
            self._tiles_across = math.ceil(self.shape[1] / self.tile_shape[1])
        else:
            pixels = self.shape[0] * self.shape[1]
            if pixels > max_striped_pixels:
                self.close()
                raise ImageTooLargeError(
                    f"mosaic {self.path!r} is a striped (untiled) TIFF of {self.shape[1]} x {self.shape[0]} "
                    f"pixels ({pixels / 1e6:.0f} MP), too big to decode whole (limit "
                    f"{max_striped_pixels / 1e6:.0f} MP) and not readable in windows; tile it first, for "
                    "example: gdal_translate -co TILED=YES -co COMPRESS=DEFLATE IN.tif OUT.tif"
                )
            self.tile_shape = self.shape
        try:
            from .georaster import read_georeference

            self.transform, self.crs = read_georeference(self.path)
        except CliffTerrainError:
            self.transform, self.crs = None, None  # a plain TIFF: no georeference

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def close(self):
        self._tif.close()

    @property
    def gsd(self):
        """Metres per pixel from the georeference, or None."""
        if self.transform is None:
            return None
        return float(np.hypot(*self.transform[:2, 0]))

    def read(self, r0, r1, c0, c1):
        """Pixels [r0:r1, c0:c1] as RGB uint8 and a valid mask (None when every pixel holds data).

        Only the TIFF tiles the window overlaps are read and decoded, one at a time.
        """
        rows, cols = self.shape
        if not (0 <= r0 < r1 <= rows and 0 <= c0 < c1 <= cols):
            raise CliffTerrainError(
                f"window [{r0}:{r1}, {c0}:{c1}] is not inside the mosaic's {rows} x {cols}"
            )
        raw = self._raw(r0, r1, c0, c1)
        from .georaster import photo_bands

        return photo_bands(
            raw, self.path, nodata=self._nodata, planar=self.planar and not self._page.is_tiled
        )

    def _raw(self, r0, r1, c0, c1):
        page = self._page
        if not page.is_tiled:
            if self._whole is None:
                self._whole = page.asarray()
                if self.planar:
                    self._whole = np.moveaxis(self._whole, 0, -1)
            return self._whole[r0:r1, c0:c1]
        th, tw = self.tile_shape
        samples = int(page.samplesperpixel)
        out = np.empty((r1 - r0, c1 - c0, samples), dtype=page.dtype)
        for tr in range(r0 // th, (r1 - 1) // th + 1):
            for tc in range(c0 // tw, (c1 - 1) // tw + 1):
                segment = self._decode_tile(tr * self._tiles_across + tc).reshape(th, tw, samples)
                # The part of this tile inside the window.
                ar0, ar1 = max(r0, tr * th), min(r1, (tr + 1) * th)
                ac0, ac1 = max(c0, tc * tw), min(c1, (tc + 1) * tw)
                out[ar0 - r0 : ar1 - r0, ac0 - c0 : ac1 - c0] = segment[
                    ar0 - tr * th : ar1 - tr * th, ac0 - tc * tw : ac1 - tc * tw
                ]
        return out

    def _decode_tile(self, index):
        """Read and decode TIFF tile `index` (row-major) alone."""
        page, fh = self._page, self._tif.filehandle
        fh.seek(page.dataoffsets[index])
        data = fh.read(page.databytecounts[index])
        segment, _, _ = page.decode(data, index, jpegtables=page.jpegtables)
        return segment

    def overview(self, *, max_pixels=OVERVIEW_PIXELS):
        """The whole mosaic reduced by an integer step (every `step`-th pixel) to at most `max_pixels`.

        Returns
        -------
        rgb : (rows', cols', 3) uint8
        valid : (rows', cols') bool or None
        step : int
        """
        rows, cols = self.shape
        step = max(1, math.ceil(math.sqrt(rows * cols / max_pixels)))
        out_rows, out_cols = math.ceil(rows / step), math.ceil(cols / step)
        rgb = np.zeros((out_rows, out_cols, 3), np.uint8)
        valid = np.ones((out_rows, out_cols), bool)
        # A band of TIFF tiles at a time (whole rows of tiles), so each tile is decoded once.
        band = max(self.tile_shape[0], step)
        band -= band % step or 0
        band = max(band, step)
        for r0 in range(0, rows, band):
            r1 = min(rows, r0 + band)
            part, ok = self.read(r0, r1, 0, cols)
            rgb[r0 // step : r0 // step + len(range(0, r1 - r0, step))] = part[::step, ::step]
            if ok is not None:
                valid[r0 // step : r0 // step + len(range(0, r1 - r0, step))] = ok[::step, ::step]
        return rgb, (None if valid.all() else valid), step


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


def mosaic_settings(reader, *, profile="circular", exaggeration=1.0, min_region=None, tile=DEFAULT_TILE):
    """The vegetation index and threshold for the whole mosaic, from its overview.

    Parameters
    ----------
    reader : MosaicReader
    profile, exaggeration
        As in :func:`cliff_terrain.build_relief`.
    min_region : int, optional
        Regions smaller than this many pixels are dropped; default as
        :func:`cliff_terrain.segmentation.segment` picks it for one tile.
    tile : int, optional
        The tile size (for the default `min_region`).

    Returns
    -------
    MosaicSettings
    """
    from scipy import ndimage

    from .heights import PROFILES
    from .quaternion import quaternion_filter
    from .segmentation import colour_edges, distance_map, label_max, segment

    check_choice("profile", profile, PROFILES)
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
        edges = colour_edges(quaternion_filter(rgb))
        sample = edges.ravel()[::7][seg.mask.ravel()[::7]]
        edge_scale = 0.5 * float(np.percentile(dmax, 90)) / (float(np.percentile(sample, 99)) + 1e-6)
        radius = float(np.median(dmax))
    else:
        radius, edge_scale = 3.0, 0.0
    return MosaicSettings(
        seg.index, float(seg.threshold), min_region, profile, exaggeration, radius, edge_scale
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
        with MosaicReader(reader) as opened:
            return relief_tile(opened, window, settings)
    from skimage.morphology import remove_small_holes, remove_small_objects

    from .heights import inflate
    from .quaternion import quaternion_filter
    from .segmentation import colour_edges, distance_map, split_regions, vegetation_index

    wr0, wr1, wc0, wc1 = window.window
    rgb, valid = reader.read(wr0, wr1, wc0, wc1)
    vi, _ = vegetation_index(rgb, index=settings.index)
    # As segment() does: a light blur, so single noisy pixels neither rise nor punch holes.
    vi = cv2.GaussianBlur(vi, (0, 0), 1.0)
    mask = vi > settings.threshold
    if valid is not None:
        mask &= valid
    if settings.min_region:
        mask = remove_small_objects(mask, settings.min_region)
        mask = remove_small_holes(mask, settings.min_region)
    edges = colour_edges(quaternion_filter(rgb))
    labels = split_regions(
        mask, distance_map(mask), edges=edges, radius=settings.radius, edge_scale=settings.edge_scale
    )
    heights = inflate(labels, profile=settings.profile, exaggeration=settings.exaggeration)
    r0, r1, c0, c1 = window.core
    cut = (slice(r0 - wr0, r1 - wr0), slice(c0 - wc0, c1 - wc0))
    return TileRelief(window.core, mask[cut], labels[cut], heights[cut])


def relief_tiles(reader, *, tile=DEFAULT_TILE, overlap=DEFAULT_OVERLAP, settings=None, client=None, **kwargs):
    """The :class:`TileRelief` of every tile of a mosaic, one at a time (row by row).

    Memory follows the tile (about 1 GB for 4096-pixel tiles with a 512-pixel margin), not the
    mosaic: a caller that keeps only what it needs of each tile (an adaptive mesh, statistics)
    processes a mosaic of any size.

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
        workers must see the same file; :func:`cliff_terrain.season.runner.local_cluster` makes a
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
    >>> from cliff_terrain.season.runner import local_cluster  # doctest: +SKIP
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
        return (relief_tile(reader, window, settings) for window in windows)
    return _tiles_on_dask(client, reader.path, windows, settings)


def _tiles_on_dask(client, path, windows, settings):
    """relief_tile(path, window, settings) of each window as Dask tasks, results in order, bounded ahead."""
    import collections
    import itertools

    ahead = 2 * max(1, len(client.scheduler_info().get("workers", {})))
    pending = iter(windows)
    futures = collections.deque()

    def submit(batch):
        futures.extend(client.submit(relief_tile, path, window, settings, pure=False) for window in batch)

    submit(itertools.islice(pending, ahead))
    try:
        while futures:
            result = futures.popleft().result()  # a task's exception is raised here, as in a loop
            submit(itertools.islice(pending, 1))
            yield result
    finally:
        if futures:  # the caller stopped early or a tile failed: drop the tiles still queued
            client.cancel(list(futures))


def _nodata(page):
    tag = page.tags.get(42113)  # GDAL_NODATA
    if tag is None:
        return None
    try:
        return float(str(tag.value).strip("\x00 "))
    except ValueError:
        return None
