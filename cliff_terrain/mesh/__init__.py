"""From heights to a mesh: the grid, the adaptive TIN and seams (an orthomosaic's tiles: cliff_terrain.mosaic)."""
