"""Vector files of the field: plot polygons (GeoJSON, Shapefile), the plot grid's files and field book,
GeoJSON tables and transects. The names below are loaded when first used.
"""

from ..._lazy import attach

# Public name -> the module of this package that defines it (imported when the name is first used).
_EXPORTS = {
    "PlotSet": "plot_polygons",
    "Transect": "transect",
    "join_field_book": "plot_files",
    "parse_transect": "transect",
    "read_field_book": "plot_files",
    "read_plots": "plot_polygons",
    "table_geojson": "geojson",
    "write_plots": "plot_files",
}

__getattr__, __dir__, __all__ = attach(__name__, _EXPORTS)
