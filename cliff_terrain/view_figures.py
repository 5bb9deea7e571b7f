"""The files beside the rendered views: the pipeline's maps and the annotated figures.

:func:`write_maps` writes the stages as images (``mask.png``, ``height.tif``, ...);
:func:`write_figures` draws the legends on copies of the renders (``*_annotated.png``) and the
``summary.png`` contact sheet, from a :class:`cliff_terrain.pipeline.Relief` and the renders in
the same folder. Used by ``render_views.py`` and by the Render Views operator (numpy, Pillow,
tifffile and SciPy; no Blender).
"""

from __future__ import annotations

from pathlib import Path

from . import figures

# render_views.py lists the same names before Blender (and this package) is loaded.
MAPS = ("filtered.png", "mask.png", "distance.png", "height.tif")
FIGURES = ("xy_annotated.png", "xz_annotated.png", "mesh_annotated.png", "summary.png")


def write_maps(relief, out):
    """filtered.png, mask.png, distance.png (8-bit) and height.tif (float32 heights, in relief.units)."""
    import numpy as np
    import tifffile
    from PIL import Image

    filtered = np.round(np.clip(relief.filtered, 0.0, 1.0) * 255.0).astype(np.uint8)
    Image.fromarray(filtered).save(out / "filtered.png")
    Image.fromarray(relief.mask.astype(np.uint8) * 255).save(out / "mask.png")
    top = float(relief.distance.max(initial=0.0))
    distance = relief.distance / top if top > 0 else relief.distance
    Image.fromarray(np.round(distance * 255.0).astype(np.uint8)).save(out / "distance.png")
    tifffile.imwrite(
        out / "height.tif",
        np.ascontiguousarray(relief.heights, dtype=np.float32),
        photometric="minisblack",
        metadata={"units": relief.units, "pixel_size": float(relief.pixel_size)},
    )


def crop_figures(relief):
    """The crop's key figures (:func:`cliff_terrain.key_figures.key_figures`: one definition everywhere)."""
    from .key_figures import key_figures

    return key_figures(relief)


def write_figures(relief, out, side, metrics, *, transect=None):
    """xy_annotated.png, xz_annotated.png, mesh_annotated.png and summary.png; returns what
    metrics.json records about them (the side view's exaggeration, the crop's key figures)."""
    import numpy as np
    from PIL import Image

    def read(name):
        with Image.open(out / name) as image:
            return np.asarray(image.convert("RGBA" if "A" in image.mode else "RGB"))

    def save(name, array):
        Image.fromarray(array).save(out / name)
        return array

    meta = relief.metadata
    crop = crop_figures(relief)
    factor, unit = (
        figures.display_units(relief.max_height, relief.units)
        if relief.max_height > 0
        else (1.0, relief.units)
    )
    lit = read("xy.png")
    gsd = meta.gsd_m_per_px
    metres_per_pixel = gsd * meta.width / lit.shape[1] if gsd else None
    xy = save(
        "xy_annotated.png",
        figures.annotate_top_view(
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
            xz = figures.annotate_side_view(
                read("xz.png"),
                ground_row=side["ground_row"],
                rows_per_unit=side["rows_per_unit"],
                max_height=side["top"],
                units=relief.units,
                exaggeration=side["exaggeration"],
                title=title,
            )
        else:  # a transect across bare ground only: nothing to put a ruler on
            xz = figures.contact_sheet([(f"{title}: bare ground", read("xz.png"))], tile=480, columns=1)
        xz = save("xz_annotated.png", xz)
        mesh = save(
            "mesh_annotated.png",
            figures.annotate_colour_bar(read("mesh.png"), max_height=relief.max_height, units=relief.units),
        )
        heights = np.round(figures.height_colours(relief.heights / relief.max_height) * 255).astype(np.uint8)
        heights = figures.annotate_colour_bar(heights, max_height=relief.max_height, units=relief.units)
    else:
        # Nothing rose: no ruler or colour bar can be labelled; the figures say so instead.
        note = f"flat relief: no {'plant' if crop['plants'] == 0 else 'height'} to measure"
        xz = save("xz_annotated.png", figures.contact_sheet([(note, read("xz.png"))], tile=480, columns=1))
        mesh = save(
            "mesh_annotated.png", figures.contact_sheet([(note, read("mesh.png"))], tile=480, columns=1)
        )
        heights = np.zeros(relief.heights.shape, np.uint8)

    def height(value):
        return "n/a" if value is None else f"{value * factor:.3g} {unit}"

    if gsd:
        units_line = f"GSD {gsd * 100:.3g} cm/px ({meta.gsd_source})"
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
        ("photo", read("xy_flat.png")),
        ("plants (mask)", read("mask.png")),
        (f"heights ({unit})", heights),
        ("lit top view (x-y)", xy),
        ("3D view", read("view3d.png")),
        ("mesh by height", mesh),
        ("side view (x-z)", xz, 2),
    ]
    save("summary.png", figures.contact_sheet(panels, facts=facts, title=Path(meta.path).name))
    return {
        **crop,
        "side_view": {
            key: side[key]
            for key in ("exaggeration", "top", "ground_row", "rows_per_unit", "strip_columns", "transect")
        },
        "figures": {"raw_renders": "unchanged", "annotated": list(FIGURES), "height_label_unit": unit},
    }
