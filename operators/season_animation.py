"""The Season Animation operator: a ``cliff-terrain season`` folder -> one relief per date, shown in turn.

It reads the season's outputs (never runs Dask), builds the scene with :mod:`scene.season_animation` (reliefs
aligned by georeference, a timeline marker per date, optional plot outlines, a camera) and, with
``render``, renders one PNG per date and a video into ``FOLDER/animation/``. Errors in the season's
files are reported and the operator returns CANCELLED.
"""

import traceback
from pathlib import Path

import bpy

from .file_operator import FileOperator

ANIMATION_DIR = "animation"


class CLIFF_TERRAIN_OT_season_animation(FileOperator, bpy.types.Operator):
    """Animate a season computed by `cliff-terrain season`: one relief per date, one date per frame,
    rendered into the season folder's animation/ (PNG frames and a video)"""

    bl_idname = "cliff_terrain.season_animation"
    bl_label = "Season Animation"
    bl_options = {"REGISTER", "UNDO"}
    path_property = "directory"

    directory: bpy.props.StringProperty(
        name="Season Folder",
        description="The folder `cliff-terrain season --out` wrote (season.json, cache/)",
        subtype="DIR_PATH",
    )
    show_plots: bpy.props.BoolProperty(
        name="Plot Outlines", description="Draw the season's plot polygons", default=True
    )
    color_by: bpy.props.StringProperty(
        name="Colour By",
        description="Colour the plots on each frame by a column of season.csv (cover, height_p90, ...: "
        "changes each date) or traits/traits.csv (max_height_m, senescence_date, ...); empty: the photo",
        default="",
    )
    render: bpy.props.BoolProperty(
        name="Render", description="Render the PNG frames and the video into animation/", default=True
    )

    def execute(self, context):
        try:
            from ..cliff_terrain.errors import CliffTerrainError
            from ..cliff_terrain.io.vector.plot_polygons import read_plots
            from ..cliff_terrain.season.reader import plot_colours, read_season
            from ..scene.season_animation import build_season_scene, render_season
            from .progress import Progress
        except ImportError as exc:
            self.report({"ERROR"}, f"Cliff Terrain cannot load its libraries: {exc}")
            return {"CANCELLED"}
        folder = Path(bpy.path.abspath(self.directory))
        try:
            season = read_season(folder)
            plots = read_plots(season.plots) if season.plots and (self.show_plots or self.color_by) else None
            colours = None
            if self.color_by:
                if plots is None:
                    raise CliffTerrainError(f"`color_by` {self.color_by!r} needs the season's plots file")
                colours = plot_colours(season, self.color_by, n_plots=len(plots.polygons))
                self.report({"INFO"}, f"colour by {colours.describe()}")
            with Progress(context) as bar:
                share = 0.25 if self.render else 1.0  # of the bar: the reliefs, then the frames
                built = build_season_scene(
                    context,
                    season,
                    plots=plots if self.show_plots else None,
                    colours=colours,
                    colour_plots=plots,
                    progress=lambda fraction, stage: bar(share * fraction, stage),
                )
                if self.render:
                    render_season(
                        built,
                        folder / ANIMATION_DIR,
                        log=lambda m: self.report({"INFO"}, m),
                        progress=lambda fraction, stage: bar(share + (1 - share) * fraction, stage),
                    )
        except CliffTerrainError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        except Exception as exc:  # a bug: the traceback to the console, the name to the user
            traceback.print_exc()
            self.report({"ERROR"}, f"Season Animation failed: {type(exc).__name__}: {exc}")
            return {"CANCELLED"}
        skipped = f"; {len(built.failed)} failed dates left out" if built.failed else ""
        self.report({"INFO"}, f"{len(built.dates)} dates, frames 1-{len(built.dates)}{skipped}")
        return {"FINISHED"}


CLASSES = (CLIFF_TERRAIN_OT_season_animation,)


# Registered in order, unregistered in reverse (Blender's own helper for exactly this).
register, unregister = bpy.utils.register_classes_factory(CLASSES)
