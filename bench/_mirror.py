"""Files of public GitHub repositories at pinned commits, read from bare git mirrors: what
``bench/layout_fields.py`` and ``bench/layout_masks.py`` lay their validation sets out from.

A repository ``owner/name`` is looked for at ``MIRROR/owner+name/repo`` (the session's `fetch`
tool puts it there; anything else: ``git clone --bare``, then set the ``MIRROR`` environment
variable). The repositories held out for the project's own checks are refused by name.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
from pathlib import Path

MIRROR = Path(os.environ.get("MIRROR", "/work/.mirror"))
# Held out for the project's own checks (the developers' guide): never read here.
RESERVED = {
    "filipematias23/Bison-Fly_Workshop_01",
    "eseigel/plantcv-geospatial-tutorial-plant-height",
    "niconaut/CropDetectR",
    "JamesMCurrier/FieldMeasurer",
    "aipal-nchu/RiceSeedlingDataset",
}


def git_dir(repo):
    """The bare git directory of `repo` (``owner/name``) under :data:`MIRROR`."""
    if repo in RESERVED:
        raise SystemExit(f"refusing {repo}: held out")
    base = MIRROR / repo.replace("/", "+") / "repo"
    return base / ".git" if (base / ".git").is_dir() else base


def git(repo, *args):
    """``git --git-dir <repo's mirror> ARGS``' standard output (bytes)."""
    return subprocess.run(
        ["git", "--git-dir", str(git_dir(repo)), *args], check=True, capture_output=True
    ).stdout


def blob(repo, commit, path):
    """The bytes of `path` at `commit`, refusing a Git LFS pointer (the file itself is elsewhere)."""
    data = git(repo, "show", f"{commit}:{path}")
    if data.startswith(b"version https://git-lfs"):
        raise SystemExit(f"{repo}:{path} is a Git LFS pointer; no copy of it here")
    return data


def blob_id(data):
    """Git's blob id (sha1) of `data`: what the MANIFESTs record, comparable with ``git ls-tree``."""
    return hashlib.sha1(b"blob %d\0" % len(data) + data).hexdigest()
