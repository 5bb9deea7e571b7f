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
from .mesh import MeshArrays, MeshSizes, grid_sizes, grid_topology, place_vertices
from .quaternion import quaternion_filter
from .segmentation import METHODS, distance_map, segment

MIN_SIZE = 16
MAX_SIZE = 16384


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
    mesh : MeshArrays
        The relief mesh, x/y/z in `units`.
    units : {"m", "px"}
        Metres when the ground sampling distance is known, else processing pixels.
    pixel_size : float
        Size of one processing pixel in `units`.
    params : dict
        The settings of the call.
    timings : dict
        Seconds per stage.
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
    mesh: MeshArrays
    units: str
    pixel_size: float
    params: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)

    @property
    def n_regions(self) -> int:
        return int(self.labels.max(initial=0))

    @property
    def max_height(self) -> float:
        return float(self.heights.max(initial=0.0))


def build_relief(
    image_or_path,
    *,
    max_size=1000,
    segmentation="vegetation",
    profile="circular",
    exaggeration=1.0,
    gsd=None,
    two_sided=True,
    progress=None,
    mesh_sink=None,
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
    profile : {"circular", "poisson"}, optional
        Cross-section of each region (see :func:`cliff_terrain.heights.inflate`).
    exaggeration : float, optional
        Height factor (> 0).
    gsd : float, optional
        Ground sampling distance of the *original* photo in metres per pixel; wins over what
        the camera metadata gives. With a GSD the heights and the mesh are in metres.
    two_sided : bool, optional
        Close the relief into a watertight solid with a base (back UVs have u > 1).
    progress : callable, optional
        ``progress(fraction, stage)`` is called as each stage starts, fraction in [0, 1], always
        in the calling thread (a GUI may update itself from it).
    mesh_sink : MeshSink, optional
        Receives the mesh step by step, in the calling thread, while decoding, filter,
        segmentation and heights run in a worker thread, so that a caller can fill a mesh of its
        own in parallel (the Blender add-on does). Each step comes when the worker least needs
        the GIL, which work such as Blender's bulk calls holds throughout: see
        :class:`MeshSink`. The mesh it is given, with its vertices placed, is ``Relief.mesh``.
        Whatever it raises propagates once the worker has finished.

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
    exaggeration = check_float("exaggeration", exaggeration, minimum=0.0, strict_minimum=True)
    gsd = check_float("gsd", gsd, minimum=0.0, strict_minimum=True, allow_none=True)
    if not isinstance(two_sided, bool | np.bool_):
        raise CliffTerrainError(f"`two_sided` must be True or False, got {two_sided!r}")
    if progress is not None and not callable(progress):
        raise CliffTerrainError(f"`progress` must be callable or None, got {progress!r}")
    if mesh_sink is not None and not all(
        callable(getattr(mesh_sink, step, None)) for step in ("allocate", "prepare", "fill")
    ):
        raise CliffTerrainError(
            f"`mesh_sink` must have methods allocate, prepare and fill, or be None, got {mesh_sink!r}"
        )
    params = {
        "max_size": max_size,
        "segmentation": segmentation,
        "profile": profile,
        "exaggeration": exaggeration,
        "gsd": gsd,
        "two_sided": bool(two_sided),
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

    # Decoding, resizing, filter, segmentation and heights run in a worker thread while this
    # thread builds the mesh's faces, UVs and edges, which depend on the grid's shape only, and
    # hands them to `mesh_sink` step by step. Progress is relayed to this thread.
    events = queue.SimpleQueue()

    worker_done = False

    def relay(*, wait):
        """Pass the worker's progress on; with `wait`, until the worker has finished."""
        nonlocal worker_done
        while not worker_done:
            try:
                event = events.get(block=wait)
            except queue.Empty:
                return
            if event is None:
                worker_done = True
            elif progress is not None:
                progress(*event)

    worker_clock = _Stages(lambda fraction, stage: events.put((fraction, stage)), timings, stage="load")
    # Set when the worker enters its long GIL-free stretch (the watershed, else the heights).
    gil_free = threading.Event()
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="cliff_terrain") as pool:
        image_stages = pool.submit(
            _image_stages, source, max_size, segmentation, profile, exaggeration, worker_clock, gil_free
        )
        image_stages.add_done_callback(lambda _: (gil_free.set(), events.put(None)))
        started = time.perf_counter()
        try:
            if mesh_sink is not None:
                # The worker is decoding and resizing the photo, in calls that release the GIL.
                mesh_sink.allocate(grid_sizes(grid_shape, two_sided=bool(two_sided)))
                relay(wait=False)
            mesh_arrays = grid_topology(grid_shape, two_sided=bool(two_sided))
            if mesh_sink is not None:
                mesh_sink.prepare(mesh_arrays)
                relay(wait=False)
                # Work that holds the GIL stalls the worker at each of its many short numpy
                # steps; while the worker is inside the watershed it stalls it the least.
                gil_free.wait()
                mesh_sink.fill()
        finally:
            timings["topology"] = time.perf_counter() - started
            relay(wait=True)
            if isinstance(source, OpenImage):
                source.close()  # the worker has finished; it may have failed before decoding
        image, metadata, working, filtered, seg, distance, heights_px = image_stages.result()
    clock = _Stages(progress, timings)
    clock.start("mesh", 0.8)

    rows, cols = working.shape[:2]
    if metadata.gsd_m_per_px:
        units = "m"
        # The GSD is per original pixel; the grid is coarser by the original width over its own.
        pixel_size = float(metadata.gsd_m_per_px) * metadata.width / cols
    else:
        units, pixel_size = "px", 1.0
    heights = heights_px * np.float32(pixel_size) if units == "m" else heights_px
    mesh = place_vertices(mesh_arrays, heights, pixel_size=pixel_size)
    clock.start(None, 1.0)

    return Relief(
        image=image,
        metadata=metadata,
        working=working,
        filtered=filtered,
        mask=seg.mask,
        labels=seg.labels,
        boundaries=seg.boundaries,
        distance=distance,
        heights=heights,
        mesh=mesh,
        units=units,
        pixel_size=pixel_size,
        params=params,
        timings=timings,
    )


def _image_stages(source, max_size, segmentation, profile, exaggeration, clock, gil_free):
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
    seg = segment(working, method=segmentation, filtered=filtered, valid=valid, on_watershed=gil_free.set)
    gil_free.set()

    clock.start("heights", 0.6)
    distance = distance_map(seg.labels)
    heights_px = inflate(seg.labels, profile=profile, exaggeration=exaggeration, distance=distance)
    clock.start(None, None)
    return image, metadata, working, filtered, seg, distance, heights_px


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
