"""The output folder of a measuring command: checked before the work, and outputs that never look
complete when the run was interrupted.

Every command writes its files all or nothing (:func:`cliff_terrain.measure.tables.write_files`:
each to ``NAME.part-PID``, then all renamed, the *marker* last, a journal beside them while they
are renamed). A run killed while writing leaves ``.part-PID`` files, or some outputs without the
marker and with the journal: neither looks like a finished run. The same command then runs again
without ``--overwrite``: an interrupted run's outputs are replaced, and a dead run's ``.part-PID``
files are removed. Outputs *with* their marker are a finished run's, and files of those names
without marker or journal are the user's (a ``plots.geojson`` of their own in the folder): both
are kept unless ``--overwrite`` says otherwise. An input is never an output: that is refused even
with ``--overwrite``.
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
    """The `names` in folder `out` that must not be replaced without ``--overwrite``: all that exist,
    unless `marker` is missing and the renaming journal is there (an interrupted run's leftovers,
    replaced). Removes a dead run's ``.part-PID`` files."""
    from ..measure.tables import RENAMING_JOURNAL

    check_out_folder(out)
    if not out.is_dir():
        return []
    for leftover in out.iterdir():
        match = re.fullmatch(r".+\.part-(\d+)", leftover.name)
        if match and not _alive(int(match.group(1))) and leftover.is_file():
            leftover.unlink(missing_ok=True)
    if not (out / marker).exists() and (out / RENAMING_JOURNAL).exists():
        return []
    return [name for name in names if (out / name).exists()]


def check_inputs_not_outputs(out, names, inputs):
    """Refuse an input (``{option: path}``) that is one of the outputs `names` in folder `out`: the
    run would replace what it reads, ``--overwrite`` or not."""
    targets = {os.path.normcase(os.path.abspath(out / name)): name for name in names}
    for option, path in inputs.items():
        if path is not None and os.path.normcase(os.path.abspath(path)) in targets:
            name = targets[os.path.normcase(os.path.abspath(path))]
            raise CliffTerrainError(
                f"{option} {str(path)!r} is where --out {str(out)!r} writes its {name}: the run would "
                "replace its own input; give another --out"
            )


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
