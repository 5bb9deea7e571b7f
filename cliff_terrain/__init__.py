"""Cliff Terrain's pure core: one UAV crop photo to a textured 3D relief (numpy, scikit-image, OpenCV).

Never imports bpy. The main entry point is :func:`build_relief`.

Importing the package is cheap: the public names are loaded when first used (as scikit-image does),
after checking that the libraries they need import and are recent enough, so that a missing, broken
or too old library is reported by name and version (:class:`DependencyError`) rather than by
whichever module happens to import it first. The exceptions are always at hand.
"""

from ._lazy import attach
from .errors import CliffTerrainError, DependencyError, ImageReadError, ImageTooLargeError

__version__ = "0.1.0"

# Public name -> the module that defines it.
_EXPORTS = {
    "FieldTruth": "data.synthetic",
    "ImageMetadata": "io.photo._metadata",
    "MeshArrays": "mesh.grid",
    "MeshSizes": "mesh.grid",
    "OpenImage": "io.photo._open",
    "PhotoReader": "io.photo._reader",
    "Relief": "build",
    "ReliefParams": "params",
    "Segmentation": "photo_heights.segmentation",
    "adaptive_mesh": "mesh.adaptive",
    "build_relief": "build",
    "distance_map": "photo_heights.labels",
    "grid_mesh": "mesh.grid",
    "grid_shape": "build",
    "grid_sizes": "mesh.grid",
    "height_points": "evaluate.metrics",
    "inflate": "photo_heights.inflate",
    "load_image": "io.photo._open",
    "mesh_relief": "build",
    "open_image": "io.photo._open",
    "psnr": "evaluate.metrics",
    "quaternion_filter": "photo_heights.quaternion",
    "resize_longest": "photo_heights.resize",
    "segment": "photo_heights.segmentation",
    "ssim": "evaluate.metrics",
    "surface_distance": "evaluate.metrics",
    "synthetic_field": "data.synthetic",
    "vegetation_index": "photo_heights.vegetation",
}


def _check_required():
    from ._deps import check_required

    check_required()


__getattr__, __dir__, _lazy_names = attach(__name__, _EXPORTS, before=_check_required)
__all__ = [
    "CliffTerrainError",
    "DependencyError",
    "ImageReadError",
    "ImageTooLargeError",
    "__version__",
    *_lazy_names,
]
