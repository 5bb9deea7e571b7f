"""The output folder of a measuring command: checked before the work, and outputs that never look
complete when the run was interrupted.

Every command writes its files all or nothing (:func:`cliff_terrain.measure.tables.write_files`:
each to ``NAME.part-PID``, then all renamed, the *marker* last). A run killed while writing leaves
``.part-PID`` files, or some outputs without the marker: neither looks like a finished run. The same
command then runs again without ``--overwrite``: outputs without their marker are an interrupted
run's and are replaced, and a dead run's ``.part-PID`` files are removed. Outputs *with* their
marker are a finished run's and are kept unless ``--overwrite`` says otherwise.
"""

from __future__ import annotations

import os
import re

from ..errors import CliffTerrainError


def check_out_folder(out, *, option="--out"):
    """Refuse an output folder that is a file (before any work, so the work is not wasted)."""
    if out.exists() and not out.is_dir():
        raise CliffTerrainError(
            f"`{option}` {str(out)!r} is a file, not a folder; give a folder (it is created if missing)"
        )


def finished_outputs(out, names, *, marker):
    """The `names` in folder `out` a finished run wrote: all that exist when `marker` does, else none
    (an interrupted run's leftovers, replaced). Removes a dead run's ``.part-PID`` files."""
    check_out_folder(out)
    if not out.is_dir():
        return []
    for leftover in out.iterdir():
        match = re.fullmatch(r".+\.part-(\d+)", leftover.name)
        if match and not _alive(int(match.group(1))) and leftover.is_file():
            leftover.unlink(missing_ok=True)
    if not (out / marker).exists():
        return []
    return [name for name in names if (out / name).exists()]


def _alive(pid):
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True
    return True
