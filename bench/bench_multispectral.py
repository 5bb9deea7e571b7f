"""Multispectral reading and vegetation indices on real UAV rasters, against plain tifffile + numpy.

    python bench/bench_multispectral.py [--data DIR] [--repeat 7]

Times in one run, on the same files: reading the bands (``read_bands``) against a peer that reads
them with ``tifffile.imread`` and applies the same no-data and scaling rules in numpy; and NDVI,
NDRE, GNDVI, OSAVI per pixel (``index_map``) against each formula written out in numpy on the
peer's bands. It prints the ratios (ours / peer, lower is faster), the largest difference of the
bands and of the index maps, and the whole-field means.

The real orthomosaic clip ``tests/data/multispectral/615.tif`` (PlantCV-geospatial, MPL-2.0) is
always there. ``--data DIR`` adds a MicaSense RedEdge capture (micasense/imageprocessing, MIT, the
2017 files from before they moved to Git LFS): ``DIR/raw/IMG_0001_{1..5}.tif`` (one raw 16-bit file
per band, in the camera's order B, G, R, NIR, RE) and ``DIR/derived/IMG_0001_stack_BGRReN.tif`` (the
same bands shifted onto NIR and stacked, with GDAL band descriptions). These stay outside the
repository. Their values are raw counts and the raw bands are not co-registered, so their indices
are timed and checked against the formulas, not read as agronomy.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
import tifffile

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from machine_info import describe  # noqa: E402

from cliff_terrain.io.raster.bands import read_bands  # noqa: E402
from cliff_terrain.photo_heights.indices import index_map  # noqa: E402

INDEX_NAMES = ("NDVI", "NDRE", "GNDVI", "OSAVI")
FORMULAS = {
    "NDVI": lambda b: (b["nir"] - b["red"]) / (b["nir"] + b["red"]),
    "NDRE": lambda b: (b["nir"] - b["rededge"]) / (b["nir"] + b["rededge"]),
    "GNDVI": lambda b: (b["nir"] - b["green"]) / (b["nir"] + b["green"]),
    "OSAVI": lambda b: (b["nir"] - b["red"]) / (b["nir"] + b["red"] + np.float32(0.16)),
}


def cases(data):
    found = [
        {
            "label": "615.tif: real 5-band float32 reflectance clip, 161x177, no data -10000",
            "path": REPO / "tests" / "data" / "multispectral" / "615.tif",
            "names": "B,G,R,RE,NIR",  # the file names no band (PlantCV's own test gives the order)
            "order": ("blue", "green", "red", "rededge", "nir"),
            "scale": None,
            "nodata": -10000.0,
        }
    ]
    if data is not None:
        found += [
            {
                "label": "MicaSense RedEdge IMG_0001 stacked, 5-band uint16, 1238x918, named in the file",
                "path": data / "derived" / "IMG_0001_stack_BGRReN.tif",
                "names": None,
                "order": ("blue", "green", "red", "rededge", "nir"),
                "scale": 65535.0,
                "nodata": None,
            },
            {
                "label": "MicaSense RedEdge IMG_0001 raw, one uint16 file per band, 1280x960",
                "path": [data / "raw" / f"IMG_0001_{i}.tif" for i in (1, 2, 3, 4, 5)],
                "names": "B,G,R,NIR,RE",  # the camera's file order: NIR (4) before red edge (5)
                "order": ("blue", "green", "red", "nir", "rededge"),
                "scale": 65535.0,
                "nodata": None,
            },
        ]
    return found


def peer_read(paths, order, scale, nodata):
    """The peer: tifffile, then the reader's no-data and scaling rules written out in numpy."""
    paths = [paths] if isinstance(paths, str | os.PathLike) else list(paths)
    planes = [tifffile.imread(p) for p in paths]
    raw = np.concatenate([p[..., None] if p.ndim == 2 else p for p in planes], axis=2)[..., : len(order)]
    data = raw.astype(np.float32)
    invalid = ~np.isfinite(data).all(axis=2) | (raw == 0).all(axis=2)
    if nodata is not None:
        invalid |= (raw == nodata).all(axis=2)
    if scale is not None:
        data /= np.float32(scale)
    data[invalid] = np.nan
    return {name: data[..., k] for k, name in enumerate(order)}


def best_of(function, repeat):
    times, result = [], None
    for _ in range(repeat):
        started = time.perf_counter()
        result = function()
        times.append(time.perf_counter() - started)
    return min(times), result


def run_case(case, repeat):
    print(f"\n{case['label']}")
    t_ours, bands = best_of(lambda: read_bands(case["path"], names=case["names"]), repeat)
    t_peer, peer = best_of(
        lambda: peer_read(case["path"], case["order"], case["scale"], case["nodata"]), repeat
    )
    worst = max(
        float(np.nanmax(np.abs(bands.data[..., bands.names.index(name)] - peer[name])))
        for name in case["order"]
    )
    print(
        f"  read     ours {t_ours * 1e3:7.2f} ms  peer {t_peer * 1e3:7.2f} ms  ratio {t_ours / t_peer:4.2f}  "
        f"max |band difference| {worst:.2g}  valid {int(bands.valid.sum())}/{bands.valid.size} px"
    )
    for name in INDEX_NAMES:
        t_o, ours = best_of(lambda n=name: index_map(bands, n), repeat)
        with np.errstate(invalid="ignore", divide="ignore"):
            t_p, expected = best_of(lambda n=name: FORMULAS[n](peer), repeat)
        both = np.isfinite(ours) & np.isfinite(expected)
        difference = float(np.max(np.abs(ours[both] - expected[both]))) if both.any() else float("nan")
        print(
            f"  {name:6s}   ours {t_o * 1e3:7.2f} ms  peer {t_p * 1e3:7.2f} ms  ratio {t_o / t_p:4.2f}  "
            f"max |difference| {difference:.1e}  mean {np.nanmean(ours):.4f} (peer {np.nanmean(expected):.4f})"
        )


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=None, help="the MicaSense folder (raw/, derived/)")
    parser.add_argument("--repeat", type=int, default=7)
    args = parser.parse_args(argv)
    print(describe())
    for case in cases(args.data):
        paths = case["path"] if isinstance(case["path"], list) else [case["path"]]
        if not all(Path(p).exists() for p in paths):
            print(f"\n{case['label']}: not under {args.data}, skipped")
            continue
        run_case(case, args.repeat)


if __name__ == "__main__":
    main()
