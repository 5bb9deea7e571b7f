"""`ReliefParams`: every setting of :func:`cliff_terrain.build.build_relief`, declared and checked once.

The one mapping between the settings and their other spellings lives here: the command-line
options (:meth:`ReliefParams.add_arguments`, :meth:`ReliefParams.from_args`), and the Blender
sidebar's properties and a relief's recorded settings (:meth:`ReliefParams.to_properties`,
:meth:`ReliefParams.from_properties`), which hold no None: 0 (or an empty path) stands for it.
Outside Python (options, properties, records) the height source is called ``heights``.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping
from dataclasses import dataclass

from . import settings
from ._validate import check_choice, check_float, check_int
from .errors import CliffTerrainError

# Optional settings whose "not given" is None in Python and 0 (or "") in ID properties.
_OPTIONAL_NUMBERS = ("max_height", "gsd", "max_error")
_PATHS = ("dsm", "dtm")
# The sidebar's properties, named as the settings except the height source.
PROPERTY_NAMES = {
    "segmentation": "segmentation",
    "profile": "profile",
    "max_size": "max_size",
    "exaggeration": "exaggeration",
    "max_height": "max_height",
    "gsd": "gsd",
    "two_sided": "two_sided",
    "mesh": "mesh",
    "max_error": "max_error",
    "dsm": "dsm",
    "dtm": "dtm",
    "height_source": "heights",
}


@dataclass(frozen=True)
class ReliefParams:
    """The settings of one relief build; checked when made (a :class:`CliffTerrainError` names the
    setting and the value). See :func:`cliff_terrain.build.build_relief` for their meaning.

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
    height_source: str = settings.DEFAULT_HEIGHT_MODE
    ground_block: float | None = None
    ground_method: str | None = None  # the ground estimate (measure.ground.GROUND_METHODS); None: "auto"
    bands: tuple | None = None  # a multispectral photo's band names, when its file gives none

    def __post_init__(self):
        checked = {
            "max_size": check_int(
                "max_size", self.max_size, minimum=settings.MIN_SIZE, maximum=settings.MAX_SIZE
            ),
            "segmentation": check_choice(
                "segmentation", self.segmentation, settings.ids(settings.SEGMENTATIONS)
            ),
            "profile": check_choice("profile", self.profile, settings.ids(settings.PROFILES)),
            "exaggeration": check_float(
                "exaggeration", self.exaggeration, minimum=settings.MIN_EXAGGERATION, strict_minimum=True
            ),
            "height_source": check_choice(
                "height_source", self.height_source, settings.ids(settings.HEIGHT_MODES)
            ),
        }
        for name in (*_OPTIONAL_NUMBERS, "ground_block"):
            value = getattr(self, name)
            checked[name] = check_float(name, value, minimum=0.0, strict_minimum=True, allow_none=True)
        if not isinstance(self.two_sided, bool) and type(self.two_sided).__name__ != "bool_":
            raise CliffTerrainError(f"`two_sided` must be True or False, got {self.two_sided!r}")
        checked["two_sided"] = bool(self.two_sided)
        if self.ground_method is not None:
            from .measure.ground import GROUND_METHODS

            checked["ground_method"] = check_choice("ground_method", self.ground_method, GROUND_METHODS)
        if self.mesh is not None:
            check_choice("mesh", self.mesh, settings.ids(settings.MESHES))
        for name in _PATHS:
            value = getattr(self, name)
            if value is not None and not isinstance(value, str | os.PathLike):
                raise CliffTerrainError(f"`{name}` must be a file path or None, got {value!r}")
            checked[name] = None if value is None else os.fspath(value)
        if self.dsm is None and self.dtm is not None:
            raise CliffTerrainError(f"`dtm` needs a `dsm`, got dtm={checked['dtm']!r} and dsm=None")
        if self.dsm is None and checked["height_source"] != "inflated":
            raise CliffTerrainError(
                f"`height_source` {checked['height_source']!r} needs a `dsm` (a surface model GeoTIFF), got None"
            )
        if self.bands is not None:
            from .io.bands import parse_band_names

            checked["bands"] = parse_band_names(self.bands)
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
        record = {PROPERTY_NAMES.get(name, name): value for name, value in self.as_kwargs().items()}
        if self.ground_block is None:
            del record["ground_block"]  # only with a surface model and no terrain model
        if self.ground_method is None:
            del record["ground_method"]
        return record

    # ---- Blender's ID properties (the sidebar, the operators, a relief's record) ----

    def to_properties(self):
        """The sidebar's properties (ID properties hold no None: 0 stands for "not given")."""
        values = self.as_kwargs()
        return {prop: 0.0 if values[name] is None else values[name] for name, prop in PROPERTY_NAMES.items()}

    @classmethod
    def from_properties(cls, props, *, path=os.fspath):
        """The settings of the sidebar's properties, an operator's, or a relief's recorded ``params``.

        `props` is an object with the properties as attributes, or a mapping (missing keys take the
        defaults). 0 (or an empty path) means "not given"; `path` turns a given path into a file
        path (the operators pass ``bpy.path.abspath`` for Blender's relative ``//`` paths).
        """
        if isinstance(props, Mapping):
            values = {name: props[prop] for name, prop in PROPERTY_NAMES.items() if prop in props}
        else:
            values = {name: getattr(props, prop) for name, prop in PROPERTY_NAMES.items()}
        for name in _OPTIONAL_NUMBERS:
            if name in values and not values[name]:
                values[name] = None
        for name in _PATHS:
            value = values.get(name)
            values[name] = path(value) if isinstance(value, str) and value else None
        return cls(**values)

    # ---- The command line ----

    @staticmethod
    def add_arguments(parser, *, number=None):
        """Add the settings' options to an argparse `parser` (or group); :meth:`from_args` reads them.

        `number(kind, option, **limits)` makes the argparse type of a numeric option, which may
        check it at once (``render_views.py`` does); by default `kind` itself, and the settings
        are checked when :meth:`from_args` makes them.
        """

        def typed(kind, option, **limits):
            return kind if number is None else number(kind, option, **limits)

        positive = {"minimum": 0.0, "strict_minimum": True}
        parser.add_argument(
            "--max-size",
            type=typed(int, "--max-size", minimum=settings.MIN_SIZE, maximum=settings.MAX_SIZE),
            default=settings.DEFAULT_MAX_SIZE,
            help=f"longest side of the processing grid in pixels, {settings.MIN_SIZE} to "
            f"{settings.MAX_SIZE} (default {settings.DEFAULT_MAX_SIZE})",
        )
        parser.add_argument(
            "--segmentation",
            choices=settings.ids(settings.SEGMENTATIONS),
            default=settings.DEFAULT_SEGMENTATION,
        )
        parser.add_argument(
            "--profile", choices=settings.ids(settings.PROFILES), default=settings.DEFAULT_PROFILE
        )
        parser.add_argument(
            "--exaggeration",
            type=typed(float, "--exaggeration", minimum=settings.MIN_EXAGGERATION, strict_minimum=True),
            default=settings.DEFAULT_EXAGGERATION,
            help="height factor",
        )
        parser.add_argument(
            "--max-height",
            type=typed(float, "--max-height", **positive),
            default=settings.DEFAULT_MAX_HEIGHT,
            help="canopy height: where the plateau profile levels off (a cap for the others); metres with "
            "a GSD, else processing pixels (default: the radius of a typical isolated plant)",
        )
        parser.add_argument(
            "--gsd",
            type=typed(float, "--gsd", **positive),
            help="ground sampling distance of the photo in m/px (default: from its metadata, if any)",
        )
        parser.add_argument(
            "--one-sided", action="store_true", help="the relief surface only (no walls and base)"
        )
        parser.add_argument(
            "--mesh",
            choices=settings.ids(settings.MESHES),
            default=settings.DEFAULT_MESH,
            help="grid: a vertex per pixel corner; adaptive: a TIN within --max-error; auto: adaptive "
            "wherever it builds at least as fast (processing grids of 1.5 MP and more), else the grid, and "
            f"says which (default {settings.DEFAULT_MESH})",
        )
        parser.add_argument(
            "--max-error",
            type=typed(float, "--max-error", **positive),
            help="adaptive mesh: largest vertical error, in metres with a GSD, else in processing pixels "
            "(default: half a pixel for heights from the photo; the DSM's noise, at least 1 cm, for "
            "measured heights)",
        )
        parser.add_argument(
            "--dsm", metavar="DSM", help="surface model GeoTIFF of the orthophoto: measured heights"
        )
        parser.add_argument(
            "--dtm", metavar="DTM", help="terrain model GeoTIFF (default: ground estimated from the DSM)"
        )
        parser.add_argument(
            "--heights",
            choices=settings.ids(settings.HEIGHT_MODES),
            help="where heights come from (default: measured with --dsm, else inflated)",
        )
        parser.add_argument(
            "--bands",
            metavar="NAMES",
            help="a multispectral image's band names when its file does not name them, e.g. B,G,R,RE,NIR",
        )

    @classmethod
    def from_args(cls, args, **changes):
        """The settings of options parsed from :meth:`add_arguments` (then `changes`)."""
        values = {
            "max_size": args.max_size,
            "segmentation": args.segmentation,
            "profile": args.profile,
            "exaggeration": args.exaggeration,
            "max_height": args.max_height,
            "gsd": args.gsd,
            "two_sided": not args.one_sided,
            "mesh": args.mesh,
            "max_error": args.max_error,
            "dsm": args.dsm,
            "dtm": args.dtm,
            "height_source": args.heights or ("measured" if args.dsm else settings.DEFAULT_HEIGHT_MODE),
            "bands": args.bands,
        }
        return cls(**{**values, **changes})
