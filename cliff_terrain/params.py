"""`ReliefParams`: every setting of :func:`cliff_terrain.build.build_relief`, checked once.

Each setting is declared once, in :data:`cliff_terrain.settings.PARAMETERS` (label, help, unit,
default, limits, choices); this module checks the settings against those declarations and speaks
their other languages: the command-line options (:meth:`ReliefParams.add_arguments`,
:func:`add_option`, :meth:`ReliefParams.from_args`), and the Blender sidebar's properties and a
relief's recorded settings (:meth:`ReliefParams.to_properties`, :meth:`ReliefParams.from_properties`),
which hold no None: 0 (or an empty path) stands for it. A setting has one name in all of them.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
from collections.abc import Mapping
from dataclasses import dataclass

from . import settings
from ._validate import check_choice, check_float, check_int
from .errors import CliffTerrainError
from .settings import PARAMETERS

# The sidebar's properties: the settings it shows (operators/properties.py makes them).
SIDEBAR = tuple(name for name, p in PARAMETERS.items() if p.sidebar)
# Old names in relief records written before the height source had one name everywhere.
_RECORDED_AS = {"heights": "height_source"}


@dataclass(frozen=True)
class ReliefParams:
    """The settings of one relief build; checked when made (a :class:`CliffTerrainError` names the
    setting and the value). See :func:`cliff_terrain.build.build_relief` for their meaning, and
    :data:`cliff_terrain.settings.PARAMETERS` for their declarations (help, unit, limits).

    Parameters
    ----------
    max_size : int, optional
        Longest side of the processing grid in pixels (16 to 16384).
    segmentation : {"vegetation", "paper"}, optional
        What rises: plants (``"vegetation"``) or the paper's bright class (``"paper"``).
    profile : {"auto", "circular", "poisson", "plateau"}, optional
        Cross-section of each region.
    exaggeration : float, optional
        Height factor (> 0).
    max_height : float, optional
        Canopy height (metres with a ground sampling distance, else processing pixels).
    gsd : float, optional
        Ground sampling distance of the original photo, metres per pixel.
    two_sided : bool, optional
        Close the relief into a watertight solid.
    mesh : {"auto", "grid", "adaptive"} or None, optional
        The mesh to make; None for heights only.
    max_error : float, optional
        The adaptive mesh's largest vertical error, in the relief's units.
    dsm, dtm : str or os.PathLike, optional
        Surface and terrain model GeoTIFFs of a georeferenced orthophoto.
    height_source : {"inflated", "calibrated", "measured"}, optional
        Where the heights come from; the last two need `dsm`.
    ground_block : float, optional
        Block size in metres of the estimated ground's trend (with a `dsm` and no `dtm`).
    ground_method : {"auto", "baseline", "smooth", "detailed"}, optional
        The estimated ground (with a `dsm` and no `dtm`); None: ``"auto"``.
    bands : str or sequence of str, optional
        A multispectral photo's band names, when its file gives none (e.g. ``"B,G,R,RE,NIR"``).

    Returns
    -------
    ReliefParams
        Frozen; :meth:`replace` makes a checked copy, :meth:`as_kwargs` gives the keywords of
        :func:`cliff_terrain.build.build_relief`.

    Examples
    --------
    >>> params = ReliefParams(max_size=500, gsd=0.01)
    >>> params.as_kwargs()["max_size"], params.profile
    (500, 'auto')
    >>> ReliefParams(max_size=3)
    Traceback (most recent call last):
    ...
    cliff_terrain.errors.CliffTerrainError: `max_size` must be >= 16, got 3
    """

    max_size: int = settings.DEFAULT_MAX_SIZE
    segmentation: str = settings.DEFAULT_SEGMENTATION
    profile: str = settings.DEFAULT_PROFILE
    exaggeration: float = settings.DEFAULT_EXAGGERATION
    max_height: float | None = settings.DEFAULT_MAX_HEIGHT
    gsd: float | None = None
    two_sided: bool = True
    mesh: str | None = settings.DEFAULT_MESH
    max_error: float | None = None
    dsm: str | None = None
    dtm: str | None = None
    height_source: str = settings.DEFAULT_HEIGHT_SOURCE
    ground_block: float | None = None
    ground_method: str | None = None
    bands: tuple | None = None

    def __post_init__(self):
        checked = {name: _check(PARAMETERS[name], getattr(self, name)) for name in PARAMETERS}
        if self.dsm is None and self.dtm is not None:
            raise CliffTerrainError(f"`dtm` needs a `dsm`, got dtm={checked['dtm']!r} and dsm=None")
        if self.dsm is None and checked["height_source"] != "inflated":
            raise CliffTerrainError(
                f"`height_source` {checked['height_source']!r} needs a `dsm` (a surface model GeoTIFF), got None"
            )
        for name, value in checked.items():
            object.__setattr__(self, name, value)

    def replace(self, **changes):
        """A copy with `changes` (checked as a new one is)."""
        return dataclasses.replace(self, **changes)

    def as_kwargs(self):
        """The settings as :func:`cliff_terrain.build.build_relief` keyword arguments."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    def as_record(self):
        """The settings as recorded in files (``relief.json``, ``metrics.json``): plain values, None kept."""
        record = self.as_kwargs()
        if self.ground_block is None:
            del record["ground_block"]  # only with a surface model and no terrain model
        if self.ground_method is None:
            del record["ground_method"]
        return record

    # ---- Blender's ID properties (the sidebar, the operators, a relief's record) ----

    def to_properties(self):
        """The sidebar's properties (ID properties hold no None: 0 stands for "not given")."""
        return {name: 0.0 if getattr(self, name) is None else getattr(self, name) for name in SIDEBAR}

    @classmethod
    def from_properties(cls, props, *, path=os.fspath):
        """The settings of the sidebar's properties, an operator's, or a relief's recorded ``params``.

        `props` is an object with the properties as attributes, or a mapping (missing keys take the
        defaults; a record's old ``heights`` is read as ``height_source``). 0 (or an empty path)
        means "not given"; `path` turns a given path into a file path (the operators pass
        ``bpy.path.abspath`` for Blender's relative ``//`` paths).
        """
        if isinstance(props, Mapping):
            props = {_RECORDED_AS.get(key, key): value for key, value in props.items()}
            values = {name: props[name] for name in SIDEBAR if name in props}
        else:
            values = {name: getattr(props, name) for name in SIDEBAR}
        for name, value in values.items():
            kind = PARAMETERS[name].kind
            if kind == "float" and PARAMETERS[name].default is None and not value:
                values[name] = None
            elif kind == "path":
                values[name] = path(value) if isinstance(value, str) and value else None
        return cls(**values)

    # ---- The command line ----

    @staticmethod
    def add_arguments(parser, *, number=None):
        """Add the relief's options to an argparse `parser` (or group); :meth:`from_args` reads them.

        One option per setting declared with ``relief_option`` (:func:`add_option`). `number(kind,
        option, **limits)` makes the argparse type of a numeric option, which may check it at once
        (``render_views.py`` does); by default `kind` itself, and the settings are checked when
        :meth:`from_args` makes them.
        """
        for name, parameter in PARAMETERS.items():
            if parameter.relief_option:
                add_option(parser, name, number=number)

    @classmethod
    def from_args(cls, args, **changes):
        """The settings of options parsed from :meth:`add_arguments` (then `changes`).

        Without ``--height-source`` the heights are measured with ``--dsm``, else inflated.
        """
        values = {name: getattr(args, name) for name in PARAMETERS if hasattr(args, name)}
        if values.get("height_source") is None:
            values["height_source"] = "measured" if values.get("dsm") else settings.DEFAULT_HEIGHT_SOURCE
        return cls(**{**values, **changes})


def _check(parameter, value):
    """`value` of `parameter` as checked (and converted); a :class:`CliffTerrainError` names both."""
    name, kind = parameter.name, parameter.kind
    if value is None and (parameter.default is None or parameter.allow_none):
        return None
    if kind == "int":
        return check_int(name, value, minimum=parameter.minimum, maximum=parameter.maximum)
    if kind == "float":
        limits = {"minimum": parameter.minimum, "maximum": parameter.maximum}
        return check_float(name, value, strict_minimum=parameter.exclusive_minimum, **limits)
    if kind == "choice":
        return check_choice(name, value, settings.ids(parameter.choices))
    if kind == "bool":
        if not isinstance(value, bool) and type(value).__name__ != "bool_":  # numpy's too
            raise CliffTerrainError(f"`{name}` must be True or False, got {value!r}")
        return bool(value)
    if kind == "path":
        if not isinstance(value, str | os.PathLike):
            raise CliffTerrainError(f"`{name}` must be a file path or None, got {value!r}")
        return os.fspath(value)
    from .io.raster.bands import parse_band_names  # kind "names": only the bands

    return parse_band_names(value)


def add_option(parser, name, *, number=None, **overrides):
    """Add the command-line option of setting `name` (:data:`cliff_terrain.settings.PARAMETERS`).

    The option, its type, choices, default and help come from the declaration; `overrides` are
    argparse keywords that differ for one command (e.g. ``required=True``). `number` is as in
    :meth:`ReliefParams.add_arguments`. The value lands in ``args.<name>``.

    Examples
    --------
    >>> import argparse
    >>> parser = argparse.ArgumentParser()
    >>> add_option(parser, "max_size")
    >>> parser.parse_args(["--max-size", "500"]).max_size
    500
    """
    parameter = PARAMETERS[name]
    kind = parameter.kind
    option = {"dest": name, "help": option_help(parameter, default=not overrides.get("required"))}
    if kind in ("int", "float"):
        convert = int if kind == "int" else float
        limits = {
            key: value
            for key, value in (("minimum", parameter.minimum), ("maximum", parameter.maximum))
            if value is not None
        }
        if parameter.exclusive_minimum:  # floats only
            limits["strict_minimum"] = True
        option.update(type=convert if number is None else number(convert, parameter.flag, **limits))
        option["default"] = parameter.default
    elif kind == "choice":
        option.update(choices=settings.ids(parameter.choices), default=parameter.default)
    elif kind == "bool":  # the option turns a default True off (--one-sided)
        option.update(action="store_false" if parameter.default else "store_true")
    if parameter.metavar:
        option["metavar"] = parameter.metavar
    if name == "height_source":  # without it: measured with --dsm, else inflated (from_args)
        option["default"] = None
    option.update(overrides)
    parser.add_argument(parameter.flag, **option)
    if name == "height_source":
        parser.add_argument(
            "--heights",
            dest=name,
            choices=option["choices"],
            action=_Deprecated,
            help=argparse.SUPPRESS,
        )


def option_help(parameter, *, default=True):
    """The ``--help`` text of `parameter`'s option: its help, choices, unit, limits and `default`."""
    if parameter.kind == "bool":
        return parameter.option_help or parameter.help
    text = parameter.help
    if parameter.choices:
        text += f"; {parameter.choice_help()}"
    details = []
    unit = {"relief": "m with a GSD, else processing px"}.get(parameter.unit, parameter.unit)
    if parameter.limits or unit:
        details.append(" ".join(filter(None, [parameter.limits, unit])))
    if not default:
        pass
    elif parameter.name == "height_source":
        details.append("default: measured with --dsm, else inflated")
    elif parameter.default is not None:
        details.append(f"default {parameter.default}")
    elif parameter.unset:
        details.append(f"default: {parameter.unset}")
    return f"{text}; {', '.join(details)}" if details else text


class _Deprecated(argparse.Action):
    """An old option that still works, with a warning naming the new one (``--heights``)."""

    def __call__(self, parser, namespace, values, option_string=None):
        new = PARAMETERS[self.dest].flag
        print(f"{parser.prog}: warning: {option_string} is deprecated: use {new}", file=sys.stderr)
        setattr(namespace, self.dest, values)
