"""How good a relief is: PSNR/SSIM, the rendered views against the photo, mask quality."""

# The package's public API: its modules (import them themselves; none is loaded by importing the package).
__all__ = [
    "mask_quality",
    "metrics",
    "views",
]
