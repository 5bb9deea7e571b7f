"""A relief object's record: what a build writes into its ``cliff_terrain`` custom property, and how
everything else reads it back.

The record is an ID property (it travels with the object into the .blend and stays readable by
scripts as ``obj["cliff_terrain"]["grid_rows"]``). It is written in one place,
:func:`write_record`, and read in one place, :meth:`Record.of`: a typed, frozen :class:`Record`
whose field defaults are what a record written by an earlier version lacks (``mask_digest``,
``mesh_rule``, the key figures...) or what a build without a surface model leaves out
(``map_offset``, ``crs``, ``ground``). So a default is written once, here, and every reader of the
panel, the operators and ``scene/`` gets the same one.
"""

from __future__ import annotations

import contextlib
import dataclasses
from dataclasses import dataclass, field

KEY = "cliff_terrain"  # the object's custom property


@dataclass(frozen=True)
class Record:
    """What a relief object records about its build.

    Sizes are in the relief's `units` (``"m"`` with a ground sampling distance, else processing
    pixels, ``"px"``); one of them is `blender_units_per_unit` Blender units.
    """

    # The photo the relief was built from, and its processing grid.
    source: str
    pixel_size: float
    grid_rows: int
    grid_cols: int
    version: str = ""
    units: str = "px"
    # Blender units per core unit: 1 for metres; "normalised units" make the longest side 10.
    blender_units_per_unit: float = 1.0
    size_mode: str = "normalised"
    regions: int = 0
    # The photo's ground sampling distance (0 when unknown) and where it came from ("" when unknown).
    gsd_m_per_px: float = 0.0
    gsd_source: str = ""
    # The adaptive mesh's bound (0 for the grid) and which rule chose it ("given", half a pixel, the
    # DSM's noise; "" for the grid); the mesh made and why ("given", or what "auto" chose).
    max_error: float = 0.0
    max_error_rule: str = ""
    mesh: str = ""
    mesh_rule: str = ""
    # Front faces (triangles, or grid quads); None in records from before adaptive meshes.
    front_faces: int | None = None
    max_height: float = 0.0
    # Tells a rebuild of the relief from its photo from another photo ("": an earlier version's record).
    mask_digest: str = ""
    # A multispectral photo's bands (as named by its file or by the build) and the vegetation
    # indices they allow (Color By offers them).
    bands: tuple = ()
    indices: tuple = ()
    image_width: int = 0
    image_height: int = 0
    # The settings as the sidebar holds them (0 for "not given"), which a rebuild reads back.
    params: dict = field(default_factory=dict)
    # The key figures (cliff_terrain.measure.key_figures): cover (None before they were recorded),
    # canopy height p50/p90 in cm (-1 without a surface model).
    cover: float | None = None
    canopy_p50_cm: float = -1.0
    canopy_p90_cm: float = -1.0
    # With a surface model: the map (x, y) of the mesh's local (0, 0) in EPSG `crs`, and the ground's source.
    map_offset: tuple | None = None
    crs: int | str | None = None  # an EPSG code, or a user-defined CRS's WKT
    ground: str | None = None
    # Why the estimated ground took its soil from the surface, not from the photo's colour ("": it
    # took the colour's, or no ground was estimated).
    soil_note: str = ""
    # When the surface model does not see the soil between the plots (the ground's occlusion check
    # failed): that, in one line ("": it passed, or no ground was estimated).
    ground_note: str = ""

    __hash__ = None  # `params` is a dict

    @classmethod
    def of(cls, obj):
        """The record of relief object `obj`, or None when `obj` is None or no relief."""
        if obj is None or KEY not in obj:
            return None
        return cls.from_properties(obj[KEY])

    @classmethod
    def from_properties(cls, data):
        """A record from its ID property (or the plain dict of one); keys it does not know are left out."""
        if hasattr(data, "to_dict"):
            data = data.to_dict()
        names = {f.name for f in dataclasses.fields(cls)}
        values = {k: v for k, v in data.items() if k in names}
        for name in ("bands", "indices", "map_offset"):
            if values.get(name) is not None:
                values[name] = tuple(values[name])
        return cls(**values)

    def as_properties(self):
        """The record as an ID property's value: lists for tuples, no key for None."""
        return {
            k: list(v) if isinstance(v, tuple) else v
            for k, v in dataclasses.asdict(self).items()
            if v is not None
        }

    @property
    def source_file(self):
        """`source` as a file: a path relative to the .blend (``//photos/a.tif``, kept as the user
        gave it, so a moved project folder still finds its photo) resolved against the open file."""
        return _file(self.source)

    def file_params(self):
        """`params` with their paths (a surface or terrain model) resolved as :attr:`source_file`."""
        return {
            k: _file(v) if isinstance(v, str) and v.startswith("//") else v for k, v in self.params.items()
        }

    def frame_error(self, obj):
        """Why `obj`'s mesh no longer lies in the frame it was built in, or "" when it does.

        The relief's rasters are read through the mesh's local coordinates: x from 0 to the grid's
        width, y from 0 to its height, in :attr:`blender_pixel` steps. Applying a scale or rotation
        (Object > Apply) moves the vertices themselves, and the probe then read the wrong pixel
        ("outside the relief" on the relief) and Color By Height the wrong height.
        """
        size = self.blender_pixel
        rows, cols = self.grid_shape
        xs = [corner[0] for corner in obj.bound_box]
        ys = [corner[1] for corner in obj.bound_box]
        tolerance = 0.5 * size
        if (
            max(abs(min(xs)), abs(max(xs) - cols * size), abs(min(ys)), abs(max(ys) - rows * size))
            <= tolerance
        ):
            return ""
        return (
            f"the relief {obj.name!r} no longer lies in the frame it was built in (a transform applied "
            "with Object > Apply, or its mesh edited): undo that, or build it again"
        )

    @property
    def metres(self):
        """True when sizes are in metres (a known ground sampling distance)."""
        return self.units == "m"

    @property
    def grid_shape(self):
        """(rows, cols) of the processing grid."""
        return int(self.grid_rows), int(self.grid_cols)

    @property
    def blender_pixel(self):
        """Size of one processing pixel in Blender units."""
        return float(self.pixel_size) * float(self.blender_units_per_unit)


def is_relief(obj):
    """True for a mesh object that a build made (it has a record)."""
    return obj is not None and obj.type == "MESH" and KEY in obj


def write_record(obj, relief, path, params, scale, *, figures=None):
    """Record on `obj` what its build was: `relief` (the core's) of photo `path` with `params`
    (:class:`~cliff_terrain.params.ReliefParams`, or its recorded properties), `scale` Blender units
    per core unit. `figures`: :func:`record_figures` of the relief, if already worked out."""
    obj[KEY] = build_record(relief, path, params, scale, figures=figures).as_properties()


def _file(path):
    """A stored path as a file: blend-relative ``//`` paths resolved against the open .blend."""
    if isinstance(path, str) and path.startswith("//"):
        import bpy

        return bpy.path.abspath(path)
    return path


@contextlib.contextmanager
def absolute_paths():
    """Every relief's recorded ``//`` paths made absolute for the duration (then put back).

    A copy of the file saved elsewhere (the render job's, in a temporary folder) gets its images'
    relative paths remapped by Blender, not the paths in the records: resolved there, they pointed
    into the temporary folder, and the job failed "the photo ... is not there".
    """
    import bpy

    kept = []
    for obj in bpy.data.objects:
        if KEY not in obj:
            continue
        record = obj[KEY]
        params = record.get("params", {})
        for owner, name in [(record, "source"), *((params, k) for k in params.keys())]:
            value = owner.get(name)
            if isinstance(value, str) and value.startswith("//"):
                kept.append((owner, name, value))
                owner[name] = _file(value)
    try:
        yield
    finally:
        for owner, name, value in kept:
            owner[name] = value


def build_record(relief, path, params, scale, *, figures=None):
    """The :class:`Record` of a build (see :func:`write_record`)."""
    from ..cliff_terrain import __version__
    from ..cliff_terrain.params import ReliefParams
    from ..cliff_terrain.photo_heights.indices import available_indices

    digest, figures = record_figures(relief) if figures is None else figures
    if not isinstance(params, ReliefParams):  # render_views.py passes a relief's recorded ``params``
        params = ReliefParams.from_properties(params)
    bands = tuple(relief.metadata.band_names or ())
    return Record(
        version=__version__,
        source=str(path),
        units=relief.units,
        blender_units_per_unit=scale,
        size_mode="metres" if relief.units == "m" else "normalised",
        pixel_size=float(relief.pixel_size),
        grid_rows=int(relief.mesh.grid_shape[0]),
        grid_cols=int(relief.mesh.grid_shape[1]),
        regions=int(relief.n_regions),
        gsd_m_per_px=float(relief.metadata.gsd_m_per_px or 0.0),
        gsd_source=relief.metadata.gsd_source or "",
        max_error=float(relief.max_error or 0.0),
        max_error_rule=relief.max_error_rule or "",
        mesh=relief.mesh_kind or "",
        mesh_rule=relief.mesh_rule,
        front_faces=int(relief.mesh.n_front_faces),
        max_height=relief.max_height,
        mask_digest=digest,
        bands=bands,
        indices=tuple(available_indices(bands)),
        image_width=int(relief.metadata.width),
        image_height=int(relief.metadata.height),
        params=params.to_properties(),
        **figures,
    )


def record_figures(relief):
    """``(mask_digest, key_figures)`` of a relief, for its record: they need no mesh (the Build
    Relief operator works them out in a thread beside an adaptive mesh)."""
    return relief.mask_digest, key_figures(relief)


def key_figures(relief):
    """Cover and, with a surface model, the canopy height p50/p90 (cm, -1 without) and the map offset.

    The mesh is built near the world origin; ``map_offset`` is the map (x, y) of its local (0, 0)
    (the grid's bottom-left corner) in EPSG ``crs``: add it to a vertex to get map coordinates.
    """
    from ..cliff_terrain.measure.key_figures import key_figures as core_figures

    # One definition of the figures (the core's), shown in the sidebar in centimetres.
    core = core_figures(relief)
    figures = {"cover": core["cover"], "canopy_p50_cm": -1.0, "canopy_p90_cm": -1.0}
    canopy = getattr(relief, "canopy", None)
    if canopy is not None:
        if core["canopy_height_p90_m"] is not None:
            figures.update(
                canopy_p50_cm=core["canopy_height_p50_m"] * 100.0,
                canopy_p90_cm=core["canopy_height_p90_m"] * 100.0,
            )
        rows = relief.heights.shape[0]  # the mesh's grid
        t = canopy.transform
        figures["map_offset"] = (float(t[0, 1] * rows + t[0, 2]), float(t[1, 1] * rows + t[1, 2]))
        from ..cliff_terrain.io.raster.crs import crs_record

        figures["crs"] = crs_record(canopy.crs)  # an EPSG code, or a user-defined CRS's WKT
        figures["ground"] = canopy.ground_source
        evidence = (canopy.check or {}).get("evidence") or {}
        figures["soil_note"] = evidence.get("colour_contradicted") or ""
        from ..cliff_terrain.measure.ground_occlusion import occlusion_line

        figures["ground_note"] = occlusion_line((canopy.check or {}).get("occlusion"))
    return figures
