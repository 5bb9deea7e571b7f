"""A breeder's field book read as a ruler: measured plot heights from a CSV, matched to the plots.

:func:`read_ruler` finds the plot id column and the height column, the unit, and refuses what it
cannot read in one line naming the file (:mod:`cliff_terrain.measure.ruler` compares and calibrates).
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import RulerError

# The inch is exact (0.0254 m since 1959): field books of North American trials often keep heights in it.
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254}
_UNIT_NAMES = {"inch": "in", "inches": "in"}
_UNIT_IN_NAME = re.compile(r"(?:^|[_\s(\[])(m|cm|mm|in|inch|inches)[)\]]?$", re.IGNORECASE)
_UNIT_COLUMNS = ("unit", "units")
# Field books abbreviate the trait: HT, PH, PHT, PLHT, PLTHT (plant height, as in the Crop
# Ontology's trait names and breeding databases' exports), alone or beside a unit or a date.
_HEIGHT_WORDS = {"ht", "ph", "pht", "plht", "pltht", "planthgt", "hgt"}


@dataclass
class Ruler:
    """Measured heights matched to a plot set.

    Attributes
    ----------
    heights_m : (n_plots,) float64
        The measured height of each plot in metres, NaN where the file has none.
    id_column, height_column : str
        The file's columns used.
    plot_field : str
        The plot attribute the ids matched (``"plot"``: the 0-based index in the plot file).
    unit : str
        ``"m"``, ``"cm"`` or ``"mm"``: the file's unit.
    unmatched : int
        Rows of the file whose id names no plot.
    path : str
    """

    heights_m: np.ndarray
    id_column: str
    height_column: str
    plot_field: str
    unit: str
    unmatched: int
    path: str

    @property
    def matched(self):
        return int(np.count_nonzero(np.isfinite(self.heights_m)))


def _key(value):
    """An id as text: '12', '12.0' and 12 are the same plot; case and outer spaces do not matter."""
    text = str(value).strip()
    try:
        number = float(text)
    except ValueError:
        return text.lower()
    return str(int(number)) if number.is_integer() else repr(number)


def read_ruler(path, plots, *, id_column=None, height_column=None, units=None):
    """Read a CSV of measured plot heights and match it to `plots`.

    Parameters
    ----------
    path : path
        A CSV file with a header: a plot id column and a height column.
    plots : PlotSet
        The plots (:func:`cliff_terrain.io.vector.plot_polygons.read_plots`); an id matches one of their
        attributes (the one that matches most rows) or ``plot``, the 0-based index.
    id_column, height_column : str, optional
        The file's columns; default: the column whose values match the plots best (when they name
        as many plots through two plot fields, the field named as the column, else a
        :class:`RulerError`), and the one column named like a height: its name holds "height", or
        it is a field book's abbreviation (``HT``, ``PH``, ``PHT``, ``PLHT``, ``PLTHT``, ``HGT``)
        with at most a unit and a date beside it.
    units : {"m", "cm", "mm", "in"}, optional
        The heights' unit; default: from a ``unit``/``units`` column, else from the height column's
        name (``height_cm``, ``Height (m)``, ``PH_in``; ``inch`` and ``inches`` are ``in``). One of
        them must say it.

    Returns
    -------
    Ruler

    Raises
    ------
    RulerError
        The file is missing, not a text CSV, has no such column, mixes units, has heights that are
        not numbers, or names none of the plots; the message names the file.

    Examples
    --------
    >>> import tempfile, os
    >>> from cliff_terrain.io.vector.plot_polygons import PlotSet
    >>> square = [np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]])]
    >>> plots = PlotSet([square] * 3, [{"id": "A1"}, {"id": "A2"}, {"id": "A3"}], ("id",), None, "")
    >>> folder = tempfile.mkdtemp(); path = os.path.join(folder, "ruler.csv")
    >>> _ = open(path, "w").write("plot_id,height_cm\\nA1,71\\nA3,80\\n")
    >>> ruler = read_ruler(path, plots)
    >>> ruler.heights_m.tolist(), ruler.plot_field, ruler.unit
    ([0.71, nan, 0.8], 'id', 'cm')
    """
    from .._validate import check_choice

    name = str(path)
    path = Path(path)
    if units is not None:
        check_choice("--ruler-units", units, tuple(UNITS))
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise RulerError(f"cannot read the ruler file {name!r}: {exc.strerror or exc}") from None
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):  # UTF-16 with its BOM: Excel's "Unicode Text"
        try:
            text = raw.decode("utf-16")
        except UnicodeDecodeError:
            raise RulerError(f"the ruler file {name!r} is not a text CSV (broken UTF-16)") from None
    elif b"\x00" in raw[:4096]:
        raise RulerError(f"the ruler file {name!r} is not a text CSV (it holds binary data)")
    else:
        try:
            text = raw.decode("utf-8-sig")
        except UnicodeDecodeError:
            text = raw.decode("latin-1")
    rows = list(csv.DictReader(text.splitlines()))
    columns = [c for c in (rows[0].keys() if rows else ()) if c is not None]
    if not rows or not columns:
        raise RulerError(f"the ruler file {name!r} has no rows under a header")
    if len(columns) == 1 and any(c in columns[0] for c in ";\t|"):
        raise RulerError(
            f"the ruler file {name!r}: its header is one column, {columns[0]!r}: save it comma-separated"
        )
    height_column = _height_column(name, columns, height_column)
    # The 0-based index as `plot`, unless an attribute is named so (then it stands for it).
    fields = {field: [_key(a.get(field, "")) for a in plots.attributes] for field in plots.fields}
    fields.setdefault("plot", [str(i) for i in range(len(plots))])
    id_column, plot_field, index = _id_column(
        name, rows, columns, id_column, fields, height_column, plots_fields=plots.fields
    )
    unit = _unit(name, rows, columns, height_column, units)
    heights = np.full(len(plots), np.nan)
    unmatched = 0
    seen = {}
    for number_row, row in enumerate(rows, start=2):
        key = _key(row.get(id_column, ""))
        value = (row.get(height_column) or "").strip()
        if key not in index:
            unmatched += 1
            continue
        if key in seen:
            raise RulerError(
                f"the ruler file {name!r}: plot {row.get(id_column)!r} appears twice (rows {seen[key]} and "
                f"{number_row}); give one height per plot"
            )
        seen[key] = number_row
        if not value or value.lower() in ("na", "nan"):
            continue
        try:
            number = float(value)
        except ValueError:
            raise RulerError(
                f"the ruler file {name!r}: height {value!r} of plot {row.get(id_column)!r} "
                f"(column {height_column!r}) is not a number"
            ) from None
        # A height below 0 or infinite is a sign or a unit gone wrong: a calibration on it would
        # turn every plot's height upside down.
        if not np.isfinite(number) or number < 0:
            raise RulerError(
                f"the ruler file {name!r}: height {value!r} of plot {row.get(id_column)!r} "
                f"(column {height_column!r}, row {number_row}) is not a height (below 0 or infinite)"
            )
        heights[index[key]] = number * UNITS[unit]
    if not np.isfinite(heights).any():
        raise RulerError(f"the ruler file {name!r} gives no height for any of the plots it names")
    return Ruler(heights, id_column, height_column, plot_field, unit, unmatched, name)


def _height_column(name, columns, wanted):
    if wanted is not None:
        if wanted not in columns:
            raise RulerError(
                f"the ruler file {name!r} has no column {wanted!r} (it has {', '.join(columns)})"
            )
        return wanted
    found = [c for c in columns if _names_a_height(c)]
    if len(found) != 1:
        why = "no column named like a height" if not found else f"several height columns ({', '.join(found)})"
        raise RulerError(
            f"the ruler file {name!r} has {why}; name it with --ruler-height (columns: {', '.join(columns)})"
        )
    return found[0]


def _names_a_height(column):
    """Whether a column's name names a height: holds "height", or is a field book's abbreviation of
    it with at most a unit and a date beside it (``HT``, ``PH_cm``, ``PLTHT (in)``, ``PH 2023-07-26``).
    Not a name that merely holds its letters (``WEIGHT``, ``phase``) nor one that says more of it
    (``soil_pH``, ``HT_notes``, ``PH_date``, ``PHT_flag``)."""
    text = column.strip().lower()
    if "height" in text:
        return True
    words = [w for w in re.split(r"[^a-z]+", text) if w and w not in (*UNITS, *_UNIT_NAMES)]
    return len(words) == 1 and words[0] in _HEIGHT_WORDS


def _id_column(name, rows, columns, wanted, fields, height_column, plots_fields=()):
    index_is_row = "plot" not in plots_fields
    candidates = [wanted] if wanted is not None else [c for c in columns if c != height_column]
    if wanted is not None and wanted not in columns:
        raise RulerError(f"the ruler file {name!r} has no column {wanted!r} (it has {', '.join(columns)})")
    best = (0, None, None)
    shared = (0, None, None)  # the best match with an attribute that names several plots each
    tied = []  # the fields that name as many of the best column's ids as the best
    for column in candidates:
        keys = [_key(r.get(column, "")) for r in rows]
        for field, values in fields.items():
            hits = sum(k in set(values) for k in keys)
            if len(set(values)) < len(values):  # an attribute that does not name each plot once is no id
                if hits > shared[0]:
                    shared = (hits, column, field)
                continue
            if hits > best[0]:
                best, tied = (hits, column, field), [field]
            elif hits == best[0] and hits and column == best[1]:
                tied.append(field)
    if len(tied) > 1:
        # The ids name as many plots through two fields (a 0-based index and a 1-based number): one of
        # them joins every height to a neighbour. The field named as the column is meant; else ask.
        # (`plot`, the 0-based row, only by that exact name: the column plots.csv writes; a field
        # book's "Plot" is the breeder's number.)
        column = best[1].strip()
        named = [
            f
            for f in tied
            if (column == "plot" if f == "plot" and index_is_row else f.strip().lower() == column.lower())
        ]
        if len(named) != 1:
            raise RulerError(
                f"the ruler file {name!r}: the ids of its column {best[1]!r} name as many plots through "
                f"the plots' {' and '.join(repr(f) for f in tied)} ('plot' is the 0-based row); name "
                "the column as the one meant"
            )
        best = (best[0], best[1], named[0])
    if shared[0] and shared[0] >= best[0] and (best[0] == 0 or best[2] == "plot"):
        # The ids name plots through an attribute several plots share (a plot number repeated in
        # each trial); the 0-based index matching them instead would join every height to another
        # plot.
        raise RulerError(
            f"the ruler file {name!r}: its column {shared[1]!r} matches the plots' {shared[2]!r}, which "
            "names several plots each; give ids that name one plot each (or --ruler-id naming such a column)"
        )
    if best[0] == 0:
        raise RulerError(
            f"the ruler file {name!r}: none of its ids names a plot of the plot file "
            f"(tried columns {', '.join(candidates) or 'none'} against the plots' {', '.join(fields)})"
        )
    _, column, field = best
    return column, field, {v: i for i, v in enumerate(fields[field])}


def _unit(name, rows, columns, height_column, units):
    unit_column = next((c for c in columns if c.strip().lower() in _UNIT_COLUMNS), None)
    if unit_column is not None:
        seen = {_unit_name((r.get(unit_column) or "").strip().lower()) for r in rows} - {""}
        if len(seen) > 1:
            raise RulerError(
                f"the ruler file {name!r} mixes units in column {unit_column!r} ({', '.join(sorted(seen))}); "
                "give every height in one unit"
            )
        if seen:
            (found,) = seen
            if found not in UNITS:
                raise RulerError(f"the ruler file {name!r}: unit {found!r} is not one of m, cm, mm, in")
            if units is not None and units != found:
                raise RulerError(f"the ruler file {name!r} says {found!r} but --ruler-units says {units!r}")
            return found
    match = _UNIT_IN_NAME.search(height_column.strip())
    if match:
        found = _unit_name(match.group(1).lower())
        if units is not None and units != found:
            raise RulerError(
                f"the ruler file {name!r}: column {height_column!r} says {found!r} but --ruler-units says {units!r}"
            )
        return found
    if units is None:
        raise RulerError(
            f"the ruler file {name!r} does not say the unit of {height_column!r}; "
            "give --ruler-units m, cm, mm or in (or a 'unit' column)"
        )
    return units


def _unit_name(text):
    """A unit as :data:`UNITS` names it: ``inch`` and ``inches`` are ``in``."""
    return _UNIT_NAMES.get(text, text)
