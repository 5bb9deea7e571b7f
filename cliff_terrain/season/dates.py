"""The date of each photo of a season, and where it came from.

In this order: the date given on the command line (``--dates NAME=YYYY-MM-DD``: what the user
says wins), EXIF ``DateTimeOriginal`` (when the camera took the photo), a ``YYYYMMDD`` or
``YYYY-MM-DD`` in the file name, then the TIFF ``DateTime`` tag. That tag says when the file was
written: an orthomosaic's is the day it was processed or saved again, not the flight's (a season
dated so put a flight of June in September). Only the file's header is read. Needs Pillow only.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import os
import re
from pathlib import Path

from ..errors import CliffTerrainError

# Where a date came from, as the season table's `date_source` column spells it.
SOURCES = ("exif", "tiff", "filename", "option")

_EXIF_IFD = 0x8769
_DATETIME_ORIGINAL = 0x9003
_DATETIME = 0x0132
# Eight digits, or four-two-two with dashes, not inside a longer run of digits.
_NAME_DATE = re.compile(r"(?<!\d)(\d{4})(-?)(\d{2})\2(\d{2})(?!\d)")


def photo_date(path, *, given=None):
    """The date a photo was taken and the source of that date.

    Parameters
    ----------
    path : str or os.PathLike
        The photo.
    given : dict, optional
        Dates from the command line, keyed by the path as given (relative to the working folder or
        absolute) or by the file name (``datetime.date`` values); they win over the file's own.

    Returns
    -------
    date : datetime.date
    source : {"exif", "tiff", "filename", "option"}

    Raises
    ------
    CliffTerrainError
        When no date is found, naming the file.

    Examples
    --------
    >>> photo_date("flights/20180815_field.tif")  # no such file: the name still has a date
    (datetime.date(2018, 8, 15), 'filename')
    """
    path = Path(path)
    key = given_key(path, given)
    if key is not None:
        return given[key], "option"
    exif, tiff = _header_dates(path)
    if exif is not None:
        return exif, "exif"
    named = date_in_name(path.name)
    if named is not None:
        return named, "filename"
    if tiff is not None:
        return tiff, "tiff"
    raise CliffTerrainError(
        f"no date for {str(path)!r}: it has no EXIF DateTimeOriginal or TIFF DateTime, its name holds "
        f"no YYYYMMDD or YYYY-MM-DD; give one with --dates {path}=YYYY-MM-DD"
    )


def given_key(path, given):
    """The key of `given` (``--dates``) that names `path`: the same file by its path (relative or
    absolute), else its name; None when none does."""
    if not given:
        return None
    target = os.path.normcase(os.path.abspath(path))
    for key in given:
        if os.path.normcase(os.path.abspath(key)) == target:
            return key
        # The same file however it is reached (a symbolic link, macOS's /tmp, another case).
        with contextlib.suppress(OSError):
            if os.path.samefile(key, path):
                return key
    return Path(path).name if Path(path).name in given else None


def check_given_dates(given, images):
    """Refuse ``--dates`` keys that name no input, and file names that name several (ODM names every
    flight's mosaic odm_orthophoto.tif): one line each, with what to give instead."""
    used = {}
    for image in images:
        key = given_key(image, given)
        if key is not None:
            used.setdefault(key, []).append(str(image))
    for key in given or ():
        if key not in used:
            raise CliffTerrainError(
                f"--dates {key}=...: no input photo is {key!r} (give its path or its file name)"
            )
        if len(used[key]) > 1:
            raise CliffTerrainError(
                f"--dates {key}=... names {len(used[key])} photos ({', '.join(used[key][:3])}"
                f"{', ...' if len(used[key]) > 3 else ''}); give each one's path instead"
            )


def date_in_name(name):
    """The first valid ``YYYYMMDD`` or ``YYYY-MM-DD`` date in a file name, or None."""
    for match in _NAME_DATE.finditer(name):
        try:
            return dt.date(int(match[1]), int(match[3]), int(match[4]))
        except ValueError:
            continue  # eight digits that are no date (a serial number, say)
    return None


def parse_given_dates(items):
    """``["NAME=YYYY-MM-DD", ...]`` (from ``--dates``) to ``{NAME: date}``, with one-line errors."""
    given = {}
    for item in items or ():
        name, sep, text = item.rpartition("=")
        if not sep or not name:
            raise CliffTerrainError(f"`--dates` items must be NAME=YYYY-MM-DD, got {item!r}")
        try:
            given[name] = dt.date.fromisoformat(text.strip())
        except ValueError:
            raise CliffTerrainError(f"`--dates` {name!r}: {text!r} is not a date YYYY-MM-DD") from None
    return given


def _header_dates(path):
    """(EXIF DateTimeOriginal, TIFF DateTime) of the file as dates, each None when absent or unreadable."""
    from PIL import Image

    try:
        with Image.open(path) as im:
            exif = im.getexif()
            original = exif.get_ifd(_EXIF_IFD).get(_DATETIME_ORIGINAL)
            stamp = exif.get(_DATETIME)
    except Exception:  # no file or not an image: the reader reports it later with its own message
        return None, None
    return _exif_date(original), _exif_date(stamp)


def _exif_date(value):
    """``"YYYY:MM:DD HH:MM:SS"`` (EXIF and TIFF both write this) to a date; None if it is not one."""
    if isinstance(value, bytes):
        value = value.decode("ascii", "replace")
    if not isinstance(value, str):
        return None
    match = re.match(r"\s*(\d{4})[:\-](\d{2})[:\-](\d{2})", value)
    if match is None:
        return None
    try:
        return dt.date(int(match[1]), int(match[2]), int(match[3]))
    except ValueError:
        return None  # "0000:00:00 00:00:00" is how cameras write an unset clock
