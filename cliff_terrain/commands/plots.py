"""``cliff-terrain plots ORTHO --grid CxR --plot-size WxL (--corners ... | --origin X,Y) --out FILE``: plot polygons.

Builds a trial's plot polygons from its layout (:mod:`cliff_terrain.measure.plot_grid`), optionally snapped to
the crop (``--fit``, :mod:`cliff_terrain.measure.plot_fit`; with no placement the fit places the grid itself),
checks them against the orthophoto (inside it, not overlapping) and writes GeoJSON, or an ESRI
Shapefile when FILE ends in ``.shp``, in the orthophoto's CRS. With ``--fit`` the fit's report is also
written beside FILE as ``FILE.fit.json``. With ``--corners`` and ``--fit`` the corners are constraints
(``--tolerance``): every plot carries ``fit_shift_m``, ``fit_confidence`` and ``fit_flag``, and a fit
that is not accepted keeps the unfitted plots, flagged. The output feeds ``heights --plots`` and ``season --plots``.
"""

from __future__ import annotations

import os
from pathlib import Path

from .._progress import add_progress_argument

HELP = "plot polygons from a trial layout (columns x rows, plot size, alleys), optionally fitted to the crop"


def configure(parser):
    parser.add_argument("ortho", type=Path, help="the orthophoto GeoTIFF (its CRS is the plots')")
    parser.add_argument(
        "--grid", required=True, metavar="COLUMNSxROWS", help="plots across x along the columns"
    )
    parser.add_argument(
        "--plot-size",
        required=True,
        metavar="WIDTHxLENGTH",
        help="metres: width across the columns, length along",
    )
    parser.add_argument(
        "--corners",
        nargs=4,
        metavar="X,Y",
        default=None,
        help="the grid's four outer corners (map), any order",
    )
    parser.add_argument(
        "--origin",
        metavar="X,Y",
        default=None,
        help="map point of the grid's (0, 0) corner, the one the columns step away from along --angle "
        "and the plots run from at 90 degrees counter-clockwise: with --angle 0, its south-west "
        "(lower-left) corner, the grid growing east and north (plot 1's corner is --start)",
    )
    parser.add_argument(
        "--angle",
        type=float,
        default=None,
        help="direction across the columns, degrees from east (counter-clockwise)",
    )
    parser.add_argument(
        "--pitch", metavar="CxR", default=None, help="column and row pitch, metres (start to start)"
    )
    parser.add_argument(
        "--alleys",
        metavar="CxR",
        default=None,
        help="gaps between columns and between rows, metres; a comma list for uneven alleys (0.1x1,1.5,1)",
    )
    parser.add_argument("--numbering", choices=("serpentine", "rows", "columns"), default="serpentine")
    parser.add_argument(
        "--start", choices=("top-left", "top-right", "bottom-left", "bottom-right"), default="top-left",
        help="the corner of plot 1 on the map (north up)",
    )  # fmt: skip
    parser.add_argument(
        "--buffer", default="0", metavar="B|WxL", help="metres trimmed from each side of a plot"
    )
    parser.add_argument(
        "--field-book", type=Path, default=None, help="CSV joined by plot, or by column and row"
    )
    parser.add_argument(
        "--fit", action="store_true", help="snap the grid to the crop (or place it, with no placement)"
    )
    parser.add_argument(
        "--tolerance",
        type=float,
        default=None,
        metavar="METRES",
        help="with --corners and --fit: how far the fit may move each given corner, along each of the "
        "grid's axes (default: half the plot's smaller side, at most half a pitch); the pitch is "
        "what the corners and counts imply, refined within it. A fit that would move a corner "
        "further (or is pulled against that bound across touching rows), or whose confidence is "
        "below 0.5, keeps the unfitted plots and flags them (fit_flag 1). Confidence (0-1, in the "
        ".fit.json and on every plot): the score the fit would lose to the same grid shifted by "
        "half a pitch (one pitch without corners), in units of one column's or row's plant "
        "pixels, the smaller of the two axes, times the share of the plots holding crop",
    )
    parser.add_argument("--out", type=Path, required=True, help="plots.geojson or plots.shp")
    parser.add_argument("--overwrite", action="store_true", help="replace existing output files")
    add_progress_argument(parser)


def _counts(text):
    from ..errors import CliffTerrainError

    parts = text.lower().split("x")
    try:
        columns, rows = (int(p) for p in parts)
    except ValueError:
        raise CliffTerrainError(f"`--grid` must be COLUMNSxROWS like 14x10, got {text!r}") from None
    if columns < 1 or rows < 1:
        raise CliffTerrainError(f"`--grid` needs at least one column and one row, got {text!r}")
    return columns, rows


def _alleys(text):
    from ..errors import CliffTerrainError

    parts = text.lower().split("x")
    if len(parts) != 2:
        raise CliffTerrainError(
            f"`--alleys` must be COLUMNxROW gaps like 0.1x1.0 (lists: 0.1x1,1.5,1), got {text!r}"
        )
    try:
        return tuple([float(v) for v in part.split(",")] for part in parts)
    except ValueError:
        raise CliffTerrainError(f"`--alleys` must be numbers, got {text!r}") from None


def _write_together(out, write, report):
    """Write the plot files into a temporary folder beside `out`, then rename them into place, `out`
    last: Ctrl-C or a kill never leaves files that look like a finished run."""
    import json
    import shutil
    import tempfile

    folder = Path(tempfile.mkdtemp(prefix=f".{out.name}.part-", dir=out.parent))
    try:
        written = write(folder / out.name)
        if report is not None:
            fit = folder / (out.name + ".fit.json")
            fit.write_text(json.dumps(report, indent=2) + "\n")
            written.append(fit)
        for path in sorted(written, key=lambda p: p.name == out.name):
            os.replace(path, out.with_name(path.name))
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def run(args):
    from .._progress import stage_bar

    with stage_bar(f"plots {args.ortho.name}", enabled=not args.no_progress) as progress:
        return _run(args, progress or (lambda fraction, stage: None))


def _run(args, progress):
    from ..errors import CliffTerrainError
    from ..io.raster.crs import crs_text
    from ..io.raster.geotiff import read_orthophoto
    from ..io.vector.plot_files import check_plots_fit, read_field_book, write_plots
    from ..measure.plot_grid import parse_pair, place_grid, plots_from

    out = args.out
    if out.suffix.lower() not in (".geojson", ".json", ".shp"):
        raise CliffTerrainError(
            f"`--out` {str(out)!r} must end in .geojson (or .json) or .shp: the formats the plots are written in"
        )
    columns, rows = _counts(args.grid)
    size = parse_pair(args.plot_size, "--plot-size")
    pitch = parse_pair(args.pitch, "--pitch") if args.pitch else None
    alleys = _alleys(args.alleys) if args.alleys else None
    buffer = parse_pair(args.buffer, "--buffer") if "x" in args.buffer.lower() else (float(args.buffer),) * 2
    corners = [parse_pair(c, "--corners") for c in args.corners] if args.corners else None
    origin = parse_pair(args.origin, "--origin") if args.origin else None
    tolerance = None
    if args.tolerance is not None:
        if args.tolerance < 0 or args.tolerance != args.tolerance:
            raise CliffTerrainError(f"`--tolerance` must be >= 0 metres, got {args.tolerance:g}")
        if corners is None or not args.fit:
            raise CliffTerrainError("`--tolerance` bounds how far --fit moves --corners: give both")
        tolerance = args.tolerance
    elif corners is not None and args.fit:
        # Half the plot's smaller side: never half a pitch, so the fit cannot move a whole column.
        tolerance = 0.5 * min(size)
    if corners is None and origin is None and not args.fit:
        raise CliffTerrainError("place the grid: give `--corners`, `--origin` (and `--angle`), or `--fit`")
    outputs = [out] + (
        [out.with_suffix(s) for s in (".shx", ".dbf", ".prj")] if out.suffix.lower() == ".shp" else []
    )
    if args.fit:
        outputs.append(out.with_name(out.name + ".fit.json"))
    if not args.overwrite:
        # FILE is renamed last: without it, the others are an interrupted run's and are replaced.
        existing = [p for p in outputs if p.exists()] if out.exists() else []
        if existing:
            raise CliffTerrainError(f"{str(existing[0])!r} exists; pass --overwrite to replace it")
    book = read_field_book(args.field_book) if args.field_book else None  # a bad book fails before the work
    progress(0.0, "reading the orthophoto")
    ortho = read_orthophoto(args.ortho)
    if corners is None and origin is None:  # placed by the fit alone: a layout at the map's origin
        layout, placement = place_grid(
            columns, rows, plot_size=size, origin=(0.0, 0.0), pitch=pitch, alleys=alleys
        )
        placement = None
    else:
        layout, placement = place_grid(
            columns, rows, plot_size=size, corners=corners, origin=origin,
            angle=0.0 if args.angle is None else args.angle, pitch=pitch, alleys=alleys,
        )  # fmt: skip
    report = None
    given = (layout, placement)
    if args.fit:
        from ..measure.canopy import plant_mask
        from ..measure.plot_fit import fit_grid

        progress(0.3, "fitting the grid to the crop")
        plants = plant_mask(ortho.data, valid=ortho.valid)
        fit = fit_grid(
            plants,
            ortho.transform,
            layout,
            placement=placement if corners is not None else None,  # an --origin is pinned instead
            angle=args.angle,
            pitch=pitch,
            origin=origin,
            valid=ortho.valid,  # the no-data border is neither crop nor soil
            tolerance=tolerance,
        )
        report = fit.report
    numbering = dict(
        numbering=args.numbering, start=args.start, buffer=buffer, field_book=book, crs=ortho.crs
    )
    if report is not None and tolerance is not None:
        from ..measure.fit_flags import fitted_plots

        plots = fitted_plots(*given, fit, **numbering)
    elif report is not None:
        plots = plots_from(fit.layout, fit.placement, **numbering)
    else:
        plots = plots_from(layout, placement, **numbering)
    progress(0.9, "writing")
    check_plots_fit(plots, transform=ortho.transform, shape=ortho.shape, source=str(args.ortho))
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        _write_together(out, lambda tmp: write_plots(plots, tmp, crs=ortho.crs), report)
    except OSError as exc:
        raise CliffTerrainError(f"cannot write {str(out)!r}: {exc}") from None
    line = f"{args.ortho}: {len(plots)} plots ({columns} columns x {rows} rows) in {crs_text(ortho.crs)}"
    if report is not None:
        line += (
            f"; fitted: angle {report['angle_deg']:.2f} deg, pitch {report['column_pitch_m']:.3f} x "
            f"{report['row_pitch_m']:.3f} m, {report['plant_share_in_plots']:.1%} of the plant pixels in plots, "
            f"confidence {report['confidence']:.2f}"
        )
        if not report.get("accepted", True):
            line += (
                f"; NOT accepted ({report['refused_because']}): kept the unfitted plots, flagged fit_flag=1"
            )
    print(f"{line}; wrote {out}")
    return 0
