"""`build_relief`: the paper's whole pipeline, photo to textured relief mesh, with every stage kept."""

from __future__ import annotations

import dataclasses
import hashlib
import os
import warnings
from dataclasses import dataclass, field

import cv2
import numpy as np

from ._progress import StageClock
from ._validate import check_rgb
from .errors import CliffTerrainError
from .io.photo import ImageMetadata, open_image
from .mesh.adaptive import adaptive_mesh, choose_mesh
from .mesh.grid import MeshArrays, grid_topology, place_vertices
from .mesh.tin import default_max_error
from .params import ReliefParams
from .photo_heights.indices import nir_index_map, red_map
from .photo_heights.inflate import inflate, resolve_profile
from .photo_heights.quaternion import quaternion_filter
from .photo_heights.resize import resize_longest, resized_shape
from .photo_heights.segmentation import Segmentation, decide_by_surface, segment
from .photo_heights.vegetation import COLOUR_SEPARATION
from .settings import DEFAULT_GROUND_BLOCK_M


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
    cover_mask : (rows, cols) bool or None
        The plant pixels canopy cover counts (:func:`cliff_terrain.measure.canopy.cover_pixels`):
        the photo's vegetation index above the segmentation's threshold, before the holes inside
        plants are filled and specks dropped; None in paper mode and for an NDVI map (`mask` then).
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
        The settings of the call as recorded (:meth:`cliff_terrain.params.ReliefParams.as_record`,
        the profile resolved), and the plant/soil ``threshold`` the photo got.
    timings : dict
        Seconds per stage.
    max_error : float or None
        The adaptive mesh's maximum vertical error in `units` (None for the grid).
    max_error_rule : str or None
        Which rule chose `max_error` (``"given"`` when the call gave it; see
        :func:`cliff_terrain.mesh.tin.default_max_error`); None for the grid.
    mesh_kind : {"grid", "adaptive"} or None
        The mesh made (``mesh="auto"`` resolved); None without a mesh.
    mesh_rule : str
        Why that mesh (``"given"``, or what ``"auto"`` chose and why:
        :func:`cliff_terrain.mesh.adaptive.choose_mesh`).
    canopy : cliff_terrain.measure.canopy.Canopy or None
        With a DSM: the DSM, ground and canopy height on the processing grid.
    georeference : dict or None
        With a DSM: the processing grid's CRS and map origin (the mesh starts at 0, 0).
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
    max_error_rule: str | None = None
    mesh_kind: str | None = None
    mesh_rule: str = ""
    canopy: object = None
    georeference: dict | None = None
    cover_mask: np.ndarray | None = field(default=None, compare=False, repr=False)

    @property
    def n_regions(self) -> int:
        return int(self.labels.max(initial=0))

    @property
    def max_height(self) -> float:
        return float(self.heights.max(initial=0.0))

    @property
    def mask_digest(self) -> str:
        """A short hash of the plant mask: a rebuild from the same photo and settings reproduces the
        segmentation bit for bit, so an equal digest tells the same relief (16 hex digits, BLAKE2b)."""
        return hashlib.blake2b(np.packbits(self.mask, axis=None).tobytes(), digest_size=8).hexdigest()


def build_relief(image_or_path, params=None, *, progress=None, **settings):
    """Turn one UAV photo into a relief: filter, segment, inflate, mesh.

    The settings are given as keywords, as a :class:`cliff_terrain.params.ReliefParams`
    (`params`), or both (the keywords then replace the `params`' values).

    Parameters
    ----------
    image_or_path : str, os.PathLike or (rows, cols, 3) array
        A photo file (JPEG, PNG, TIFF; see :func:`load_image`) or an RGB array (uint8, or float in
        [0, 1]).
    params : ReliefParams, optional
        Every setting below but `progress` at once (default: the defaults).
    max_size : int, optional
        Longest side of the processing grid in pixels (16 to 16384); smaller photos are not
        enlarged. The mesh has (rows + 1) x (cols + 1) front vertices.
    segmentation : {"vegetation", "paper"}, optional
        ``"vegetation"``: plants rise and soil stays flat. ``"paper"``: the paper's Algorithm 2 as
        printed (Otsu on the filtered image's brightness; it may raise bright soil). See
        :mod:`cliff_terrain.photo_heights.segmentation`.
    profile : {"auto", "circular", "poisson", "plateau"}, optional
        Cross-section of each region (see :func:`cliff_terrain.photo_heights.inflate.inflate`); ``"plateau"``
        levels closed canopy off at `max_height`. ``"auto"``: ``"plateau"`` with the vegetation
        segmentation, the paper's ``"circular"`` with the paper's.
    exaggeration : float, optional
        Height factor (> 0).
    max_height : float, optional
        Canopy height (> 0, finite), in metres when the ground sampling distance is known, else in
        processing pixels; before `exaggeration`. With ``profile="plateau"`` the height at which
        closed canopy levels off (default: the radius of a typical isolated plant, see
        :func:`cliff_terrain.photo_heights.inflate.typical_plant_radius`); with the other profiles a cap.
    gsd : float, optional
        Ground sampling distance of the *original* photo in metres per pixel; wins over what
        the camera metadata gives. With a GSD the heights and the mesh are in metres.
    dsm : str or os.PathLike, optional
        A digital surface model GeoTIFF (metres, projected CRS) of the orthophoto
        `image_or_path` (a georeferenced GeoTIFF): the canopy is then measured on it, and the
        relief follows it with `height_source` ``"measured"`` or ``"calibrated"`` (here the default
        stays ``"inflated"``; the command line's with ``--dsm`` is ``"measured"``). It is resampled
        onto the processing grid; ``Relief.canopy`` holds the DSM, ground and canopy height there,
        and ``Relief.georeference`` the grid's CRS and map origin (the mesh starts at 0, 0).
    dtm : str or os.PathLike, optional
        A terrain model: the ground; without it the ground is estimated from the soil pixels
        (see :func:`cliff_terrain.measure.ground.fit_ground`).
    ground_block : float, optional
        Block size in metres of the estimated ground's lowest surface and of its held-out check
        (default 5; see :func:`cliff_terrain.measure.ground.fit_ground`); only with a `dsm` and no `dtm`.
    ground_method : {"auto", "baseline", "smooth", "detailed"}, optional
        The estimated ground (default ``"auto"``: the candidate that predicts held-out bare soil
        best, refused when none does; see :func:`cliff_terrain.measure.ground.fit_ground`).
    height_source : {"inflated", "calibrated", "measured"}, optional
        ``"inflated"``: domes from the photo (the only mode without a DSM). ``"measured"``: the
        canopy height model. ``"calibrated"``: each region's dome scaled so its top equals the
        region's measured p99 height (photo-resolution shapes, measured heights).
    two_sided : bool, optional
        Close the relief into a watertight solid with a base (back UVs have u > 1).
    mesh : {"auto", "grid", "adaptive"} or None, optional
        ``"auto"`` (default): the adaptive mesh wherever it builds at least as fast as the grid
        (:func:`cliff_terrain.mesh.adaptive.choose_mesh`; ``Relief.mesh_kind`` and
        ``Relief.mesh_rule`` say which and why). ``"grid"``: one vertex per pixel corner. ``"adaptive"``: a triangulated irregular network
        within `max_error` of every pixel's height at its centre, with far fewer triangles where
        the ground is flat (see :func:`cliff_terrain.mesh.adaptive.adaptive_mesh`). None: no mesh, only
        the heights (what tables need, e.g. a season's, or a caller that meshes them itself from
        :func:`grid_shape` and :func:`cliff_terrain.mesh.grid.place_vertices`).
    max_error : float, optional
        The adaptive mesh's largest vertical error, in the relief's units (metres with a GSD,
        else processing pixels; > 0). Default: no detail finer than the data (see
        :func:`cliff_terrain.mesh.tin.default_max_error`): half a pixel for inflated or calibrated
        heights, the DSM's noise (at least 1 cm) for measured ones; ``Relief.max_error`` is the
        value used and ``Relief.max_error_rule`` the rule that chose it.
    progress : callable, optional
        ``progress(fraction, stage)`` is called as each stage starts, fraction in [0, 1], in the
        calling thread: the stages run one after the other there.
    heights : str, optional
        Deprecated: the old name of `height_source`.

    Returns
    -------
    Relief

    Examples
    --------
    >>> from cliff_terrain.data.synthetic import synthetic_field
    >>> img, truth = synthetic_field(shape=(240, 360), n_rows=2, seed=3)
    >>> relief = build_relief(img, max_size=360)
    >>> relief.n_regions == truth.n_plants, relief.units
    (True, 'px')
    """
    if "heights" in settings:
        warnings.warn(
            "build_relief's `heights` is deprecated: pass `height_source` instead",
            DeprecationWarning,
            stacklevel=2,
        )
        settings.setdefault("height_source", settings.pop("heights"))
    if params is not None and not isinstance(params, ReliefParams):
        raise CliffTerrainError(f"`params` must be a ReliefParams or None, got {params!r}")
    params = ReliefParams(**settings) if params is None else params.replace(**settings)
    if progress is not None and not callable(progress):
        raise CliffTerrainError(f"`progress` must be callable or None, got {progress!r}")
    if params.dsm is not None and not isinstance(image_or_path, str | os.PathLike):
        raise CliffTerrainError(
            "`dsm` needs `image_or_path` to be a georeferenced orthophoto file, got an array"
        )
    params = params.replace(profile=resolve_profile(params.profile, params.segmentation))
    timings = {}
    clock = StageClock(progress, timings)
    clock.start("load", 0.0)
    if isinstance(image_or_path, str | os.PathLike):
        with open_image(
            image_or_path, max_size=params.max_size, gsd=params.gsd, bands=params.bands
        ) as source:
            image, metadata = source.decode()
            # A multispectral orthomosaic's bands, as decoding read them: plants by NDVI with NIR.
            bands = getattr(source, "bands", None)
    else:
        image, metadata = _from_array(image_or_path, params.gsd)
        bands = None
    # A surface model may decide what colour cannot (a class below the index floor: senescent canopy
    # or straw?): only read when the photo's rule was undecided.
    surface = None
    if params.dsm is not None:
        from .measure.canopy import surface_on_grid

        def surface(shape):
            return surface_on_grid(image_or_path, metadata, shape, params.dsm)

    stages = _image_stages(image, metadata, params, clock=clock, bands=bands, surface=surface)
    seg = stages.segmentation
    # Which plant/soil threshold the photo got, and why (the photo's own, or the prior band).
    threshold = {
        "index": seg.index,
        "value": round(float(seg.threshold), 4),
        "source": seg.threshold_source,
        "valley": round(float(seg.valley), 3),  # NaN in paper mode
        # Ashman's D of the chroma (of the red reflectance for NDVI) across Otsu's split: the colour
        # test (NaN where not measured).
        "colour_separation": round(float(seg.separation), 3),
        "colour_test": {
            "statistic": "ashman_d_red_reflectance" if seg.index == "ndvi" else "ashman_d_chroma",
            "min": COLOUR_SEPARATION,
        },
    }
    if seg.threshold_note:
        threshold["note"] = seg.threshold_note
    clock.start("mesh", 0.8)
    pixel_size = metadata.grid_pixel_size(stages.working.shape[:2])
    units = "px" if pixel_size is None else "m"
    if pixel_size is None:
        pixel_size, heights = 1.0, stages.heights_px
    else:
        heights = stages.heights_px * np.float32(pixel_size)
    canopy = georeference = None
    if params.dsm is not None:
        from .measure.canopy import relief_heights

        canopy, heights, pixel_size, georeference = relief_heights(
            image_or_path,
            stages,
            dsm=params.dsm,
            dtm=params.dtm,
            height_source=params.height_source,
            exaggeration=params.exaggeration,
            block_m=DEFAULT_GROUND_BLOCK_M if params.ground_block is None else params.ground_block,
            ground_method=params.ground_method or "auto",
        )
        units = "m"
    relief = Relief(
        # The segmentation's index pixels (before it filled its plants' holes): what the windowed
        # measure counts too. NDVI maps keep the mask, as the windows do.
        cover_mask=seg.index_pixels if seg.index in ("green", "nir") else None,
        image=stages.image,
        metadata=metadata,
        working=stages.working,
        filtered=stages.filtered,
        mask=seg.mask,
        labels=seg.labels,
        boundaries=seg.boundaries,
        distance=stages.distance,
        heights=heights,
        mesh=None,
        units=units,
        pixel_size=pixel_size,
        params={**params.as_record(), "threshold": threshold},
        timings=timings,
        canopy=canopy,
        georeference=georeference,
    )
    if params.mesh is not None:
        relief = mesh_relief(relief, mesh=params.mesh, max_error=params.max_error, two_sided=params.two_sided)
    clock.start(None, 1.0)
    return relief


def mesh_relief(relief, *, mesh="auto", max_error=None, two_sided=True):
    """`relief` with the mesh of its heights, as :func:`build_relief` makes it with these settings.

    ``build_relief(..., mesh=None)`` and then this give the relief ``build_relief(..., mesh=...)``
    gives, so a caller can work on the heights (their key figures, say) while the mesh is built.

    Parameters
    ----------
    relief : Relief
        A relief from :func:`build_relief`, with or without a mesh: its heights, pixel size, units
        and, with measured heights, its canopy (for the DSM's noise) are used.
    mesh : {"auto", "grid", "adaptive"}, optional
    max_error : float, optional
        The adaptive mesh's bound; by default the rule of
        :func:`cliff_terrain.mesh.tin.default_max_error` for the relief's heights.
    two_sided : bool, optional

    Returns
    -------
    Relief
        A copy with ``mesh``, ``mesh_kind`` and ``mesh_rule`` set (and, for the adaptive mesh,
        ``max_error`` and ``max_error_rule``), its ``params`` recording the three settings.

    Examples
    --------
    >>> from cliff_terrain.data.synthetic import synthetic_field
    >>> img, _ = synthetic_field(shape=(240, 360), n_rows=2, seed=3)
    >>> heights_only = build_relief(img, max_size=360, mesh=None)
    >>> relief = mesh_relief(heights_only, mesh="adaptive")
    >>> relief.mesh.n_faces == build_relief(img, max_size=360, mesh="adaptive").mesh.n_faces
    True
    >>> relief.max_error_rule
    'half a pixel (inflated heights, no scale: 0.5 px)'
    """
    if mesh is None:
        raise CliffTerrainError("`mesh` must be 'auto', 'grid' or 'adaptive', got None")
    params = ReliefParams(mesh=mesh, max_error=max_error, two_sided=two_sided)  # checked as build_relief's
    heights, pixel_size = relief.heights, relief.pixel_size
    height_source = relief.params.get("height_source", "inflated")
    max_error, max_error_rule = params.max_error, "given"
    mesh_kind, mesh_rule = choose_mesh(params.mesh, heights.shape)
    if mesh_kind == "grid":
        topology = grid_topology(heights.shape, two_sided=params.two_sided)
        relief_mesh = place_vertices(topology, heights, pixel_size=pixel_size)
        max_error = max_error_rule = None
    else:
        if max_error is None:
            noise = None
            if relief.canopy is not None and height_source == "measured":
                from .measure.canopy import dsm_noise

                noise = dsm_noise(relief.canopy, plants=relief.mask)
            max_error, max_error_rule = default_max_error(
                height_source=height_source, units=relief.units, pixel_size=pixel_size, dsm_noise=noise
            )
        relief_mesh = adaptive_mesh(
            heights, max_error=max_error, pixel_size=pixel_size, two_sided=params.two_sided
        )
    recorded = {"mesh": params.mesh, "max_error": params.max_error, "two_sided": params.two_sided}
    return dataclasses.replace(
        relief,
        mesh=relief_mesh,
        mesh_kind=mesh_kind,
        mesh_rule=mesh_rule,
        max_error=max_error,
        max_error_rule=max_error_rule,
        params={**relief.params, **recorded},
    )


def grid_shape(image_or_path, *, max_size):
    """(rows, cols) of the processing grid :func:`build_relief` makes of a photo, from its header only.

    Parameters
    ----------
    image_or_path : str, os.PathLike or (rows, cols, 3) array
    max_size : int

    Examples
    --------
    >>> grid_shape(np.zeros((2300, 3500, 3), np.uint8), max_size=2000)
    (1314, 2000)
    """
    params = ReliefParams(max_size=max_size)
    if isinstance(image_or_path, str | os.PathLike):
        with open_image(image_or_path, max_size=params.max_size) as source:
            shape = source.shape
    else:
        shape = np.shape(image_or_path)[:2]
    return resized_shape(shape, params.max_size)


@dataclass
class _ImageStages:
    """The photo's stages up to the heights in processing pixels."""

    image: np.ndarray
    metadata: ImageMetadata
    working: np.ndarray
    filtered: np.ndarray
    segmentation: Segmentation
    distance: np.ndarray
    heights_px: np.ndarray


def _image_stages(image, metadata, params, *, clock, bands=None, surface=None):
    """Resize, filter, segment (by NDVI when `bands` hold NIR and red) and inflate (`clock` is at "load").

    `surface(shape)`, when given, returns the DSM on the processing grid: it is read only when the
    photo's threshold rule was undecided (see :func:`~cliff_terrain.photo_heights.segmentation.decide_by_surface`).
    """
    clock.start("resize", 0.1)
    working = resize_longest(image, params.max_size)

    clock.start("filter", 0.2)
    filtered = quaternion_filter(working)

    clock.start("segment", 0.35)
    valid = None
    if metadata.valid_mask is not None:  # an orthophoto's no-data area stays flat
        size = working.shape[1::-1]
        valid = cv2.resize(metadata.valid_mask.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0
    ndvi = nir_index_map(bands, shape=working.shape[:2]) if params.segmentation == "vegetation" else None
    # NDVI's colour test reads the red band: leaves absorb it, soil does not.
    red = red_map(bands, shape=working.shape[:2]) if ndvi is not None else None
    seg = segment(
        working, method=params.segmentation, filtered=filtered, valid=valid, index_map=ndvi, red=red
    )
    if surface is not None and seg.threshold_note.startswith("undecided"):
        seg = decide_by_surface(
            seg, working, surface(working.shape[:2]), filtered=filtered, valid=valid, index_map=ndvi
        )

    clock.start("heights", 0.6)
    distance = seg.region_distance  # distance_map(seg.labels), computed with the watershed
    max_height = params.max_height
    pixel_size = metadata.grid_pixel_size(working.shape[:2])
    if max_height is not None and pixel_size is not None:  # metres -> processing pixels
        max_height /= pixel_size
    heights_px = inflate(
        seg.labels,
        profile=params.profile,
        exaggeration=params.exaggeration,
        distance=distance,
        max_height=max_height,
        mask_distance=seg.distance,
    )
    return _ImageStages(image, metadata, working, filtered, seg, distance, heights_px)


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
