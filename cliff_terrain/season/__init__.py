"""A season of flights: dates, per-image cache, the Dask runner and the growth chart.

``cliff-terrain season`` (``commands/season.py``) drives it. Import the modules themselves:
``dates`` and ``cache`` need only Pillow and numpy; ``runner`` imports Dask only when it runs on it,
``charts`` imports matplotlib (the ``season`` extra, ``pip install 'cliff-terrain[season]'``).
The Blender extension ships none of this but ``reader`` (reading a season's results back).
"""

# The package's public API: its modules (import them themselves; none is loaded by importing the package).
__all__ = [
    "align",
    "cache",
    "charts",
    "cluster",
    "dates",
    "growth",
    "plan",
    "reader",
    "runner",
    "security",
    "table",
    "task",
    "trait_charts",
    "traits",
]
