"""A season's plan: its photos, their dates and surface models, checked before any work.

:func:`plan_season` checks everything it can before any work (files, dates, CRS, plots), so bad
input is one error at once, and lists one :class:`Job` per date.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

from .. import settings
from ..errors import CliffTerrainError
from ..params import ReliefParams
from .dates import check_given_dates, photo_date

SEASON_SETTINGS = ("max_size", "segmentation", "profile", "exaggeration", "height_source")
IMAGE_SUFFIXES = (".tif", ".tiff", ".jpg", ".jpeg", ".png", ".webp")


@dataclasses.dataclass
class Job:
    """One image of the season: what a worker needs to compute it."""

    path: str
    date: str
    date_source: str
    plots: str
    params: dict
    dsm: str | None = None
    shift: list | None = (
        None  # map (x, y) metres of its content from the season's consensus (None: not aligned)
    )
    align_score: float | None = None
    cache: str = ""  # the cache folder (set by run_season)
    plots_hash: str = ""
    version: str = ""
    indices: tuple = ()  # vegetation indices per plot (cliff_terrain.photo_heights.indices.INDICES names)
    bands: tuple | None = None  # the photos' band names when their files do not name them

    def as_dict(self):
        return dataclasses.asdict(self)


def find_images(inputs):
    """Files and folders (their image files, not recursive) to a sorted list of unique paths."""
    found = []
    for item in inputs:
        path = Path(item)
        if path.is_dir():
            files = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file())
            if not files:
                raise CliffTerrainError(
                    f"no images in folder {str(path)!r} (looked for {', '.join(IMAGE_SUFFIXES)})"
                )
            found.extend(files)
        elif path.is_file():
            found.append(path)
        else:
            raise CliffTerrainError(f"input {str(path)!r} is neither a file nor a folder")
    if not found:
        raise CliffTerrainError("no input images given")
    unique = sorted({p.resolve() for p in found})
    return [str(p) for p in unique]


def pair_dsm(images, dsm):
    """Each image's DSM: `dsm` is a file (one image), a folder, or a pattern with ``{stem}``.

    A folder is searched for a file holding the image's date or stem, e.g. ``20180815_dsm.tif``.
    """
    if dsm is None:
        return {image: None for image in images}
    text = str(dsm)
    pairs = {}
    for image in images:
        stem = Path(image).stem
        if "{stem}" in text:
            candidate = Path(text.format(stem=stem))
        elif Path(text).is_dir():
            candidate = _dsm_in_folder(Path(text), Path(image))
        elif len(images) == 1:
            candidate = Path(text)
        else:
            raise CliffTerrainError(
                f"`--dsm` must be a folder or a pattern with {{stem}} for {len(images)} images, got {text!r}"
            )
        if candidate is None or not candidate.is_file():
            raise CliffTerrainError(f"no DSM for {image!r} (`--dsm` {text!r})")
        pairs[image] = str(candidate)
    return pairs


def _dsm_in_folder(folder, image):
    from .dates import date_in_name

    date = date_in_name(image.name)
    for path in sorted(folder.iterdir()):
        if path.suffix.lower() not in (".tif", ".tiff") or path.resolve() == image.resolve():
            continue
        if image.stem in path.stem or (date is not None and date_in_name(path.name) == date):
            return path
    return None


def plan_season(
    inputs,
    *,
    plots,
    dates=None,
    dsm=None,
    max_size=settings.DEFAULT_MAX_SIZE,
    segmentation=settings.DEFAULT_SEGMENTATION,
    profile=settings.DEFAULT_PROFILE,
    exaggeration=settings.DEFAULT_EXAGGERATION,
    height_source=None,
    indices=None,
    bands=None,
):
    """Check the inputs and list the season's jobs, sorted by date.

    Parameters
    ----------
    inputs : list of str or os.PathLike
        Photos, or folders of photos.
    plots : str or os.PathLike
        The plot polygons (GeoJSON), in the photos' CRS.
    dates : dict, optional
        ``{file name or path: datetime.date}`` for photos whose file holds no date.
    dsm : str, optional
        Surface models: see :func:`pair_dsm`.
    max_size, segmentation, profile, exaggeration
        As for :func:`cliff_terrain.build_relief`.
    height_source : {"inflated", "calibrated", "measured"}, optional
        As for :func:`cliff_terrain.build_relief`: "measured" (the default with `dsm`) and
        "calibrated" need `dsm`; "inflated" is the only mode without one.
    indices : str or sequence of str, optional
        Vegetation indices per plot and date (``"NDVI,NDRE"``): ``season.csv`` gains their columns
        (``ndvi_mean`` ...). Every photo must hold their bands (checked here, before any work).
    bands : str or sequence of str, optional
        The photos' band names in order (``"B,G,R,RE,NIR"``) when their files do not name them.

    Returns
    -------
    jobs : list of Job
    plot_set : PlotSet

    Raises
    ------
    CliffTerrainError
        For a missing file, a photo without a date, two photos of one date, or a photo whose CRS
        differs from the plots'.
    """
    from ..io.raster.bands import parse_band_names, read_bands
    from ..io.raster.geotiff import read_georeference
    from ..io.vector.plot_polygons import read_plots
    from ..measure.field_plots import check_plot_crs
    from ..photo_heights.indices import check_indices, parse_indices

    source = height_source or ("inflated" if dsm is None else "measured")
    if dsm is None and source in settings.ids(settings.HEIGHT_SOURCES) and source != "inflated":
        raise CliffTerrainError(f"`height_source` {source!r} needs `dsm` (surface models), got None")
    checked = ReliefParams(
        max_size=max_size,
        segmentation=segmentation,
        profile=profile,
        exaggeration=exaggeration,
        height_source=source,
        dsm=None if dsm is None else os.fspath(dsm),
    ).as_record()
    # The settings a season's reliefs share (the cache key's); each date's DSM is its job's.
    params = {name: checked[name] for name in SEASON_SETTINGS}
    plot_set = read_plots(plots)
    indices = parse_indices(indices)
    bands = parse_band_names(bands)
    images = find_images(inputs)
    check_given_dates(dates, images)
    dsms = pair_dsm(images, dsm)
    jobs, seen = [], {}
    for image in images:
        date, source = photo_date(image, given=dates)
        if date in seen:
            raise CliffTerrainError(
                f"two photos of {date.isoformat()}: {seen[date]!r} and {image!r}; a season has one "
                "orthophoto per date (mosaic the tiles of one flight first)"
            )
        seen[date] = image
        _, crs = read_georeference(image)
        check_plot_crs(plot_set, crs, raster=image)
        if indices:  # a date whose file lacks an index's band: refused before any work
            check_indices(read_bands(image, names=bands), indices)
        jobs.append(
            Job(
                path=image,
                date=date.isoformat(),
                date_source=source,
                plots=str(Path(plots).resolve()),
                params=params,
                dsm=dsms[image],
                indices=indices,
                bands=bands,
            )
        )
    jobs.sort(key=lambda job: job.date)
    return jobs, plot_set
