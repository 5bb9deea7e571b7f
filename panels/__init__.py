"""The 3D Viewport sidebar of Cliff Terrain."""

from .sidebar import register, unregister

__all__ = ["register", "unregister"]
