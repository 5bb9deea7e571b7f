"""Reading a season's outputs (``season.json`` and the cached height grids), for the Blender animation.

Needs numpy only: the extension ships this module, never the runner (Dask) or the chart (matplotlib).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import CliffTerrainError


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
        corner (as in :mod:`cliff_terrain.plots`).
    crs : int or None
        EPSG code.
    units, height_mode : str
    """

    date: str
    image: str
    heights: np.ndarray
    mask: np.ndarray
    transform: np.ndarray
    crs: int | None
    units: str
    height_mode: str


@dataclass
class SeasonOutputs:
    """A season folder: its dates that computed, the ones that failed, and its plots file."""

    folder: Path
    dates: list
    failed: list  # (date, image, error)
    plots: str | None
    crs: int | None


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
