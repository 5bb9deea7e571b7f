"""Orthomosaics larger than memory, tile by tile: the relief of each tile (``tiles``) and its mesh, joined
to its neighbours (``meshes``); the windows are read by :class:`cliff_terrain.io.raster.mosaic.MosaicReader`."""

# The package's public API: its modules (import them themselves; none is loaded by importing the package).
__all__ = [
    "meshes",
    "tiles",
]
