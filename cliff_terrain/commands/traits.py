"""``cliff-terrain traits SEASON_DIR [--out DIR]``: breeders' traits per plot from a computed season.

Reads ``SEASON_DIR/season.csv`` (and ``season.json`` for the plots file), fits each plot's growth curves
(:mod:`cliff_terrain.season.traits`) and writes, into ``--out`` (default ``SEASON_DIR/traits``):
``traits.csv`` (one row per plot, the plot's attributes kept), ``traits.geojson`` when the season has
plot polygons, ``growth.png`` (measured points and fitted curves) and ``traits_map.png`` (one trait
over the plots, with a colour bar). All or nothing; existing files are kept without ``--overwrite``.
"""

from __future__ import annotations

from pathlib import Path

HELP = "growth curves and traits per plot (max height, growth rate, closure, senescence) from a season"


def configure(parser):
    parser.add_argument("season", type=Path, help="the folder `cliff-terrain season --out` wrote")
    parser.add_argument("--out", type=Path, default=None, help="output folder (default: SEASON/traits)")
    parser.add_argument(
        "--model", choices=("auto", "logistic", "gompertz", "double", "spline"), default="auto",
        help="the height curve's model (default auto: the lowest AICc, recorded per plot)",
    )  # fmt: skip
    parser.add_argument(
        "--closure", type=float, default=0.9, help="cover at which the canopy is closed (0-1, default 0.9)"
    )
    parser.add_argument("--color-by", default=None, help="a plot attribute or trait to colour growth.png by")
    parser.add_argument(
        "--trait",
        default="max_height_m",
        help="the column of traits.csv that traits_map.png shows (default max_height_m)",
    )
    parser.add_argument("--overwrite", action="store_true", help="replace existing output files")


def run(args):
    import csv
    import json

    from .._deps import require_extra
    from ..errors import CliffTerrainError
    from ..measure.tables import previous_outputs, table_csv, write_files
    from ..season.traits import SEASON_COLUMNS, TRAIT_COLUMNS, TRAITS_OUTPUTS, season_traits
    from .out_folder import check_out_folder, finished_outputs

    table = args.season / "season.csv"
    if not table.is_file():
        raise CliffTerrainError(f"{str(table)!r} does not exist: run `cliff-terrain season` first")
    out = args.out or args.season / "traits"
    manifest = args.season / "season.json"
    season = json.loads(manifest.read_text()) if manifest.is_file() else {}
    plots_path = season.get("plots")
    # Without plot polygons there is neither a GeoJSON nor a map.
    outputs = [n for n in TRAITS_OUTPUTS if plots_path or n not in ("traits.geojson", "traits_map.png")]
    check_out_folder(out)
    if not args.overwrite:  # the last file written marks a finished run
        existing = finished_outputs(out, outputs, marker=outputs[-1])
        if existing:
            raise CliffTerrainError(f"{str(out / existing[0])!r} exists; pass --overwrite to replace it")
    with open(table, newline="", encoding="utf-8") as stream:
        rows = list(csv.DictReader(stream))
    # The names a chart can use, checked before the fits: the plots' attributes and the traits.
    known = {name for name in (rows[0] if rows else {}) if name not in SEASON_COLUMNS} | {
        "plot",
        *TRAIT_COLUMNS,
    }
    if args.color_by is not None and args.color_by not in known:
        raise CliffTerrainError(
            f"`--color-by` must be a plot attribute or trait ({', '.join(sorted(known))}), got {args.color_by!r}"
        )
    if plots_path and args.trait not in known:
        raise CliffTerrainError(
            f"`--trait` must be a column of traits.csv ({', '.join(sorted(known))}), got {args.trait!r}"
        )
    require_extra("matplotlib", extra="season", needed_by="drawing the traits' figures")  # before the fits
    traits = season_traits(rows, model=args.model, closure=args.closure)
    columns = list(traits[0]) if traits else ["plot", *TRAIT_COLUMNS]
    files = {out / "traits.csv": table_csv(traits, columns)}
    plots = None
    if plots_path:
        from ..io.vector.geojson import polygon_geometries, table_geojson
        from ..io.vector.plot_polygons import read_plots

        plots = read_plots(plots_path)
        by_index = {str(t["plot"]): t for t in traits}
        geometries = polygon_geometries(plots)
        features = [(by_index[str(i)], g) for i, g in enumerate(geometries) if str(i) in by_index]
        files[out / "traits.geojson"] = table_geojson(
            [f for f, _ in features], [g for _, g in features], crs=plots.crs or season.get("crs")
        )

    from ..season.trait_charts import growth_curves_chart, traits_map

    files[out / "growth.png"] = lambda tmp: growth_curves_chart(rows, traits, tmp, color_by=args.color_by)
    if plots is not None:
        files[out / "traits_map.png"] = lambda tmp: traits_map(plots, traits, tmp, trait=args.trait)
    try:
        out.mkdir(parents=True, exist_ok=True)
        # An interrupted run's map and polygons (its renaming journal lists them), from a season with
        # plots, do not stay beside a table of one without them.
        every = ("traits.csv", "traits.geojson", "growth.png", "traits_map.png")
        write_files(files, remove=previous_outputs(out, [n for n in every if n not in outputs]))
    except OSError as exc:
        raise CliffTerrainError(f"cannot write into {str(out)!r}: {exc}") from None
    flagged = sum(1 for t in traits if t["flag"])
    print(f"{len(traits)} plots ({flagged} flagged); wrote {', '.join(outputs)} into {out}")
    return 0
