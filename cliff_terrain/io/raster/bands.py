"""Multispectral orthomosaics: named reflectance bands from one multi-band GeoTIFF or one file per band.

Reading rules (the README's "Multispectral" section):

* **Names.** A band is matched by its name: blue, green, red, red edge, NIR, LWIR (thermal). The
  name comes from ``--bands`` (`names`) when given, else from the file: GDAL's band descriptions
  (the ``GDAL_METADATA`` TIFF tag 42112, ``<Item name="DESCRIPTION" sample="N" role="description">``,
  as OpenDroneMap and GDAL write them), or, for one band per file, the file's name
  (``field_nir.tif``). Spellings are forgiving: case, spaces, dashes and wavelengths are ignored
  ("Red edge", "RedEdge", "Red-Edge 717", "NIR", "Nir", "Thermal", "B", "RE"). A 3- or 4-band file
  without names is R, G, B (and alpha), as an RGB orthophoto is.
* **Valid pixels.** An alpha band (ExtraSamples alpha, a band named alpha, or one band more than
  `names` gives) of 0, the ``GDAL_NODATA`` value in every band, a non-finite sample, or zeros in
  every band (OpenDroneMap's fill outside the flight) is no data: NaN in :attr:`Bands.data`.
* **Reflectance.** GDAL's per-band scale and offset (``role="scale"``/``"offset"`` items) are
  applied when present. Otherwise integer samples are divided by their type's maximum (uint8 255,
  uint16 65535), and float samples are reflectance as they are when the reflective bands stay
  within 1.5, else divided by 255 (an 8-bit rendering stored as float) or 65535. LWIR keeps its
  values (it enters no index).
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass

import numpy as np

from ...errors import CliffTerrainError, GeoreferenceError, MissingBandError, RasterReadError
from ._geokeys import GDAL_METADATA, GDAL_NODATA, gdal_items, georeference, nodata_value
from ._tiff_window import TiffRaster

#: The bands an index may ask for, in spectral order.
BAND_NAMES = ("blue", "green", "red", "rededge", "nir", "lwir")
_ALIASES = {
    "b": "blue",
    "blue": "blue",
    "g": "green",
    "green": "green",
    "r": "red",
    "red": "red",
    "re": "rededge",
    "rededge": "rededge",
    "edge": "rededge",
    "nir": "nir",
    "n": "nir",
    "nearinfrared": "nir",
    "nearir": "nir",
    "lwir": "lwir",
    "thermal": "lwir",
    "tir": "lwir",
    "alpha": "alpha",
}
_EXTRA_ALPHA = (1, 2)  # TIFF ExtraSamples: associated, unassociated alpha
_RGB_PHOTOMETRIC = 2


@dataclass
class Bands:
    """Named reflectance bands of one field and date on one grid.

    Attributes
    ----------
    names : tuple of str
        One of :data:`BAND_NAMES` per band, in the file's order.
    data : (rows, cols, bands) float32 array
        Reflectance (0-1), NaN where there is no data.
    valid : (rows, cols) bool array
        Pixels with data.
    transform : (3, 3) array or None
        Pixel (col, row) -> map (x, y); None without a usable georeference.
    crs : int or None
    source : str
        The file read (the files, joined by ", ").
    """

    names: tuple
    data: np.ndarray
    valid: np.ndarray
    transform: np.ndarray | None
    crs: int | None
    source: str

    @property
    def shape(self):
        return self.data.shape[:2]

    def band(self, name, *, needed_by=None):
        """The (rows, cols) float32 plane of band `name`; :class:`MissingBandError` when absent."""
        if name not in self.names:
            what = f"{needed_by} needs" if needed_by else "needs"
            raise MissingBandError(
                f"{what} a {band_label(name)} band, which {self.source!r} lacks (its bands: "
                f"{', '.join(band_label(n) for n in self.names)}); name the bands with --bands"
            )
        return self.data[..., self.names.index(name)]


def band_label(name):
    """How a band is written for people: ``"red edge"``, ``"NIR"``, ``"LWIR"``, ``"blue"``."""
    return {"rededge": "red edge", "nir": "NIR", "lwir": "LWIR"}.get(name, name)


def band_name(text):
    """The band a name means (one of :data:`BAND_NAMES` or ``"alpha"``), or None.

    Examples
    --------
    >>> band_name("Red edge"), band_name("NIR 842"), band_name("Blue-444"), band_name("Thermal")
    ('rededge', 'nir', 'blue', 'lwir')
    """
    return _ALIASES.get(re.sub(r"[^a-z]", "", str(text).lower()))


def parse_band_names(text):
    """``--bands B,G,R,RE,NIR`` -> ``("blue", "green", "red", "rededge", "nir")``; None for None."""
    if text is None:
        return None
    items = [item.strip() for item in (text.split(",") if isinstance(text, str) else text)]
    names = []
    for item in items:
        name = band_name(item)
        if name is None:
            raise CliffTerrainError(
                f"`--bands` names an unknown band {item!r} in {text!r}; use B, G, R, RE, NIR, LWIR (or alpha)"
            )
        names.append(name)
    return tuple(names)


def read_bands(paths, *, names=None):
    """Read a multispectral orthomosaic: one multi-band GeoTIFF, or one single-band file per band.

    Parameters
    ----------
    paths : str, os.PathLike or sequence of them
        The file, or one file per band on one grid.
    names : sequence of str or str, optional
        The bands' names in order (``"B,G,R,RE,NIR"``), overriding the file's own (``--bands``).

    Returns
    -------
    Bands
    """
    names = parse_band_names(names)
    if isinstance(paths, str | os.PathLike):
        paths = [paths]
    paths = [os.fspath(p) for p in paths]
    if not paths:
        raise CliffTerrainError("`paths` must name at least one band file, got none")
    if len(paths) == 1:
        return _read_file(paths[0], names)
    if names is not None and len(names) != len(paths):
        raise CliffTerrainError(f"`--bands` names {len(names)} bands for {len(paths)} band files")
    parts = []
    for index, path in enumerate(paths):
        own = (names[index],) if names is not None else _name_from_file(path)
        parts.append(_read_file(path, own))
    first = parts[0]
    for part in parts[1:]:
        same_grid = (
            part.transform is None or first.transform is None or np.allclose(part.transform, first.transform)
        )
        if part.shape != first.shape or not same_grid:
            raise RasterReadError(
                f"band file {part.source!r} is not on the grid of {first.source!r}; export the bands on one grid"
            )
    all_names = tuple(n for part in parts for n in part.names)
    _check_unique(all_names, ", ".join(paths))
    valid = np.logical_and.reduce([part.valid for part in parts])
    data = np.concatenate([part.data for part in parts], axis=2)
    data[~valid] = np.nan
    return Bands(all_names, data, valid, first.transform, first.crs, ", ".join(paths))


def is_multispectral(path):
    """True when a TIFF holds more than 4 samples or names bands other than red, green, blue in order
    (and alpha): :func:`named_bands`."""
    with TiffRaster(path, what="orthophoto") as tiff:
        return bool(named_bands(tiff))


def named_bands(tiff):
    """The band names of an open TIFF (:class:`TiffRaster`) when it is multispectral (more than 4
    samples, or bands named other than red, green, blue in order and alpha; None for a band without
    a name), else ``()``: an RGB(A) photo. A 4th band named NIR is a band, not alpha."""
    samples = tiff.samples
    descriptions, _, _ = _gdal_items(tiff.page, samples)
    names = [band_name(d) if d else None for d in descriptions]
    named = tuple(n for n in names if n and n != "alpha")
    if samples > 4 or (bool(named) and named != ("red", "green", "blue")[: len(named)]):
        return tuple(names)
    return ()


def _name_from_file(path):
    stem = os.path.splitext(os.path.basename(path))[0].lower()
    tokens = [t for t in re.split(r"[^a-z]+", stem) if t]
    pairs = [a + b for a, b in zip(tokens, tokens[1:], strict=False)]
    for token in reversed(pairs + tokens):
        name = _ALIASES.get(token)
        if name is not None and name != "alpha" and (len(token) > 1 or len(tokens) == 1):
            return (name,)
    raise CliffTerrainError(
        f"cannot tell the band of {path!r} from its name; name the bands with --bands (e.g. B,G,R,RE,NIR)"
    )


def _check_unique(names, source):
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise CliffTerrainError(f"{source!r} holds the {band_label(repeated[0])} band twice; check --bands")


def _gdal_items(page, samples):
    """(descriptions, scales, offsets) per sample from the GDAL_METADATA tag (None where absent)."""
    tag = page.tags.get(GDAL_METADATA)
    return gdal_items(None if tag is None else tag.value, samples)


def _read_file(path, names):
    with TiffRaster(path, what="orthophoto") as tiff:
        page, samples, tags = tiff.page, tiff.samples, tiff.tags
        array = tiff.read()
        planar, source = tiff.planar, tiff.path
        extrasamples = tuple(int(v) for v in (page.extrasamples or ()))
        photometric = int(page.photometric)
        descriptions, scales, offsets = _gdal_items(page, samples)
    if planar:
        array = np.moveaxis(array, 0, -1)
    if array.ndim == 2:
        array = array[..., None]
    alpha = {samples - len(extrasamples) + i for i, v in enumerate(extrasamples) if v in _EXTRA_ALPHA}
    alpha |= {i for i, d in enumerate(descriptions) if d and band_name(d) == "alpha"}
    if names is not None:
        if len(names) == samples - 1 and not alpha:
            alpha = {samples - 1}
        if len(names) != samples - len(alpha) and len(names) != samples:
            raise CliffTerrainError(
                f"`--bands` names {len(names)} bands but {source!r} holds {samples - len(alpha)} (besides alpha)"
            )
        if len(names) == samples:
            alpha = {i for i, n in enumerate(names) if n == "alpha"}
            order = [i for i in range(samples) if i not in alpha]
            names = tuple(n for n in names if n != "alpha")
        else:
            order = [i for i in range(samples) if i not in alpha]
    else:
        order = [i for i in range(samples) if i not in alpha]
        named = [band_name(descriptions[i]) if descriptions[i] else None for i in order]
        if all(named):
            names = tuple(named)
        elif len(order) == 3 and not any(named) or photometric == _RGB_PHOTOMETRIC and len(order) == 3:
            names = ("red", "green", "blue")
        elif len(order) == 4 and samples == 4 and not any(named) and not extrasamples:
            # An RGB orthophoto's fourth band is alpha (as the photo reader takes it).
            alpha, order, names = {3}, [0, 1, 2], ("red", "green", "blue")
        else:
            missing = [str(i + 1) for i, n in zip(order, named, strict=True) if not n]
            raise CliffTerrainError(
                f"{source!r} does not name its band(s) {', '.join(missing)}; name the bands with --bands "
                "(e.g. --bands B,G,R,RE,NIR)"
            )
    _check_unique(names, source)
    try:
        transform, crs = georeference(tags, source)
    except (GeoreferenceError, RasterReadError):
        transform, crs = None, None  # a plain multi-band photo: indices still work, plots do not
    nodata = nodata_value(tags.get(GDAL_NODATA), source)
    raw = array[..., order]
    valid = _valid(raw, nodata)
    for index in alpha:
        valid &= array[..., index] > 0
    data = _reflectance(raw, names, [scales[i] for i in order], [offsets[i] for i in order], valid)
    data[~valid] = np.nan
    return Bands(tuple(names), data, valid, transform, crs, source)


def _valid(raw, nodata):
    valid = np.ones(raw.shape[:2], dtype=bool)
    if raw.dtype.kind == "f":
        valid &= np.all(np.isfinite(raw), axis=2)
    if nodata is not None and np.isfinite(nodata):
        if raw.dtype.kind == "f" and nodata < -1e38:  # OpenDroneMap's -3.4e38 is not a float32
            valid &= ~np.all(raw < -1e38, axis=2)
        else:
            valid &= ~np.all(raw == np.asarray(nodata).astype(raw.dtype), axis=2)
    elif nodata is not None:
        valid &= ~np.all(np.isnan(raw), axis=2)
    with np.errstate(invalid="ignore"):
        valid &= np.any(raw != 0, axis=2)  # OpenDroneMap's zero fill outside the flight
    return valid


def _reflectance(raw, names, scales, offsets, valid):
    data = raw.astype(np.float32)
    explicit = [s is not None or o is not None for s, o in zip(scales, offsets, strict=True)]
    for index, (scale, offset) in enumerate(zip(scales, offsets, strict=True)):
        if explicit[index]:
            data[..., index] = data[..., index] * np.float32(scale or 1.0) + np.float32(offset or 0.0)
    reflective = [i for i, n in enumerate(names) if n != "lwir" and not explicit[i]]
    if not reflective:
        return data
    if raw.dtype.kind in "ui":
        divisor = float(np.iinfo(raw.dtype).max)
    else:
        values = data[..., reflective][valid]
        top = float(values.max()) if values.size else 1.0
        divisor = 1.0 if top <= 1.5 else 255.0 if top <= 255.0 + 1e-3 else 65535.0
    if divisor != 1.0:
        data[..., reflective] /= np.float32(divisor)
    return data


def rgb_rendering(bands, channels=("red", "green", "blue")):
    """An 8-bit RGB rendering of `bands` (the relief's texture): true colour, or a false colour.

    `channels` names the bands shown as red, green and blue (``("nir", "red", "green")`` is the
    usual colour-infrared). One gain for the three (the 99.5th percentile of their valid pixels
    maps to 255) keeps the colours' balance. Without a blue band, true colour falls back to
    NIR-red-green (or red edge-red-green).

    Returns
    -------
    rgb : (rows, cols, 3) uint8 array
    valid : (rows, cols) bool array or None
        None when every pixel holds data.
    """
    channels = tuple(channels)
    if channels == ("red", "green", "blue") and "blue" not in bands.names:
        near = "nir" if "nir" in bands.names else "rededge"
        channels = (near, "red", "green")
    planes = np.stack([bands.band(c, needed_by="the colour rendering") for c in channels], axis=2)
    values = planes[bands.valid]
    top = float(np.percentile(values, 99.5)) if values.size else 1.0
    gain = 255.0 / top if top > 0 else 1.0
    rgb = np.clip(np.nan_to_num(planes, nan=0.0) * np.float32(gain) + np.float32(0.5), 0, 255).astype(
        np.uint8
    )
    return np.ascontiguousarray(rgb), (None if bands.valid.all() else bands.valid)
