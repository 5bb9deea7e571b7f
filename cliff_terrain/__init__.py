"""Cliff Terrain's pure core: one UAV crop photo to a textured 3D relief (numpy, scikit-image, OpenCV).

Never imports bpy. The main entry point is :func:`build_relief`.
"""

from .errors import CliffTerrainError, ImageReadError, ImageTooLargeError
from .heights import inflate
from .image_io import ImageMetadata, load_image
from .mesh import MeshArrays, affine_matrix, apply_transform, grid_mesh
from .metrics import height_points, psnr, ssim, surface_distance
from .pipeline import Relief, build_relief, resize_longest
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
    "Relief",
    "Segmentation",
    "__version__",
    "affine_matrix",
    "apply_transform",
    "build_relief",
    "distance_map",
    "grid_mesh",
    "height_points",
    "inflate",
    "load_image",
    "psnr",
    "quaternion_filter",
    "resize_longest",
    "segment",
    "ssim",
    "surface_distance",
    "synthetic_field",
    "vegetation_index",
]
