"""Vegetation indices of multispectral bands, each defined once: its formula, bands and reference.

:data:`INDICES` holds the definitions (the index table of docs/concepts/multispectral.md is this table); :func:`index_map`
computes one as a float32 map, NaN where it is undefined (no data, or a zero denominator). Bands
are reflectance from :func:`cliff_terrain.io.raster.bands.read_bands`. An index whose band the file lacks
raises :class:`~cliff_terrain.errors.MissingBandError` naming the index, the band and the file.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..errors import CliffTerrainError


@dataclass(frozen=True)
class IndexDefinition:
    """One vegetation index: its name, formula (B, G, R, RE, NIR reflectance), bands and reference;
    `ratio(**bands)` gives the formula's (numerator, denominator) from the bands' planes."""

    name: str
    formula: str
    bands: tuple
    reference: str
    ratio: Callable


def _normalized(a, b):
    return a - b, a + b


INDICES = {
    d.name: d
    for d in (
        IndexDefinition(
            "ExG",
            "2g - r - b, with r, g, b = R, G, B / (R + G + B)",
            ("red", "green", "blue"),
            "Woebbecke et al. 1995",
            lambda red, green, blue: (2 * green - red - blue, red + green + blue),
        ),
        IndexDefinition(
            "NGRDI",
            "(G - R) / (G + R)",
            ("red", "green"),
            "Tucker 1979",
            lambda red, green: _normalized(green, red),
        ),
        IndexDefinition(
            "VARI",
            "(G - R) / (G + R - B)",
            ("red", "green", "blue"),
            "Gitelson et al. 2002",
            lambda red, green, blue: (green - red, green + red - blue),
        ),
        IndexDefinition(
            "GLI",
            "(2G - R - B) / (2G + R + B)",
            ("red", "green", "blue"),
            "Louhaichi et al. 2001",
            lambda red, green, blue: (2 * green - red - blue, 2 * green + red + blue),
        ),
        IndexDefinition(
            "NDVI",
            "(NIR - R) / (NIR + R)",
            ("nir", "red"),
            "Rouse et al. 1974",
            lambda nir, red: _normalized(nir, red),
        ),
        IndexDefinition(
            "NDRE",
            "(NIR - RE) / (NIR + RE)",
            ("nir", "rededge"),
            "Barnes et al. 2000",
            lambda nir, rededge: _normalized(nir, rededge),
        ),
        IndexDefinition(
            "GNDVI",
            "(NIR - G) / (NIR + G)",
            ("nir", "green"),
            "Gitelson et al. 1996",
            lambda nir, green: _normalized(nir, green),
        ),
        IndexDefinition(
            "OSAVI",
            "(NIR - R) / (NIR + R + 0.16)",
            ("nir", "red"),
            "Rondeaux et al. 1996",
            lambda nir, red: (nir - red, nir + red + np.float32(0.16)),
        ),
    )
}


def parse_indices(text):
    """``"NDVI,ndre"`` -> ``("NDVI", "NDRE")`` (case-insensitive, repeats dropped); () for None or "".

    Examples
    --------
    >>> parse_indices("ndvi, NDRE,NDVI")
    ('NDVI', 'NDRE')
    """
    if text is None:
        return ()
    items = text.split(",") if isinstance(text, str) else list(text)
    by_key = {name.lower(): name for name in INDICES}
    names = []
    for item in items:
        key = str(item).strip().lower()
        if not key:
            continue
        if key not in by_key:
            raise CliffTerrainError(
                f"`--indices` names an unknown index {str(item).strip()!r}; choose from {', '.join(INDICES)}"
            )
        if by_key[key] not in names:
            names.append(by_key[key])
    return tuple(names)


def index_map(bands, name):
    """Index `name` (a key of :data:`INDICES`) of `bands` as a (rows, cols) float32 map.

    NaN where a band has no data or the denominator is zero.

    Examples
    --------
    >>> from cliff_terrain.io.raster.bands import Bands
    >>> data = np.array([[[0.05, 0.5]]], np.float32)            # red, NIR
    >>> bands = Bands(("red", "nir"), data, np.ones((1, 1), bool), None, None, "x.tif")
    >>> round(float(index_map(bands, "NDVI")[0, 0]), 4)
    0.8182
    """
    if name not in INDICES:
        raise CliffTerrainError(f"`name` must be one of {', '.join(INDICES)}, got {name!r}")
    definition = INDICES[name]
    planes = {b: bands.band(b, needed_by=name).astype(np.float32, copy=False) for b in definition.bands}
    with np.errstate(invalid="ignore"):  # no-data planes hold NaN; the ratio stays NaN there
        numerator, denominator = definition.ratio(**planes)
    values = np.full(denominator.shape, np.nan, np.float32)
    np.divide(numerator, denominator, out=values, where=denominator != 0)
    return values


def check_indices(bands, names):
    """Refuse (one :class:`MissingBandError`) the first of `names` that needs a band `bands` lacks."""
    for name in names:
        for band in INDICES[name].bands:
            bands.band(band, needed_by=name)


def index_maps(bands, names, *, shape=None):
    """{name: map} of `names` on `bands`' grid, or averaged onto a grid of `shape` (rows, cols).

    The average over each target pixel's footprint skips pixels without data (NaN): the map of a
    coarser relief grid is the mean of the finer index, not the index of mean bands.
    """
    check_indices(bands, names)
    maps = {}
    for name in names:
        values = index_map(bands, name)
        if shape is not None and tuple(shape) != values.shape:
            values = resample_mean(values, shape)
        maps[name] = values
    return maps


def resample_mean(values, shape):
    """`values` (NaN = no data) averaged onto a (rows, cols) grid over the same extent."""
    import cv2  # here: the sidebar imports this module's definitions before the extension's libraries

    finite = np.isfinite(values)
    size = (int(shape[1]), int(shape[0]))
    total = cv2.resize(np.where(finite, values, 0).astype(np.float32), size, interpolation=cv2.INTER_AREA)
    weight = cv2.resize(finite.astype(np.float32), size, interpolation=cv2.INTER_AREA)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(weight > 0.25, total / np.maximum(weight, 1e-6), np.nan).astype(np.float32)


def available_indices(band_names):
    """The indices bands of these names allow, e.g. ``ImageMetadata.band_names`` (none for None)."""
    names = set(band_names or ())
    return tuple(name for name, definition in INDICES.items() if set(definition.bands) <= names)


def nir_index_map(bands, *, shape):
    """NDVI for segmentation on a grid of `shape` when `bands` hold NIR and red, else None."""
    if bands is None or "nir" not in bands.names or "red" not in bands.names:
        return None
    return index_maps(bands, ("NDVI",), shape=shape)["NDVI"]


def red_map(bands, *, shape):
    """The red reflectance on a grid of `shape` (the NDVI threshold's colour test), or None."""
    if bands is None or "red" not in bands.names:
        return None
    red = bands.band("red")
    return red if tuple(shape) == red.shape else resample_mean(red, shape)
