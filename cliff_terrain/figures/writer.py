"""Every file a relief's figures run writes, named once, and the one writer of each.

``render_views.py`` and the Render Views operator write the same folder: the views Blender renders
(:data:`RENDERS`), the pipeline's maps (:data:`MAPS`), the region and plot tables (with a surface
model or plots), the annotated figures (:data:`FIGURES`), ``scene.blend`` (the script only) and
``metrics.json``. :func:`write_outputs` writes all but the renders and the scene, from a
:class:`cliff_terrain.build.Relief` and the renders in the same folder; :func:`write_metrics` is the
one writer of ``metrics.json`` and :func:`write_height_map` of ``height.tif``.

Importing this module needs only the standard library (numpy, Pillow, tifffile and SciPy are
imported when writing): ``render_views.py`` checks the names before Blender is loaded.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

# The rendered views (scene/views.py renders them), view -> file, in the order they are listed.
VIEW_FILES = {
    "xy": "xy.png",
    "xy_flat": "xy_flat.png",
    "xz": "xz.png",
    "view3d": "view3d.png",
    "mesh": "mesh.png",
}
RENDERS = tuple(VIEW_FILES.values())
# The pipeline's stages as images: the quaternion filter, the mask, the distance map, the heights.
MAPS = FILTERED, MASK, DISTANCE, HEIGHT_MAP = ("filtered.png", "mask.png", "distance.png", "height.tif")
# Figures with legends, drawn on copies of the renders (the raw renders stay as Blender made them,
# the top views for PSNR/SSIM), and the contact sheet for a report.
FIGURES = XY_ANNOTATED, XZ_ANNOTATED, MESH_ANNOTATED, SUMMARY = (
    "xy_annotated.png",
    "xz_annotated.png",
    "mesh_annotated.png",
    "summary.png",
)
SCENE = "scene.blend"
METRICS = "metrics.json"
# Every file of a render_views.py run but the tables (their names come with them: measure.canopy).
OUTPUTS = (*RENDERS, *MAPS, *FIGURES, SCENE, METRICS)


def write_height_map(relief, path):
    """Write `relief`'s heights to the TIFF `path`: float32 on the processing grid, in relief.units,
    with the units and the pixel size in its metadata."""
    import numpy as np
    import tifffile

    tifffile.imwrite(
        path,
        np.ascontiguousarray(relief.heights, dtype=np.float32),
        photometric="minisblack",
        metadata={"units": relief.units, "pixel_size": float(relief.pixel_size)},
    )


def write_maps(relief, out):
    """filtered.png, mask.png, distance.png (8-bit) and height.tif (float32 heights, in relief.units)."""
    import numpy as np
    from PIL import Image

    filtered = np.round(np.clip(relief.filtered, 0.0, 1.0) * 255.0).astype(np.uint8)
    Image.fromarray(filtered).save(out / FILTERED)
    Image.fromarray(relief.mask.astype(np.uint8) * 255).save(out / MASK)
    top = float(relief.distance.max(initial=0.0))
    distance = relief.distance / top if top > 0 else relief.distance
    Image.fromarray(np.round(distance * 255.0).astype(np.uint8)).save(out / DISTANCE)
    write_height_map(relief, out / HEIGHT_MAP)


def crop_figures(relief):
    """The crop's key figures (:func:`cliff_terrain.measure.key_figures.key_figures`: one definition everywhere)."""
    from ..measure.key_figures import key_figures

    return key_figures(relief)


def write_figures(relief, out, side, metrics, *, transect=None):
    """xy_annotated.png, xz_annotated.png, mesh_annotated.png and summary.png; returns what
    metrics.json records about them (the crop's key figures, the annotated files)."""
    import numpy as np
    from PIL import Image

    from .annotate import annotate_colour_bar, annotate_side_view, annotate_top_view
    from .legends import display_units, height_colours
    from .sheet import contact_sheet

    def read(name):
        with Image.open(out / name) as image:
            return np.asarray(image.convert("RGBA" if "A" in image.mode else "RGB"))

    def save(name, array):
        Image.fromarray(array).save(out / name)
        return array

    meta = relief.metadata
    crop = crop_figures(relief)
    factor, unit = (
        display_units(relief.max_height, relief.units) if relief.max_height > 0 else (1.0, relief.units)
    )
    lit = read(VIEW_FILES["xy"])
    metres_per_pixel = meta.grid_pixel_size(lit.shape[:2])
    xy = save(
        XY_ANNOTATED,
        annotate_top_view(
            lit,
            metres_per_pixel=metres_per_pixel,
            georeferenced=meta.gsd_source == "geotiff",
            transect=transect,
            photo_shape=(meta.height, meta.width),
        ),
    )
    if relief.max_height > 0:
        title = (
            "Side view from the south" if transect is None else f"Side view of the transect {transect.text}"
        )
        if side["top"] > 0:
            xz = annotate_side_view(
                read(VIEW_FILES["xz"]),
                ground_row=side["ground_row"],
                rows_per_unit=side["rows_per_unit"],
                max_height=side["top"],
                units=relief.units,
                exaggeration=side["exaggeration"],
                title=title,
            )
        else:  # a transect across bare ground only: nothing to put a ruler on
            xz = contact_sheet([(f"{title}: bare ground", read(VIEW_FILES["xz"]))], tile=480, columns=1)
        xz = save(XZ_ANNOTATED, xz)
        mesh = save(
            MESH_ANNOTATED,
            annotate_colour_bar(read(VIEW_FILES["mesh"]), max_height=relief.max_height, units=relief.units),
        )
        heights = np.round(height_colours(relief.heights / relief.max_height) * 255).astype(np.uint8)
        heights = annotate_colour_bar(heights, max_height=relief.max_height, units=relief.units)
    else:
        # Nothing rose: no ruler or colour bar can be labelled; the figures say so instead.
        note = f"flat relief: no {'plant' if crop['plants'] == 0 else 'height'} to measure"
        xz = save(XZ_ANNOTATED, contact_sheet([(note, read(VIEW_FILES["xz"]))], tile=480, columns=1))
        mesh = save(MESH_ANNOTATED, contact_sheet([(note, read(VIEW_FILES["mesh"]))], tile=480, columns=1))
        heights = np.zeros(relief.heights.shape, np.uint8)

    def height(value):
        return "n/a" if value is None else f"{value * factor:.3g} {unit}"

    if meta.gsd_m_per_px:
        units_line = f"GSD {meta.gsd_m_per_px * 100:.3g} cm/px ({meta.gsd_source})"
    else:
        units_line = "no GSD: heights in processing pixels"
    facts = [
        f"plants: {crop['plants']}",
        f"ground cover: {100 * crop['cover']:.1f} %",
        f"canopy height: median {height(crop['canopy_height_p50_' + crop['units']])}",
        f"    90th percentile {height(crop['canopy_height_p90_' + crop['units']])}",
        f"plant height: median {height(crop['plant_height_median_' + crop['units']])}",
        f"    90th percentile {height(crop['plant_height_p90_' + crop['units']])}",
        f"highest point: {height(relief.max_height)}",
        f"lit top view: PSNR {metrics['psnr_xy']:.2f} dB, SSIM {metrics['ssim_xy']:.3f}",
        f"flat top view: PSNR {metrics['psnr_xy_flat']:.2f} dB",
        units_line,
        f"side view: vertical exaggeration {side['exaggeration']:g}x",
    ]
    panels = [
        ("photo", read(VIEW_FILES["xy_flat"])),
        ("plants (mask)", read(MASK)),
        (f"heights ({unit})", heights),
        ("lit top view (x-y)", xy),
        ("3D view", read(VIEW_FILES["view3d"])),
        ("mesh by height", mesh),
        ("side view (x-z)", xz, 2),
    ]
    save(SUMMARY, contact_sheet(panels, facts=facts, title=Path(meta.path).name))
    return {
        **crop,
        "figures": {"raw_renders": "unchanged", "annotated": list(FIGURES), "height_label_unit": unit},
    }


def write_metrics(out, metrics, *, side, relief=None, figures=None, render=None, timings=None):
    """Write ``metrics.json`` into `out`: the one record of a run, the script's and the operator's.

    Parameters
    ----------
    out : Path
        The output folder.
    metrics : dict
        The top views against the photo (``scene.views.evaluate_relief``: PSNR, SSIM, ...).
    side : dict
        The side view's rig (``exaggeration``, ``top``, ``ground_row``, ``rows_per_unit``,
        ``strip_columns``, ``transect``, ...).
    relief : Relief, optional
        The relief shown: its regions, heights, units, GSD, photo, grid and parameters.
    figures : dict, optional
        What :func:`write_figures` returned (the crop's key figures, the annotated files).
    render : dict, optional
        What Blender made (``vertices``, ``faces``, ``engine``, ``samples``, ``light``, ``versions``,
        ...); its keys win over the relief's (a relief rebuilt without its mesh gives the object's
        own ``params``, ``mesh`` and ``max_error`` with their rules here).
    timings : dict, optional
        Seconds per stage (rounded to 1 ms).

    Returns
    -------
    dict
        The record written (non-finite numbers as None: JSON holds no infinity).
    """
    from ..evaluate.views import json_safe
    from ..settings import PAPER_TABLE4

    record = dict(metrics)
    if relief is not None:
        meta = relief.metadata
        rows, cols = relief.heights.shape
        record.update(
            regions=relief.n_regions,
            max_height=relief.max_height,
            units=relief.units,
            gsd_m_per_px=meta.gsd_m_per_px,
            gsd_source=meta.gsd_source,
            mesh=relief.mesh_kind,
            mesh_rule=relief.mesh_rule,
            max_error=relief.max_error,
            max_error_rule=relief.max_error_rule,
            image={"path": str(meta.path), "width": meta.width, "height": meta.height},
            processing_size=[cols, rows],
            params=relief.params,
        )
    record.update(render or {})
    record["side_view"] = dict(side)
    record.update(figures or {})
    record["paper_table4"] = PAPER_TABLE4
    record["timings_s"] = {key: round(float(value), 3) for key, value in (timings or {}).items()}
    record = json_safe(record)
    (Path(out) / METRICS).write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
    return record


def write_outputs(
    relief,
    out,
    *,
    side,
    metrics,
    transect=None,
    plots=None,
    render=None,
    timings=None,
    started=None,
    log=None,
    index_maps=None,
):
    """Write the maps, the tables, the annotated figures and ``metrics.json`` of `relief` into
    `out`, beside the views rendered there (:data:`RENDERS`).

    Parameters
    ----------
    relief : Relief
        The relief the views show (its mesh is not needed).
    out : Path
        The output folder, holding the rendered views.
    side : dict
        The side view's rig (where heights fall in ``xz.png``).
    metrics : dict
        The top views against the photo.
    transect : Transect, optional
        The strip the side view shows (outlined on ``xy_annotated.png``).
    plots : PlotSet, optional
        Plot polygons: ``plots.csv`` and ``plots.geojson`` (needs a surface model). The region
        tables are written with a surface model or plots.
    render : dict, optional
        What Blender made, for ``metrics.json`` (see :func:`write_metrics`).
    timings : dict, optional
        Seconds per stage so far; the maps', tables' and figures' are added.
    started : float, optional
        ``time.perf_counter()`` at the run's start: the timings get its ``total``.
    log : callable, optional
        Called with a line before each step.
    index_maps : dict, optional
        Vegetation index name -> map on the relief's grid: the tables gain their columns
        (``ndvi_mean`` ...; see :mod:`cliff_terrain.measure.index_figures`) and are written even
        without a surface model (``regions.csv`` only).

    Returns
    -------
    dict
        The record written to ``metrics.json``.
    """
    from ..measure.canopy import relief_tables
    from ..measure.tables import write_files

    out = Path(out)
    timings = {} if timings is None else timings
    say = log or (lambda message: None)

    say("writing the maps")
    start = time.perf_counter()
    write_maps(relief, out)
    timings["maps"] = time.perf_counter() - start

    if relief.canopy is not None or plots is not None or index_maps:
        say("writing the region and plot tables")
        start = time.perf_counter()
        tables = relief_tables(relief, plots=plots, source=str(relief.metadata.path), index_maps=index_maps)
        write_files({out / name: text for name, text in tables.items()})
        timings["tables"] = time.perf_counter() - start

    say("drawing the figures")
    start = time.perf_counter()
    figures = write_figures(relief, out, side, metrics, transect=transect)
    timings["figures"] = time.perf_counter() - start

    if started is not None:
        timings["total"] = time.perf_counter() - started
    return write_metrics(
        out, metrics, side=side, relief=relief, figures=figures, render=render, timings=timings
    )
