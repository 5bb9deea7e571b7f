"""The one exception family of Cliff Terrain, so callers (the Blender UI, the CLI) can catch precisely."""


class CliffTerrainError(ValueError):
    """Raised for any bad input or setting that Cliff Terrain refuses.

    It subclasses :class:`ValueError` so generic callers still see a value problem; the message
    always names the parameter (or file) and the value received.
    """


class ImageReadError(CliffTerrainError):
    """An image file is missing, unreadable, truncated, or not an image."""


class ImageTooLargeError(CliffTerrainError):
    """An image would decode past the documented memory limit and cannot be reduced."""
