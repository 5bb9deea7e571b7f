"""From a photo to heights: the quaternion filter, the segmentation and the inflation (the whole result,
heights, labels, mesh and georeference, is :class:`cliff_terrain.Relief`, made by :mod:`cliff_terrain.build`)."""

# The package's public API: its modules (import them themselves; none is loaded by importing the package).
__all__ = [
    "disk_max",
    "indices",
    "inflate",
    "labels",
    "quaternion",
    "resize",
    "segmentation",
    "separation",
    "vegetation",
    "watershed",
]
