"""Subcommands of ``cliff-terrain`` (see :mod:`cliff_terrain.cli`); each imported only when it runs."""

# The package's public API: its modules (import them themselves; none is loaded by importing the package).
__all__ = [
    "heights",
    "index_options",
    "memory_estimate",
    "out_folder",
    "plots",
    "relief",
    "season",
    "synthetic",
    "traits",
]
