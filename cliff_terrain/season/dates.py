"""The date of each photo of a season, and where it came from.

In this order: EXIF ``DateTimeOriginal``, the TIFF ``DateTime`` tag, a ``YYYYMMDD`` or ``YYYY-MM-DD``
in the file name, then the date given on the command line (``--dates NAME=YYYY-MM-DD``). Only the
file's header is read. Needs Pillow only.
"""

from __future__ import annotations

import datetime as dt
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
        Dates from the command line, keyed by file name or path (``datetime.date`` values); used
        only when the file itself has no date.

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
    exif, tiff = _header_dates(path)
    if exif is not None:
        return exif, "exif"
    if tiff is not None:
        return tiff, "tiff"
    named = date_in_name(path.name)
    if named is not None:
        return named, "filename"
    for key in (str(path), path.name):
        if given and key in given:
            return given[key], "option"
    raise CliffTerrainError(
        f"no date for {str(path)!r}: it has no EXIF DateTimeOriginal or TIFF DateTime, its name holds "
        f"no YYYYMMDD or YYYY-MM-DD; give one with --dates {path.name}=YYYY-MM-DD"
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
