"""Byte-mutation fuzz of the image loader: only Cliff Terrain errors may escape, any result is RGB uint8.

The seeds are small re-encodings of crops of the shared UAV images (made at test time, so the fuzz
is fast), carrying real EXIF (a Canon frame's, MakerNote included), DJI-style XMP and an orientation
tag, so the mutations reach the marker parser, the EXIF/XMP readers and the entropy decoder.
"""

from __future__ import annotations

import io
import os
import struct

import numpy as np
import pytest
import tifffile
from conftest import SHARED_UAV as UAV
from PIL import Image

from cliff_terrain.errors import CliffTerrainError
from cliff_terrain.io.photo import load_image, read_metadata

# A longer run: CLIFF_TERRAIN_FUZZ_CASES=50000 CLIFF_TERRAIN_FUZZ_SEED=1 pytest tests/test_fuzz_jpeg.py
JPEG_CASES = int(os.environ.get("CLIFF_TERRAIN_FUZZ_CASES", 1500))
OTHER_CASES = JPEG_CASES // 3
SEED = int(os.environ.get("CLIFF_TERRAIN_FUZZ_SEED", 20240611))
# Small enough that a mutated header claiming a huge size is refused instead of allocated.
FUZZ_MAX_PIXELS = 2_000_000

DJI_XMP = (
    b"<?xpacket begin='\xef\xbb\xbf' id='W5M0MpCehiHzreSzNTczkc9d'?><x:xmpmeta xmlns:x=\"adobe:ns:meta/\">"
    b'<rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#"><rdf:Description rdf:about="" '
    b'xmlns:drone-dji="http://www.dji.com/drone-dji/1.0/" drone-dji:RelativeAltitude="+48.70" '
    b'drone-dji:GimbalPitchDegree="-90.00"/></rdf:RDF></x:xmpmeta><?xpacket end="w"?>'
)


def _crop(name, box):
    path = UAV / name
    if path.is_file():
        with Image.open(path) as im:
            return im.crop(box).convert("RGB"), im.info.get("exif", b"")
    # Without the shared data: a textured stand-in, so the fuzz still runs.
    rows = np.linspace(0, 255, box[3] - box[1])[:, None, None]
    cols = np.linspace(0, 255, box[2] - box[0])[None, :, None]
    noise = np.random.default_rng(1).integers(0, 40, (box[3] - box[1], box[2] - box[0], 3))
    return Image.fromarray(((rows + cols) / 2 + noise).clip(0, 255).astype(np.uint8)), b""


def _encode(im, fmt, **save):
    buffer = io.BytesIO()
    im.save(buffer, fmt, **save)
    return buffer.getvalue()


def _with_xmp(jpeg, packet):
    payload = b"http://ns.adobe.com/xap/1.0/\x00" + packet
    return jpeg[:2] + b"\xff\xe1" + struct.pack(">H", len(payload) + 2) + payload + jpeg[2:]


@pytest.fixture(scope="module")
def jpeg_seeds():
    broccoli, _ = _crop("broccoli/01_clip_raw_test.jpg", (500, 500, 596, 564))
    caliterra, canon_exif = _crop("caliterra/IMG_9370.jpg", (1800, 1400, 1880, 1460))
    seneca, _ = _crop("seneca_nir/IMG_0505.jpg", (1500, 1000, 1572, 1048))
    rotated = Image.Exif()
    rotated[0x0112] = 6
    seeds = {
        "baseline": _encode(broccoli, "JPEG", quality=85),
        "canon-exif-progressive": _encode(caliterra, "JPEG", quality=80, progressive=True, exif=canon_exif),
        "dji-xmp-444": _with_xmp(_encode(seneca, "JPEG", quality=90, subsampling=0), DJI_XMP),
        "grey-orientation-6": _encode(broccoli.convert("L"), "JPEG", quality=75, exif=rotated.tobytes()),
        "cmyk": _encode(seneca.convert("CMYK"), "JPEG", quality=80),
    }
    assert all(len(data) < 20_000 for data in seeds.values()), {k: len(v) for k, v in seeds.items()}
    return seeds


@pytest.fixture(scope="module")
def other_seeds():
    ortho = UAV / "plantcv_dsm" / "rgb.tif"
    if ortho.is_file():
        rgba = tifffile.imread(ortho)[100:148, 60:124]
    else:
        rgba = np.dstack([np.asarray(_crop("", (0, 0, 64, 48))[0]), np.full((48, 64), 255, np.uint8)])
    gdal_style = io.BytesIO()
    tifffile.imwrite(gdal_style, rgba, photometric="rgb", extrasamples=[0])
    return {
        "png-rgba": _encode(Image.fromarray(rgba), "PNG"),
        "tiff-gdal-alpha": gdal_style.getvalue(),
        "tiff-lzw": _encode(Image.fromarray(rgba[..., :3]), "TIFF", compression="tiff_lzw"),
    }


def _mutate(data, rng, *, header_bytes=700):
    """One random corruption: overwrite bytes, truncate, insert, delete, or hit the header/markers."""
    data = bytearray(data)
    kind = int(rng.integers(6))
    if kind == 0:  # overwrite a few bytes anywhere
        for _ in range(int(rng.integers(1, 9))):
            data[int(rng.integers(len(data)))] = int(rng.integers(256))
    elif kind == 1:  # truncate
        del data[int(rng.integers(1, len(data))) :]
    elif kind == 2:  # insert random bytes
        at = int(rng.integers(len(data)))
        data[at:at] = rng.integers(0, 256, int(rng.integers(1, 17)), dtype=np.uint8).tobytes()
    elif kind == 3:  # delete a slice
        at = int(rng.integers(len(data)))
        del data[at : at + int(rng.integers(1, 65))]
    elif kind == 4:  # overwrite inside the header (markers, sizes, EXIF/XMP, IFDs)
        for _ in range(int(rng.integers(1, 5))):
            data[int(rng.integers(min(header_bytes, len(data))))] = int(rng.integers(256))
    else:  # set bytes to the values that matter most to parsers
        for _ in range(int(rng.integers(1, 4))):
            data[int(rng.integers(len(data)))] = int(
                rng.choice([0x00, 0xFF, 0xD8, 0xD9, 0xDA, 0xC0, 0x7F, 0x80])
            )
    return bytes(data)


def _fuzz(seeds, n_cases, tmp_path, seed):
    rng = np.random.default_rng(seed)
    names = sorted(seeds)
    path = tmp_path / "fuzzed image.jpg"
    escaped, loaded, refused = [], 0, 0
    for case in range(n_cases):
        name = names[case % len(names)]
        data = _mutate(seeds[name], rng)
        path.write_bytes(data)
        max_size = [None, 16, 32][case % 3]
        try:
            rgb, meta = load_image(path, max_size=max_size, max_pixels=FUZZ_MAX_PIXELS)
        except CliffTerrainError as error:
            assert str(path) in str(error)
            refused += 1
        except Exception as error:  # noqa: BLE001 - the point of the fuzz is to catch anything else
            escaped.append((case, name, type(error).__name__, str(error)[:120]))
            continue
        else:
            loaded += 1
            assert rgb.dtype == np.uint8 and rgb.ndim == 3 and rgb.shape[2] == 3, (case, name, rgb.shape)
            assert rgb.flags.c_contiguous
            assert (meta.decoded_height, meta.decoded_width) == rgb.shape[:2]
            assert meta.valid_mask is None or meta.valid_mask.shape == rgb.shape[:2]
        try:
            read_metadata(path, max_pixels=FUZZ_MAX_PIXELS)
        except CliffTerrainError:
            pass
        except Exception as error:  # noqa: BLE001
            escaped.append((case, name, "read_metadata " + type(error).__name__, str(error)[:120]))
    return escaped, loaded, refused


def test_fuzzed_jpegs_raise_only_cliff_terrain_errors(jpeg_seeds, tmp_path):
    for name, data in jpeg_seeds.items():  # the seeds themselves are valid
        (tmp_path / "seed.jpg").write_bytes(data)
        rgb, _ = load_image(tmp_path / "seed.jpg")
        assert rgb.dtype == np.uint8 and rgb.shape[2] == 3, name
    escaped, loaded, refused = _fuzz(jpeg_seeds, JPEG_CASES, tmp_path, seed=SEED)
    print(f"JPEG fuzz: {JPEG_CASES} cases, {loaded} loaded, {refused} refused, {len(escaped)} escaped")
    assert not escaped, escaped[:10]
    # Both outcomes are exercised (the mutations are neither all harmless nor all fatal).
    assert loaded > JPEG_CASES // 10 and refused > JPEG_CASES // 10


def test_fuzzed_png_and_tiff_raise_only_cliff_terrain_errors(other_seeds, tmp_path):
    escaped, loaded, refused = _fuzz(other_seeds, 2 * OTHER_CASES, tmp_path, seed=7)
    print(
        f"PNG/TIFF fuzz: {2 * OTHER_CASES} cases, {loaded} loaded, {refused} refused, {len(escaped)} escaped"
    )
    assert not escaped, escaped[:10]
    assert loaded > 0 and refused > 0
