"""Reading a season's outputs (``season.json`` and the cached height grids), for the Blender animation.

Needs numpy only: the extension ships this module, never the runner (Dask) or the chart (matplotlib).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import CliffTerrainError
from ..measure.index_figures import index_columns
from ..photo_heights.indices import INDICES


@dataclass
class SeasonDate:
    """One date of a computed season.

    Attributes
    ----------
    date : str
        ISO date.
    image : str
        The photo.
    heights : (rows, cols) float32
        The relief's heights on its processing grid, in `units`.
    mask : (rows, cols) bool
        Plant pixels.
    transform : (2, 3) float64 array
        Pixel (col, row) -> map (x, y) of the grid, (0, 0) being the top-left pixel's top-left
        corner (as in :mod:`cliff_terrain.io.raster.transform`).
    crs : int, str or None
        EPSG code, or the WKT of a user-defined CRS (:func:`cliff_terrain.io.raster.crs.crs_record`).
    units, height_mode : str
    """

    date: str
    image: str
    heights: np.ndarray
    mask: np.ndarray
    transform: np.ndarray
    crs: int | str | None
    units: str
    height_mode: str


@dataclass
class SeasonOutputs:
    """A season folder: its dates that computed, the ones that failed, and its plots file."""

    folder: Path
    dates: list
    failed: list  # (date, image, error)
    plots: str | None
    crs: int | str | None


def read_season(folder):
    """Read ``FOLDER/season.json`` and each successful date's height grid, sorted by date.

    Raises
    ------
    CliffTerrainError
        When the folder holds no season or none of its dates computed.
    """
    folder = Path(folder)
    manifest_path = folder / "season.json"
    try:
        manifest = json.loads(manifest_path.read_text())
    except FileNotFoundError:
        raise CliffTerrainError(
            f"no season in {str(folder)!r}: {manifest_path.name} is missing (run `cliff-terrain season` first)"
        ) from None
    except (OSError, ValueError) as exc:
        raise CliffTerrainError(f"cannot read {str(manifest_path)!r}: {exc}") from None
    dates, failed = [], []
    for record in sorted(manifest.get("dates", []), key=lambda r: r["date"]):
        if record.get("error"):
            failed.append((record["date"], record["image"], record["error"]))
            continue
        arrays_path = folder / record["arrays"]
        try:
            with np.load(arrays_path) as data:
                heights = data["heights"].astype(np.float32, copy=False)
                mask = np.unpackbits(data["mask"], count=heights.size).reshape(heights.shape).astype(bool)
        except (OSError, KeyError, ValueError) as exc:
            raise CliffTerrainError(
                f"cannot read the heights of {record['date']} ({arrays_path}): {exc}"
            ) from None
        grid = record["grid"]
        dates.append(
            SeasonDate(
                date=record["date"],
                image=record["image"],
                heights=heights,
                mask=mask,
                transform=np.asarray(grid["transform"], dtype=np.float64).reshape(2, 3),
                crs=grid.get("crs"),
                units=record["height_units"],
                height_mode=record["height_mode"],
            )
        )
    if not dates:
        raise CliffTerrainError(f"the season in {str(folder)!r} has no computed date")
    return SeasonOutputs(
        folder=folder, dates=dates, failed=failed, plots=manifest.get("plots"), crs=manifest.get("crs")
    )


# season.csv's per-date figures a frame can be coloured by (the rest are labels and text).
DATE_COLUMNS = ("cover", "area_m2", "volume_m3", "height_mean", "height_p50", "height_p90", "height_max")
_INDEX_COLUMNS = frozenset(index_columns(INDICES))
# Where `cliff-terrain traits SEASON` writes its per-plot table.
TRAITS_TABLE = Path("traits") / "traits.csv"


@dataclass
class PlotColours:
    """Each plot's value on each date, for colouring a season's frames (:func:`plot_colours`).

    Attributes
    ----------
    name : str
        The column.
    source : str
        ``season.csv`` (a value per date) or ``traits/traits.csv`` (one per plot, on every date).
    values : (dates, plots) float64 array
        In the order of the season's dates and the plots file; NaN where a plot has none. Date
        traits are days since 1970-01-01.
    low, high : float
        The scale, shared by every date: the season's smallest and largest value.
    is_date : bool
        The values are dates.
    """

    name: str
    source: str
    values: np.ndarray
    low: float
    high: float
    is_date: bool = False

    def normalised(self, index):
        """Date `index`'s values on the scale, 0 (low) to 1 (high); NaN stays NaN."""
        span = self.high - self.low
        values = self.values[index]
        return (values - self.low) / span if span > 0 else np.where(np.isnan(values), np.nan, 0.5)

    def text(self, value):
        """A value as the legend writes it."""
        if self.is_date:
            import datetime as dt

            return (dt.date(1970, 1, 1) + dt.timedelta(days=round(value))).isoformat()
        return f"{value:.3g}"

    def legend(self):
        """The scale in a few words, as stamped on the frames."""
        return f"{self.name}: {self.text(self.low)} (purple) to {self.text(self.high)} (yellow)"

    def describe(self):
        """One line: the name, where it comes from and the scale's two ends (viridis)."""
        per = "per date" if self.source == "season.csv" else "per plot"
        return (
            f"{self.name} ({self.source}, {per}): {self.text(self.low)} (purple) to "
            f"{self.text(self.high)} (yellow), viridis"
        )


def plot_colours(season, name, *, n_plots):
    """The values of column `name` for each date and plot of `season`, on one scale.

    Parameters
    ----------
    season : SeasonOutputs
        From :func:`read_season`.
    name : str
        A per-date column of ``season.csv`` (``DATE_COLUMNS``: ``cover``, ``height_p90``, ...; the
        vegetation index columns ``ndvi_mean``, ``ndvi_plant_median`` ... when it has them) or a
        numeric or date column of ``traits/traits.csv`` (``max_height_m``, ``senescence_date``, ...;
        written by ``cliff-terrain traits SEASON``).
    n_plots : int
        The number of plots in the season's plots file.

    Returns
    -------
    PlotColours

    Raises
    ------
    CliffTerrainError
        For a `name` in neither table (the message lists the names there are), or one without a
        single value.
    """
    import csv

    tables = {}
    for source in ("season.csv", TRAITS_TABLE.as_posix()):
        path = season.folder / source
        if path.is_file():
            with open(path, newline="", encoding="utf-8") as stream:
                tables[source] = list(csv.DictReader(stream))
    season_rows = tables.get("season.csv", [])
    columns = {n: "season.csv" for n in DATE_COLUMNS if season_rows and n in season_rows[0]}
    # The vegetation index columns (``ndvi_mean`` ...) of a season run with --indices.
    columns.update({n: "season.csv" for n in (season_rows[0] if season_rows else ()) if n in _INDEX_COLUMNS})
    attributes = set(season_rows[0]) if season_rows else set()
    for row in tables.get(TRAITS_TABLE.as_posix(), [])[:1]:
        for column in row:
            if column not in attributes and column not in columns:
                columns[column] = TRAITS_TABLE.as_posix()
    trait_rows = tables.get(TRAITS_TABLE.as_posix(), [])
    usable = {n: s for n, s in columns.items() if s == "season.csv" or _kind([r.get(n) for r in trait_rows])}
    if name not in usable:
        raise CliffTerrainError(
            f"`color_by` must be one of {', '.join(usable) or 'nothing (the season has no season.csv)'}, "
            f"got {name!r}" + ("" if trait_rows else " (traits appear after `cliff-terrain traits SEASON`)")
        )
    source = usable[name]
    dates = [d.date for d in season.dates]
    values = np.full((len(dates), n_plots), np.nan)
    is_date = False
    if source == "season.csv":
        row_of = {date: i for i, date in enumerate(dates)}
        for row in season_rows:
            i, plot = row_of.get(row["date"]), int(row["plot"])
            if i is not None and 0 <= plot < n_plots and row.get(name):
                values[i, plot] = float(row[name])
    else:
        is_date = _kind([r.get(name) for r in trait_rows]) == "date"
        for row in trait_rows:
            plot = int(row["plot"])
            if 0 <= plot < n_plots and row.get(name):
                values[:, plot] = _number(row[name])
    finite = values[np.isfinite(values)]
    if not finite.size:
        raise CliffTerrainError(f"`color_by` {name!r} has no value in {source} for any plot")
    return PlotColours(
        name=name,
        source=source,
        values=values,
        low=float(finite.min()),
        high=float(finite.max()),
        is_date=is_date,
    )


def _number(text):
    """A cell as a number: a float, or an ISO date as days since 1970-01-01."""
    import datetime as dt

    try:
        return float(text)
    except ValueError:
        return float((dt.date.fromisoformat(text) - dt.date(1970, 1, 1)).days)


def _kind(cells):
    """ "number" or "date" when every non-empty cell is one (and one is there), else None."""
    filled = [c for c in cells if c]
    if not filled:
        return None
    try:
        [float(c) for c in filled]
        return "number"
    except ValueError:
        pass
    import datetime as dt

    try:
        [dt.date.fromisoformat(c) for c in filled]
        return "date"
    except ValueError:
        return None
