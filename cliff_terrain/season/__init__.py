"""A season of flights: dates, per-image cache, the Dask runner and the growth chart.

``cliff-terrain season`` (``commands/season.py``) drives it. Import the modules themselves:
``dates`` and ``cache`` need only Pillow and numpy; ``runner`` imports Dask only when it runs on it,
``charts`` imports matplotlib (the ``season`` extra, ``pip install 'cliff-terrain[season]'``).
The Blender extension ships none of this but ``outputs`` (reading a season's results).
"""
