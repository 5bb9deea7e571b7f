"""From heights to a mesh: the grid, the adaptive TIN and seams (an orthomosaic's tiles: cliff_terrain.mosaic)."""

# The package's public API: its modules (import them themselves; none is loaded by importing the package).
__all__ = [
    "adaptive",
    "grid",
    "quads",
    "seams",
    "tin",
    "tin_sample",
]
