"""Cliff Terrain's pure core: one UAV crop photo to a textured 3D relief (numpy, scikit-image, OpenCV).

Never imports bpy. The main entry point is :func:`build_relief`.
"""

from .errors import CliffTerrainError, ImageReadError, ImageTooLargeError
from .heights import inflate
from .image_io import ImageMetadata, OpenImage, load_image, open_image
from .mesh import MeshArrays, MeshSizes, affine_matrix, apply_transform, grid_mesh, grid_sizes
from .metrics import height_points, psnr, ssim, surface_distance
from .pipeline import MeshSink, Relief, build_relief, resize_longest
from .quaternion import quaternion_filter
from .segmentation import Segmentation, distance_map, segment, vegetation_index
from .synthetic import FieldTruth, synthetic_field

__version__ = "0.1.0"

__all__ = [
    "CliffTerrainError",
    "FieldTruth",
    "ImageMetadata",
    "ImageReadError",
    "ImageTooLargeError",
    "MeshArrays",
    "MeshSink",
    "MeshSizes",
    "OpenImage",
    "Relief",
    "Segmentation",
    "__version__",
    "affine_matrix",
    "apply_transform",
    "build_relief",
    "distance_map",
    "grid_mesh",
    "grid_sizes",
    "height_points",
    "inflate",
    "load_image",
    "open_image",
    "psnr",
    "quaternion_filter",
    "resize_longest",
    "segment",
    "ssim",
    "surface_distance",
    "synthetic_field",
    "vegetation_index",
]
