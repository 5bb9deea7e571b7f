"""Synthetic fields the project generates itself (the demo input and the test oracles)."""

# The package's public API: its modules (import them themselves; none is loaded by importing the package).
__all__ = [
    "synthetic",
    "synthetic_surface",
]
