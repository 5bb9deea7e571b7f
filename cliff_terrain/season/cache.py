"""Each image's result on disk, keyed by what produced it, so a killed run resumes where it stopped.

The key hashes the photo's bytes (and its DSM's and the plots' file's), the relief parameters and
Cliff Terrain's version: change any of them and the image is computed again. An entry is two files,
``KEY.npz`` (the relief's heights and mask, for the Blender animation) and ``KEY.json`` (the table
rows); the JSON is written last and atomically, so an entry without it is an unfinished one.
Failed images are never cached. Needs numpy only.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np

# Bump when the layout of an entry or the meaning of its numbers changes.
FORMAT = 1
_CHUNK = 1 << 20


def file_hash(path):
    """SHA-256 of a file's bytes, as hex."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(_CHUNK):
            digest.update(chunk)
    return digest.hexdigest()


def cache_key(*, image_hash, params, version, extra_hashes=()):
    """The entry's name: a hash of the image's content, the sorted parameters and the version."""
    text = json.dumps(
        {
            "format": FORMAT,
            "image": image_hash,
            "extra": list(extra_hashes),
            "params": params,
            "version": version,
        },
        sort_keys=True,
    )
    return hashlib.sha256(text.encode()).hexdigest()[:32]


class Cache:
    """A folder of entries (see the module's docstring)."""

    def __init__(self, folder):
        self.folder = Path(folder)

    def paths(self, key):
        return self.folder / f"{key}.npz", self.folder / f"{key}.json"

    def has(self, key):
        arrays, record = self.paths(key)
        return arrays.is_file() and record.is_file()

    def load_record(self, key):
        """The entry's JSON record (its table rows and grid), or None when the entry is absent or broken."""
        _, record = self.paths(key)
        try:
            return json.loads(record.read_text())
        except (OSError, ValueError):
            return None

    def load_arrays(self, key):
        """``{"heights": float32, "mask": bool}`` of the entry's relief grid."""
        arrays, _ = self.paths(key)
        with np.load(arrays) as data:
            return {name: data[name] for name in data.files}

    def store(self, key, record, arrays):
        """Write an entry: the arrays first, then the record, each through a temporary file."""
        self.folder.mkdir(parents=True, exist_ok=True)
        arrays_path, record_path = self.paths(key)
        # A temporary name never ends in .npz or .json, so a run killed mid-write leaves no file
        # that looks like an entry (pathlib's glob matches dot-files too).
        tmp = arrays_path.with_name(f"{arrays_path.name}.{os.getpid()}.tmp")
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **arrays)
        os.replace(tmp, arrays_path)
        tmp = record_path.with_name(f"{record_path.name}.{os.getpid()}.tmp")
        tmp.write_text(json.dumps(record, sort_keys=True))
        os.replace(tmp, record_path)
