"""The ``cliff-terrain`` command (also ``python -m cliff_terrain``): the core's jobs without Blender.

Each subcommand lives in its own module under :mod:`cliff_terrain.commands`, imported only when it
runs, so ``--help`` answers at once. A module defines ``HELP`` (one line), ``configure(parser)`` and
``run(args) -> int``. Bad input exits with status 2 and one line on stderr, never a traceback;
library warnings and log lines are kept off stderr (``CLIFF_TERRAIN_DEBUG=1`` shows them).
"""

from __future__ import annotations

import argparse
import importlib
import re
import sys

PROG = "cliff-terrain"

# Subcommand -> module under cliff_terrain.commands, in the order --help lists them.
COMMANDS = {
    "relief": "relief",
    "synthetic": "synthetic",
    "season": "season",
    "heights": "heights",
    "plots": "plots",
    "traits": "traits",
}


class _Parser(argparse.ArgumentParser):
    """argparse, but usage errors are one line and exit 2 (argparse prints the whole usage)."""

    def error(self, message):
        print(f"{self.prog}: error: {message}", file=sys.stderr)
        raise SystemExit(2)


def command_module(name):
    return importlib.import_module(f"{__package__}.commands.{COMMANDS[name]}")


def build_parser():
    from . import __version__

    parser = _Parser(
        prog=PROG, description="Cliff Terrain: UAV crop photos to 3D reliefs, heights and tables."
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    for name in COMMANDS:
        module = command_module(name)
        configure = module.configure
        child = sub.add_parser(name, help=module.HELP, description=module.HELP)
        configure(child)
    return parser


def as_typed(message, parser, command):
    """`message` with the core's parameter names, backticked (`ground_block`), as the options of
    `command` that set them (`--block`): the user typed the option, not the Python name."""
    import argparse

    (subparsers,) = (a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    for action in subparsers.choices[command]._actions:
        options = [o for o in action.option_strings if o.startswith("--")]
        if options and action.dest != "help":
            message = message.replace(f"`{action.dest}`", f"`{options[0]}`")
    return message


_NEGATIVE_PAIR = re.compile(r"-\.?\d[^,=\s]*,[^=\s]*$")


def main(argv=None):
    """Run the command line; return the exit status (0 ok, 1 some work failed, 2 bad input)."""
    from ._deps import check_required
    from .errors import CliffTerrainError

    argv = sys.argv[1:] if argv is None else list(argv)
    # argparse takes a negative map coordinate, "-120.5,4300" (--corners, --origin), for an unknown
    # option; no option of ours looks like a pair of numbers, so such a value gets a leading space,
    # which argparse reads as a value (its rule for values with spaces) and the parsers strip.
    argv = [f" {a}" if isinstance(a, str) and _NEGATIVE_PAIR.match(a) else a for a in argv]
    parser = build_parser()
    args = parser.parse_args(argv)
    _quiet_libraries()
    try:
        check_required()
        return int(command_module(args.command).run(args) or 0)
    except CliffTerrainError as exc:
        print(f"{PROG} {args.command}: error: {as_typed(str(exc), parser, args.command)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{PROG} {args.command}: interrupted", file=sys.stderr)
        return 130


def _quiet_libraries():
    """Keep library warnings and log lines off the user's stderr: it gets the one-line error, or
    the summary line (and progress bar) on success. ``CLIFF_TERRAIN_DEBUG=1`` lets them through.

    Pillow warns about truncated files and tifffile logs what it cannot parse; the readers turn
    both into the one-line error themselves. Worker processes (a local Dask cluster) inherit
    ``PYTHONWARNINGS``.
    """
    import logging
    import os
    import warnings

    if os.environ.get("CLIFF_TERRAIN_DEBUG"):
        return
    warnings.simplefilter("ignore")
    os.environ.setdefault("PYTHONWARNINGS", "ignore")
    os.environ.setdefault("DASK_LOGGING__DISTRIBUTED", "error")  # a local cluster's workers and scheduler
    # A handler on the root logger: without one, logging's last resort prints WARNING and above.
    logging.getLogger().addHandler(logging.NullHandler())
    logging.captureWarnings(True)


if __name__ == "__main__":
    sys.exit(main())
