"""Argument checks shared by the public functions; every message names the parameter and the value."""

from __future__ import annotations

import numbers

import numpy as np

from .errors import CliffTerrainError


def check_choice(name, value, choices):
    """Return `value` if it is one of `choices`, else raise naming the options."""
    if not isinstance(value, str) or value not in choices:
        options = ", ".join(repr(c) for c in choices)
        raise CliffTerrainError(f"`{name}` must be one of {options}, got {value!r}")
    return value


def check_int(name, value, *, minimum=None, maximum=None):
    """Return `value` as int, checking it is an integer within [minimum, maximum]."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise CliffTerrainError(f"`{name}` must be an integer, got {value!r}")
    value = int(value)
    if minimum is not None and value < minimum:
        raise CliffTerrainError(f"`{name}` must be >= {minimum}, got {value}")
    if maximum is not None and value > maximum:
        raise CliffTerrainError(f"`{name}` must be <= {maximum}, got {value}")
    return value


def check_float(name, value, *, minimum=None, maximum=None, strict_minimum=False, allow_none=False):
    """Return `value` as a finite float within bounds (`strict_minimum` makes the lower bound open)."""
    if value is None and allow_none:
        return None
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise CliffTerrainError(f"`{name}` must be a number, got {value!r}")
    value = float(value)
    if not np.isfinite(value):
        raise CliffTerrainError(f"`{name}` must be finite, got {value}")
    if minimum is not None:
        if strict_minimum and value <= minimum:
            raise CliffTerrainError(f"`{name}` must be > {minimum}, got {value}")
        if not strict_minimum and value < minimum:
            raise CliffTerrainError(f"`{name}` must be >= {minimum}, got {value}")
    if maximum is not None and value > maximum:
        raise CliffTerrainError(f"`{name}` must be <= {maximum}, got {value}")
    return value


def check_rgb(name, image, *, min_size=1):
    """Check an RGB image array of shape (rows, cols, 3); return it as a numpy array.

    uint8 is taken as [0, 255]; floating point must be finite (it is taken as [0, 1]).
    """
    if not isinstance(image, np.ndarray):
        raise CliffTerrainError(f"`{name}` must be a numpy array, got {type(image).__name__}")
    if image.ndim != 3 or image.shape[2] != 3:
        raise CliffTerrainError(f"`{name}` must have shape (rows, cols, 3), got {image.shape}")
    if image.shape[0] < min_size or image.shape[1] < min_size:
        raise CliffTerrainError(
            f"`{name}` must be at least {min_size}x{min_size} pixels, got {image.shape[0]}x{image.shape[1]}"
        )
    if image.dtype == np.uint8:
        return image
    if image.dtype.kind == "f":
        if not np.all(np.isfinite(image)):
            raise CliffTerrainError(f"`{name}` must hold finite values, got NaN or infinity")
        return image
    raise CliffTerrainError(f"`{name}` must be uint8 or floating point, got dtype {image.dtype}")
