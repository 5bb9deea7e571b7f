"""`build_relief`: the paper's whole pipeline, photo to textured relief mesh, with every stage kept."""

from __future__ import annotations

import os
import queue
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Protocol

import cv2
import numpy as np

from ._validate import check_choice, check_float, check_int, check_rgb
from .errors import CliffTerrainError
from .heights import PROFILES, inflate
from .image_io import ImageMetadata, OpenImage, open_image
from .mesh import MeshArrays, MeshSizes, adaptive_mesh, grid_sizes, grid_topology, place_vertices
from .quaternion import quaternion_filter
from .segmentation import METHODS, Segmentation, _before_watershed, distance_map, segment
from .settings import (
    DEFAULT_EXAGGERATION,
    DEFAULT_GROUND_BLOCK_M,
    DEFAULT_MAX_SIZE,
    DEFAULT_MESH,
    DEFAULT_PROFILE,
    DEFAULT_SEGMENTATION,
    MAX_SIZE,
    MESHES,
    MIN_EXAGGERATION,
    MIN_SIZE,
    ids,
)
from .tin import default_max_error


class MeshSink(Protocol):
    """What :func:`build_relief` hands the mesh to, step by step (its `mesh_sink`).

    Every method is called in the thread that called :func:`build_relief`, once, in this order,
    each at the moment the worker thread least needs the GIL: work that holds the GIL for long
    (Blender's bulk calls do) stalls the worker at each of its steps that need it.
    """

    def allocate(self, sizes: MeshSizes) -> None:
        """The mesh's sizes, as soon as the grid's shape is known (the photo's header is read).

        The worker is decoding and resizing the photo, in few long calls that release the GIL:
        the time to allocate.
        """

    def prepare(self, mesh: MeshArrays) -> None:
        """Faces, corners, UVs and edges (the vertices are not placed yet).

        The worker is running many short numpy steps: work here should release the GIL too
        (numpy checks, layouts), not hold it.
        """

    def fill(self) -> None:
        """The worker is inside the watershed, one long call that releases the GIL: the time
        to copy what `prepare` was given."""


@dataclass
class Relief:
    """Every stage of :func:`build_relief`.

    Arrays of the processing grid have shape (rows, cols) = the working image's.

    Attributes
    ----------
    image : (rows0, cols0, 3) uint8
        The photo as loaded (possibly decoded reduced, see ``metadata.reduction``).
    metadata : ImageMetadata
        Source, camera and ground sampling distance.
    working : (rows, cols, 3) uint8
        The photo resized to the processing size.
    filtered : (rows, cols, 3) float32
        Quaternion filter output.
    mask, labels, boundaries : (rows, cols) bool, int32, bool
        Segmentation.
    distance : (rows, cols) float32
        Euclidean distance map per region, in processing pixels.
    heights : (rows, cols) float32
        Heights in `units`.
    mesh : MeshArrays or None
        The relief mesh, x/y/z in `units` (None when built with ``mesh=None``).
    units : {"m", "px"}
        Metres when the ground sampling distance is known, else processing pixels.
    pixel_size : float
        Size of one processing pixel in `units`.
    params : dict
        The settings of the call.
    timings : dict
        Seconds per stage.
    max_error : float or None
        The adaptive mesh's maximum vertical error in `units` (None for the grid).
    """

    image: np.ndarray
    metadata: ImageMetadata
    working: np.ndarray
    filtered: np.ndarray
    mask: np.ndarray
    labels: np.ndarray
    boundaries: np.ndarray
    distance: np.ndarray
    heights: np.ndarray
    mesh: MeshArrays | None
    units: str
    pixel_size: float
    params: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    max_error: float | None = None
    canopy: object = None  # a cliff_terrain.canopy.Canopy on the processing grid when built with a DSM

    @property
    def n_regions(self) -> int:
        return int(self.labels.max(initial=0))

    @property
    def max_height(self) -> float:
        return float(self.heights.max(initial=0.0))


def build_relief(
    image_or_path,
    *,
    max_size=DEFAULT_MAX_SIZE,
    segmentation=DEFAULT_SEGMENTATION,
    profile=DEFAULT_PROFILE,
    exaggeration=DEFAULT_EXAGGERATION,
    max_height=None,
    gsd=None,
    two_sided=True,
    mesh=DEFAULT_MESH,
    max_error=None,
    progress=None,
    mesh_sink=None,
    dsm=None,
    dtm=None,
    heights="inflated",
    ground_block=None,
):
    """Turn one UAV photo into a relief: filter, segment, inflate, mesh.

    Parameters
    ----------
    image_or_path : str, os.PathLike or (rows, cols, 3) array
        A photo file (JPEG, PNG, TIFF; see :func:`load_image`) or an RGB array (uint8, or float in
        [0, 1]).
    max_size : int, optional
        Longest side of the processing grid in pixels (16 to 16384); smaller photos are not
        enlarged. The mesh has (rows + 1) x (cols + 1) front vertices.
    segmentation : {"vegetation", "paper"}, optional
        ``"vegetation"``: plants rise and soil stays flat. ``"paper"``: the paper's Algorithm 2 as
        printed (Otsu on the filtered image's brightness; it may raise bright soil). See
        :mod:`cliff_terrain.segmentation`.
    profile : {"auto", "circular", "poisson", "plateau"}, optional
        Cross-section of each region (see :func:`cliff_terrain.heights.inflate`); ``"plateau"``
        levels closed canopy off at `max_height`. ``"auto"``: ``"plateau"`` with the vegetation
        segmentation, the paper's ``"circular"`` with the paper's.
    exaggeration : float, optional
        Height factor (> 0).
    max_height : float, optional
        Canopy height (> 0, finite), in metres when the ground sampling distance is known, else in
        processing pixels; before `exaggeration`. With ``profile="plateau"`` the height at which
        closed canopy levels off (default: the radius of a typical isolated plant, see
        :func:`cliff_terrain.heights.typical_plant_radius`); with the other profiles a cap.
    gsd : float, optional
        Ground sampling distance of the *original* photo in metres per pixel; wins over what
        the camera metadata gives. With a GSD the heights and the mesh are in metres.
    dsm : str or os.PathLike, optional
        A digital surface model GeoTIFF (metres, projected CRS) of the orthophoto
        `image_or_path` (a georeferenced GeoTIFF): the heights are then measured. It is resampled
        onto the processing grid; ``Relief.canopy`` holds the DSM, ground and canopy height there,
        and ``params["georeference"]`` the grid's CRS and map origin (the mesh starts at 0, 0).
    dtm : str or os.PathLike, optional
        A terrain model: the ground; without it the ground is estimated from the soil pixels
        (see :func:`cliff_terrain.ground.estimate_ground`).
    ground_block : float, optional
        Block size in metres of the estimated ground's trend (default 5; see
        :func:`cliff_terrain.ground.estimate_ground`); only with a `dsm` and no `dtm`.
    heights : {"inflated", "calibrated", "measured"}, optional
        ``"inflated"``: domes from the photo (the only mode without a DSM). ``"measured"``: the
        canopy height model. ``"calibrated"``: each region's dome scaled so its top equals the
        region's measured p99 height (photo-resolution shapes, measured heights).
    two_sided : bool, optional
        Close the relief into a watertight solid with a base (back UVs have u > 1).
    mesh : {"grid", "adaptive"} or None, optional
        ``"grid"``: one vertex per pixel corner. ``"adaptive"``: a triangulated irregular network
        within `max_error` of every pixel's height at its centre, with far fewer triangles where
        the ground is flat (see :func:`cliff_terrain.mesh.adaptive_mesh`); `mesh_sink` is then
        not called, as the mesh's size is known only at the end. None: no mesh, only the
        heights (what tables need, e.g. a season's); everything runs in the calling thread.
    max_error : float, optional
        The adaptive mesh's largest vertical error, in the relief's units (metres with a GSD,
        else processing pixels; > 0). Default: 5 mm with a GSD, else 1 % of the relief's height
        (:func:`cliff_terrain.tin.default_max_error`); ``Relief.max_error`` is the value used.
    progress : callable, optional
        ``progress(fraction, stage)`` is called as each stage starts, fraction in [0, 1], always
        in the calling thread (a GUI may update itself from it).
    mesh_sink : MeshSink, optional
        Receives the mesh step by step, in the calling thread, while decoding, filter,
        segmentation and heights run in a worker thread, so that a caller can fill a mesh of its
        own in parallel (the Blender add-on does: 0.13 to 0.19 s of its 0.85 s on 2 idle cores).
        Each step comes when the worker least needs the GIL, which work such as Blender's bulk
        calls holds throughout: see :class:`MeshSink`. The mesh it is given, with its vertices
        placed, is ``Relief.mesh``. Whatever it raises propagates once the worker has finished.

    Returns
    -------
    Relief

    Examples
    --------
    >>> from cliff_terrain.synthetic import synthetic_field
    >>> img, truth = synthetic_field(shape=(240, 360), n_rows=2, seed=3)
    >>> relief = build_relief(img, max_size=360)
    >>> relief.n_regions == truth.n_plants, relief.units
    (True, 'px')
    """
    max_size = check_int("max_size", max_size, minimum=MIN_SIZE, maximum=MAX_SIZE)
    check_choice("segmentation", segmentation, METHODS)
    check_choice("profile", profile, PROFILES)
    if profile == "auto":  # the paper's Algorithm 3 with its Algorithm 2; closed canopy levelled else
        profile = "plateau" if segmentation == "vegetation" else "circular"
    exaggeration = check_float("exaggeration", exaggeration, minimum=MIN_EXAGGERATION, strict_minimum=True)
    max_height = check_float("max_height", max_height, minimum=0.0, strict_minimum=True, allow_none=True)
    gsd = check_float("gsd", gsd, minimum=0.0, strict_minimum=True, allow_none=True)
    if not isinstance(two_sided, bool | np.bool_):
        raise CliffTerrainError(f"`two_sided` must be True or False, got {two_sided!r}")
    if mesh is not None:
        check_choice("mesh", mesh, ids(MESHES))
    if mesh is None and mesh_sink is not None:
        raise CliffTerrainError(f"`mesh_sink` needs a mesh, got mesh=None and mesh_sink={mesh_sink!r}")
    max_error = check_float("max_error", max_error, minimum=0.0, strict_minimum=True, allow_none=True)
    if progress is not None and not callable(progress):
        raise CliffTerrainError(f"`progress` must be callable or None, got {progress!r}")
    if mesh_sink is not None and not all(
        callable(getattr(mesh_sink, step, None)) for step in ("allocate", "prepare", "fill")
    ):
        raise CliffTerrainError(
            f"`mesh_sink` must have methods allocate, prepare and fill, or be None, got {mesh_sink!r}"
        )
    # Measured heights (issue 13): the photo must be a georeferenced orthophoto of the DSM.
    heights_mode = _check_heights(heights, dsm, dtm, image_or_path)
    if ground_block is not None:
        ground_block = check_float("ground_block", ground_block, minimum=0.0, strict_minimum=True)
    params = {
        "max_size": max_size,
        "segmentation": segmentation,
        "profile": profile,
        "exaggeration": exaggeration,
        "max_height": max_height,
        "gsd": gsd,
        "two_sided": bool(two_sided),
        "mesh": mesh,
        "max_error": max_error,
        "heights": heights_mode,
        "dsm": None if dsm is None else os.fspath(dsm),
        "dtm": None if dtm is None else os.fspath(dtm),
    }
    timings = {}
    if progress is not None:
        progress(0.0, "load")
    if isinstance(image_or_path, str | os.PathLike):
        # The header now (its errors at once, and the grid's shape), the pixels in the worker.
        source = open_image(image_or_path, max_size=max_size, gsd=gsd)
        source_shape = source.shape
    else:
        source = _from_array(image_or_path, gsd)
        source_shape = source[0].shape[:2]
    grid_shape = resized_shape(source_shape, max_size)

    args = (source, max_size, segmentation, profile, exaggeration, max_height)
    if mesh == "grid":
        stages = _with_grid_topology(args, grid_shape, bool(two_sided), mesh_sink, progress, timings)
        mesh_arrays = stages.topology
    else:
        # An adaptive mesh's size depends on the heights: it is built at the end, in one go, and
        # nothing is left to overlap with the image's stages.
        try:
            stages = _image_stages(
                *args, clock=_Stages(progress, timings, stage="load"), on_watershed=lambda: None
            )
        finally:
            if isinstance(source, OpenImage):
                source.close()
    metadata, working = stages.metadata, stages.working
    seg = stages.segmentation
    # Which plant/soil threshold the photo got, and why (the photo's own, or the prior band).
    params["threshold"] = {
        "index": seg.index,
        "value": round(float(seg.threshold), 4),
        "source": seg.threshold_source,
        "valley": round(float(seg.valley), 3),  # NaN in paper mode
    }
    clock = _Stages(progress, timings)
    clock.start("mesh", 0.8)

    rows, cols = working.shape[:2]
    if metadata.gsd_m_per_px:
        units = "m"
        # The GSD is per original pixel; the grid is coarser by the original width over its own.
        pixel_size = float(metadata.gsd_m_per_px) * metadata.width / cols
    else:
        units, pixel_size = "px", 1.0
    heights = stages.heights_px * np.float32(pixel_size) if units == "m" else stages.heights_px
    canopy = None
    if dsm is not None:
        from .canopy import relief_heights

        canopy, heights, pixel_size, params["georeference"] = relief_heights(
            image_or_path,
            stages,
            dsm=dsm,
            dtm=dtm,
            mode=heights_mode,
            exaggeration=exaggeration,
            block_m=DEFAULT_GROUND_BLOCK_M if ground_block is None else ground_block,
        )
        units = "m"
    if mesh is None:
        relief_mesh = None
    elif mesh == "grid":
        relief_mesh = place_vertices(mesh_arrays, heights, pixel_size=pixel_size)
    else:
        if max_error is None:
            max_error = default_max_error(heights, units=units, pixel_size=pixel_size)
        relief_mesh = adaptive_mesh(
            heights, max_error=max_error, pixel_size=pixel_size, two_sided=bool(two_sided)
        )
    clock.start(None, 1.0)

    return Relief(
        image=stages.image,
        metadata=metadata,
        working=working,
        filtered=stages.filtered,
        mask=stages.segmentation.mask,
        labels=stages.segmentation.labels,
        boundaries=stages.segmentation.boundaries,
        distance=stages.distance,
        heights=heights,
        mesh=relief_mesh,
        units=units,
        pixel_size=pixel_size,
        params=params,
        timings=timings,
        max_error=max_error if mesh == "adaptive" else None,
        canopy=canopy,
    )


def _check_heights(heights, dsm, dtm, image_or_path):
    """The heights mode, checked against the surface models it needs."""
    from .settings import HEIGHT_MODES

    mode = check_choice("heights", heights, ids(HEIGHT_MODES))
    if dsm is None and dtm is not None:
        raise CliffTerrainError(f"`dtm` needs a `dsm`, got dtm={os.fspath(dtm)!r} and dsm=None")
    if dsm is None and mode != "inflated":
        raise CliffTerrainError(f"`heights` {mode!r} needs a `dsm` (a surface model GeoTIFF), got None")
    if dsm is not None and not isinstance(image_or_path, str | os.PathLike):
        raise CliffTerrainError(
            "`dsm` needs `image_or_path` to be a georeferenced orthophoto file, got an array"
        )
    return mode


def _with_grid_topology(args, grid_shape, two_sided, mesh_sink, progress, timings):
    """The image's stages, computed in a worker thread while this one builds the grid's topology.

    Decoding, resizing, filter, segmentation and heights run in the worker while this thread
    builds the mesh's faces, UVs and edges, which depend on the grid's shape only. The result's
    ``topology`` holds them.
    """
    source = args[0]
    worker = _Worker(progress, timings, _image_stages, *args)
    started = time.perf_counter()
    try:
        topology = _topology(grid_shape, two_sided, mesh_sink, worker)
    finally:
        timings["topology"] = time.perf_counter() - started
        worker.relay(wait=True)
        if isinstance(source, OpenImage):
            source.close()  # the worker has finished; it may have failed before decoding
    stages = worker.result()
    stages.topology = topology
    return stages


def _topology(grid_shape, two_sided, mesh_sink, worker):
    """The mesh's faces, UVs and edges, handed to `mesh_sink` step by step in time with `worker`."""
    if mesh_sink is None:
        return grid_topology(grid_shape, two_sided=two_sided)
    # The worker is decoding and resizing the photo, in calls that release the GIL.
    mesh_sink.allocate(grid_sizes(grid_shape, two_sided=two_sided))
    worker.relay()
    mesh_arrays = grid_topology(grid_shape, two_sided=two_sided)
    mesh_sink.prepare(mesh_arrays)
    worker.relay()
    # Work that holds the GIL stalls the worker at each of its many short numpy steps; while
    # the worker is inside the watershed it stalls it the least.
    worker.gil_free.wait()
    mesh_sink.fill()
    return mesh_arrays


@dataclass
class _ImageStages:
    """What the worker thread computes: the photo's stages up to the heights in processing pixels."""

    image: np.ndarray
    metadata: ImageMetadata
    working: np.ndarray
    filtered: np.ndarray
    segmentation: Segmentation
    distance: np.ndarray
    heights_px: np.ndarray
    topology: MeshArrays | None = None  # the grid's, built beside these stages


class _Worker:
    """Runs ``task(*args, clock=..., on_watershed=...)`` in a thread; relays its progress.

    The task reports its stages through `clock` (started at "load"); :meth:`relay` passes them
    on to `progress` in the calling thread. `gil_free` is set when the task calls `on_watershed`
    (its long GIL-free stretch starts) or ends, whichever comes first.
    """

    def __init__(self, progress, timings, task, *args):
        self.progress = progress
        self.gil_free = threading.Event()
        self._events = queue.SimpleQueue()
        self._done = False
        clock = _Stages(lambda fraction, stage: self._events.put((fraction, stage)), timings, stage="load")
        pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="cliff_terrain")
        self._future = pool.submit(task, *args, clock=clock, on_watershed=self.gil_free.set)
        self._future.add_done_callback(self._finished)
        pool.shutdown(wait=False)  # the thread ends with its one task

    def _finished(self, _future):
        self.gil_free.set()
        self._events.put(None)  # the end of its events

    def relay(self, *, wait=False):
        """Pass the task's progress on; with `wait`, until the task has finished."""
        while not self._done:
            try:
                event = self._events.get(block=wait)
            except queue.Empty:
                return
            if event is None:
                self._done = True
            elif self.progress is not None:
                self.progress(*event)

    def result(self):
        """The task's result (or its exception), once all its progress is relayed."""
        self.relay(wait=True)
        return self._future.result()


def _image_stages(source, max_size, segmentation, profile, exaggeration, max_height, *, clock, on_watershed):
    """Decode, resize, filter, segment and inflate (in the worker thread; `clock` is at "load")."""
    image, metadata = source.decode() if isinstance(source, OpenImage) else source
    clock.start("resize", 0.1)
    working = resize_longest(image, max_size)

    clock.start("filter", 0.2)
    filtered = quaternion_filter(working)

    clock.start("segment", 0.35)
    valid = None
    if metadata.valid_mask is not None:  # an orthophoto's no-data area stays flat
        size = working.shape[1::-1]
        valid = cv2.resize(metadata.valid_mask.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0
    with _before_watershed(on_watershed):
        seg = segment(working, method=segmentation, filtered=filtered, valid=valid)
    on_watershed()  # no watershed was needed: the heights are the next long stretch

    clock.start("heights", 0.6)
    distance = distance_map(seg.labels)
    if max_height is not None and metadata.gsd_m_per_px:  # metres -> processing pixels
        max_height /= float(metadata.gsd_m_per_px) * metadata.width / working.shape[1]
    heights_px = inflate(
        seg.labels,
        profile=profile,
        exaggeration=exaggeration,
        distance=distance,
        max_height=max_height,
        mask_distance=seg.distance,
    )
    clock.start(None, None)
    return _ImageStages(image, metadata, working, filtered, seg, distance, heights_px)


class _Stages:
    """Times the stages and reports progress as each one starts.

    ``start(None, None)`` closes the last stage without reporting (a worker's stages end where
    the caller's next one starts).
    """

    def __init__(self, progress, timings, *, stage=None):
        self.progress = progress
        self.timings = timings
        self.stage = stage  # already started (and reported) by the caller, if given
        self.t0 = time.perf_counter()

    def start(self, stage, fraction):
        now = time.perf_counter()
        if self.stage is not None:
            self.timings[self.stage] = now - self.t0
        self.stage, self.t0 = stage, now
        if self.progress is not None and fraction is not None:
            self.progress(fraction, stage or "done")


def _from_array(image, gsd):
    image = check_rgb("image_or_path", image, min_size=2)
    if image.dtype != np.uint8:
        if image.min() < 0.0 or image.max() > 1.0:
            raise CliffTerrainError(
                f"`image_or_path` as a float array must hold values in [0, 1], got [{image.min():.3g}, {image.max():.3g}]"
            )
        image = np.round(image * 255.0).astype(np.uint8)
    rows, cols = image.shape[:2]
    metadata = ImageMetadata(
        path="",
        format="array",
        mode="RGB",
        width=cols,
        height=rows,
        decoded_width=cols,
        decoded_height=rows,
        gsd_m_per_px=gsd,
        gsd_source="user" if gsd is not None else None,
    )
    return np.ascontiguousarray(image), metadata


def resize_longest(image, max_size):
    """Shrink `image` so its longest side is at most `max_size` (area averaging); never enlarge.

    Parameters
    ----------
    image : (rows, cols, 3) uint8 array
    max_size : int

    Returns
    -------
    (rows', cols', 3) uint8 array
        The same array when no shrinking is needed.
    """
    image = check_rgb("image", image)
    max_size = check_int("max_size", max_size, minimum=1)
    rows, cols = resized_shape(image.shape[:2], max_size)
    if (rows, cols) == image.shape[:2]:
        return image
    return cv2.resize(image, (cols, rows), interpolation=cv2.INTER_AREA)


def resized_shape(shape, max_size):
    """(rows, cols) of `shape` shrunk so its longest side is at most `max_size` (as :func:`resize_longest`).

    Examples
    --------
    >>> resized_shape((2300, 3500), 2000)
    (1314, 2000)
    """
    rows, cols = (int(n) for n in shape)
    longest = max(rows, cols)
    if longest <= max_size:
        return rows, cols
    scale = max_size / longest
    return max(1, round(rows * scale)), max(1, round(cols * scale))
