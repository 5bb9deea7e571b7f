"""Cliff Terrain's pure core: one UAV crop photo to a textured 3D relief (numpy, scikit-image, OpenCV).

Never imports bpy. The main entry point is :func:`build_relief`.

Importing the package is cheap: the public names are loaded when first used (as scikit-image does),
after checking that the libraries they need import and are recent enough, so that a missing, broken
or too old library is reported by name and version (:class:`DependencyError`) rather than by
whichever module happens to import it first. The exceptions are always at hand.
"""

import importlib

from .errors import CliffTerrainError, DependencyError, ImageReadError, ImageTooLargeError

__version__ = "0.1.0"

# Public name -> the module that defines it.
_EXPORTS = {
    "FieldTruth": "synthetic",
    "ImageMetadata": "image_io",
    "MeshArrays": "mesh",
    "MeshSink": "pipeline",
    "MeshSizes": "mesh",
    "OpenImage": "image_io",
    "Relief": "pipeline",
    "Segmentation": "segmentation",
    "adaptive_mesh": "mesh",
    "build_relief": "pipeline",
    "distance_map": "segmentation",
    "grid_mesh": "mesh",
    "grid_sizes": "mesh",
    "height_points": "metrics",
    "inflate": "heights",
    "load_image": "image_io",
    "open_image": "image_io",
    "psnr": "metrics",
    "quaternion_filter": "quaternion",
    "resize_longest": "pipeline",
    "segment": "segmentation",
    "ssim": "metrics",
    "surface_distance": "metrics",
    "synthetic_field": "synthetic",
    "vegetation_index": "segmentation",
}


def __getattr__(name):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from ._deps import check_required

    check_required()
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_EXPORTS))


__all__ = [
    "CliffTerrainError",
    "DependencyError",
    "ImageReadError",
    "ImageTooLargeError",
    "__version__",
    *sorted(_EXPORTS),
]
