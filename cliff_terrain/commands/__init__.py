"""Subcommands of ``cliff-terrain`` (see :mod:`cliff_terrain.cli`); each imported only when it runs."""
