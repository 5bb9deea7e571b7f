"""Vector files of the field: plot polygons (GeoJSON, Shapefile), the plot grid's files and field book,
GeoJSON tables and transects. The names below are loaded when first used.
"""

import importlib

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


def __getattr__(name):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_EXPORTS))


__all__ = sorted(_EXPORTS)
