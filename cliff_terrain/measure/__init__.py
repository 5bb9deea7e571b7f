"""Numbers an agronomist reads: ground, canopy height, plants, field plots and their tables."""

# The package's public API: its modules (import them themselves; none is loaded by importing the package).
__all__ = [
    "canopy",
    "field_plots",
    "fit_flags",
    "grid_search",
    "ground",
    "ground_check",
    "ground_detail",
    "index_figures",
    "key_figures",
    "plot_fit",
    "plot_grid",
    "ruler",
    "tables",
]
