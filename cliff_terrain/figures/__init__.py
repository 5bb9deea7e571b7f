"""Pictures for people: colour maps, legends, annotated views and contact sheets, and the files
of a rendered relief (``writer``: their names and their one writer)."""

# The package's public API: its modules (import them themselves; none is loaded by importing the package).
__all__ = [
    "annotate",
    "drawing",
    "legends",
    "ruler_chart",
    "sheet",
    "writer",
]
