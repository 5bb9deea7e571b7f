"""Image loading: formats and modes to RGB, no-data, orientation, metadata/GSD, memory guard, bad input."""

from __future__ import annotations

import math
import struct
import tracemalloc
import warnings
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
import tifffile
from conftest import SHARED_UAV as UAV
from PIL import Image, ImageOps, TiffImagePlugin

from cliff_terrain.errors import CliffTerrainError, ImageReadError, ImageTooLargeError
from cliff_terrain.io.photo import ImageMetadata, load_image, read_metadata

needs_uav = pytest.mark.skipif(not UAV.is_dir(), reason=f"shared UAV images not found at {UAV}")
BROCCOLI = UAV / "broccoli" / "01_clip_raw_test.jpg"
CALITERRA = UAV / "caliterra" / "IMG_9370.jpg"
SENECA = UAV / "seneca_nir" / "IMG_0505.jpg"
DSM = UAV / "plantcv_dsm" / "gray.tif"
ORTHO_RGB = UAV / "plantcv_dsm" / "rgb.tif"


def _uav_photos():
    if not UAV.is_dir():
        return []
    return sorted(p for p in UAV.rglob("*") if p.suffix in (".jpg", ".tif") and p != DSM)


def _rng_image(shape, seed=0, dtype=np.uint8, high=256):
    return np.random.default_rng(seed).integers(0, high, shape).astype(dtype)


def _small_real_jpeg(path, size=(160, 120), quality=90, **save):
    """A small JPEG re-encoded from a crop of a real UAV photo (or a noise image without the data)."""
    if BROCCOLI.is_file():
        with Image.open(BROCCOLI) as im:
            crop = im.crop((400, 400, 400 + size[0], 400 + size[1]))
    else:
        crop = Image.fromarray(_rng_image((size[1], size[0], 3)))
    crop.save(path, quality=quality, **save)
    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"))


def _png_chunk(kind, data):
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _png_claiming(path, width, height):
    """A PNG whose IHDR (with a correct CRC) claims `width` x `height` RGB pixels, with almost no data."""
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    idat = zlib.compress(b"\x00" * 64)
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n"
        + _png_chunk(b"IHDR", ihdr)
        + _png_chunk(b"IDAT", idat)
        + _png_chunk(b"IEND", b"")
    )
    return path


def _jpeg_claiming(path, source, width, height):
    """Copy of JPEG `source` with its SOF frame header patched to claim `width` x `height`."""
    data = bytearray(source.read_bytes())
    i = 2
    while i < len(data):
        marker, length = data[i + 1], struct.unpack(">H", data[i + 2 : i + 4])[0]
        if marker in (0xC0, 0xC1, 0xC2):
            data[i + 5 : i + 9] = struct.pack(">HH", height, width)
            path.write_bytes(bytes(data))
            return path
        i += 2 + length
    raise AssertionError("no SOF marker")


def _raw_exif(path):
    """Independent EXIF reader: walk a JPEG's APP1 TIFF structure by hand -> {ifd name: {tag: value}}."""
    data = Path(path).read_bytes()
    i = 2
    tiff = None
    while i + 4 <= len(data) and data[i] == 0xFF:
        marker, length = data[i + 1], struct.unpack(">H", data[i + 2 : i + 4])[0]
        if marker == 0xE1 and data[i + 4 : i + 10] == b"Exif\x00\x00":
            tiff = data[i + 10 : i + 2 + length]
            break
        if marker == 0xDA:
            break
        i += 2 + length
    assert tiff is not None, f"no EXIF in {path}"
    order = "<" if tiff[:2] == b"II" else ">"
    sizes = {1: 1, 2: 1, 3: 2, 4: 4, 5: 8, 7: 1, 9: 4, 10: 8}

    def ifd(offset):
        out = {}
        (count,) = struct.unpack(order + "H", tiff[offset : offset + 2])
        for k in range(count):
            entry = tiff[offset + 2 + 12 * k : offset + 14 + 12 * k]
            tag, kind, n = struct.unpack(order + "HHI", entry[:8])
            size = sizes.get(kind, 1) * n
            raw = (
                entry[8 : 8 + size] if size <= 4 else tiff[struct.unpack(order + "I", entry[8:])[0] :][:size]
            )
            if kind == 2:
                out[tag] = raw.rstrip(b"\x00").decode("latin-1")
            elif kind == 3:
                out[tag] = struct.unpack(order + "H" * n, raw)
            elif kind == 4:
                out[tag] = struct.unpack(order + "I" * n, raw)
            elif kind == 5:
                ints = struct.unpack(order + "I" * (2 * n), raw)
                out[tag] = tuple(ints[j] / ints[j + 1] for j in range(0, 2 * n, 2))
            else:
                out[tag] = raw
        return out

    ifd0 = ifd(struct.unpack(order + "I", tiff[4:8])[0])
    return {
        "ifd0": ifd0,
        "exif": ifd(ifd0[0x8769][0]) if 0x8769 in ifd0 else {},
        "gps": ifd(ifd0[0x8825][0]) if 0x8825 in ifd0 else {},
    }


def _with_xmp(jpeg_bytes, packet):
    """Insert an XMP APP1 segment (the way DJI writes it) right after the JPEG's SOI marker."""
    payload = b"http://ns.adobe.com/xap/1.0/\x00" + packet
    segment = b"\xff\xe1" + struct.pack(">H", len(payload) + 2) + payload
    return jpeg_bytes[:2] + segment + jpeg_bytes[2:]


def _dji_xmp(relative_altitude, *, element=False):
    value = f"{relative_altitude:+.2f}"
    inner = (
        f"<drone-dji:RelativeAltitude>{value}</drone-dji:RelativeAltitude>"
        if element
        else f'drone-dji:RelativeAltitude="{value}"'
    )
    description = (
        f'<rdf:Description rdf:about="DJI Meta Data" xmlns:drone-dji="http://www.dji.com/drone-dji/1.0/">{inner}'
        "</rdf:Description>"
        if element
        else f'<rdf:Description rdf:about="DJI Meta Data" xmlns:drone-dji="http://www.dji.com/drone-dji/1.0/" '
        f'drone-dji:AbsoluteAltitude="+402.31" {inner} drone-dji:GimbalPitchDegree="-90.00"/>'
    )
    return (
        "<?xpacket begin='\ufeff' id='W5M0MpCehiHzreSzNTczkc9d'?>"
        '<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
        f"{description}</rdf:RDF></x:xmpmeta><?xpacket end='w'?>"
    ).encode()


def _dji_jpeg(path, *, relative_altitude=50.2, element=False, size=(640, 480)):
    exif = Image.Exif()
    exif[0x010F] = "DJI"
    exif[0x0110] = "FC6310"
    exif.get_ifd(0x8769)[0x920A] = TiffImagePlugin.IFDRational(88, 10)  # 8.8 mm
    exif.get_ifd(0x8769)[0xA405] = 24  # 35 mm equivalent
    exif.get_ifd(0x8825)[0x05] = b"\x00"
    exif.get_ifd(0x8825)[0x06] = TiffImagePlugin.IFDRational(3505, 10)  # 350.5 m above sea level
    tmp = path.with_suffix(".noxmp.jpg")
    _small_real_jpeg(tmp, size=size, exif=exif.tobytes())
    data = tmp.read_bytes()
    if relative_altitude is not None:
        data = _with_xmp(data, _dji_xmp(relative_altitude, element=element))
    path.write_bytes(data)
    return path


def _expected_dji_gsd(height, width=640, rows=480, focal=8.8, focal_35=24):
    crop = focal_35 / focal
    sensor_width = math.hypot(36, 24) / crop * width / math.hypot(width, rows)  # 43.27 mm full frame
    return height * sensor_width / (focal * width)


# ---------------------------------------------------------------------------------------------- bad input


def test_missing_path(tmp_path):
    path = tmp_path / "nowhere.jpg"
    with pytest.raises(ImageReadError, match=r"nowhere\.jpg.*no such file"):
        load_image(path)
    with pytest.raises(ImageReadError, match="no such file"):
        read_metadata(str(path))


def test_directory(tmp_path):
    with pytest.raises(ImageReadError, match="is a directory"):
        load_image(tmp_path)


def test_empty_file(tmp_path):
    path = tmp_path / "empty.jpg"
    path.write_bytes(b"")
    with pytest.raises(ImageReadError, match=r"empty\.jpg.*empty \(0 bytes\)"):
        load_image(path)


def test_non_image_bytes_named_jpg(tmp_path):
    path = tmp_path / "notes.jpg"
    path.write_bytes(b"These are field notes, not a photo.\n" * 20)
    with pytest.raises(ImageReadError, match=r"notes\.jpg.*not a JPEG, PNG, TIFF"):
        load_image(path)


def test_truncated_jpeg_is_refused_not_half_grey(tmp_path):
    source = tmp_path / "whole.jpg"
    _small_real_jpeg(source)
    data = source.read_bytes()
    path = tmp_path / "cut.jpg"
    path.write_bytes(data[: int(len(data) * 0.6)])
    with pytest.raises(ImageReadError, match=r"cut\.jpg.*truncated"):
        load_image(path)
    # The header is intact, so the metadata alone still reads.
    assert read_metadata(path).width == 160


def test_truncated_png_and_tiff(tmp_path):
    rgb = _rng_image((60, 70, 3))
    for suffix in (".png", ".tif"):
        whole = tmp_path / f"whole{suffix}"
        Image.fromarray(rgb).save(whole)
        cut = tmp_path / f"cut{suffix}"
        cut.write_bytes(whole.read_bytes()[: whole.stat().st_size // 2])
        with pytest.raises(ImageReadError, match=r"truncated|corrupt"):
            load_image(cut)


def test_a_tiff_cut_short_raises_the_truncated_kind_of_its_readers_error(tmp_path):
    # The kind, not the words, tells a file cut short from a broken one (the photo reader asked
    # TiffRaster's message for "is truncated" until 2026-12-07): a photo's is an ImageReadError, a
    # surface model's a RasterReadError, and both a TruncatedFileError.
    from cliff_terrain.errors import (
        RasterReadError,
        TruncatedFileError,
        TruncatedImageError,
        TruncatedRasterError,
    )
    from cliff_terrain.io.raster._tiff_window import TiffRaster

    whole = tmp_path / "whole.tif"
    tifffile.imwrite(whole, _rng_image((60, 70, 3)), photometric="rgb", compression="zlib")
    cut = tmp_path / "cut.tif"
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size // 2])
    with pytest.raises(TruncatedImageError, match=r"cut\.tif' is truncated: the file has") as raised:
        load_image(cut)
    assert isinstance(raised.value, ImageReadError)
    with pytest.raises(TruncatedRasterError, match="is truncated") as raised:
        TiffRaster(cut)
    assert isinstance(raised.value, RasterReadError) and isinstance(raised.value, TruncatedFileError)
    header = tmp_path / "header.tif"
    header.write_bytes(whole.read_bytes()[:6])
    with pytest.raises(TruncatedImageError, match="its TIFF header ends early"):
        TiffRaster(header, what="image", error=ImageReadError)
    broken = tmp_path / "broken.tif"
    broken.write_bytes(b"II*\x00" + b"\xff" * 400)  # a header pointing nowhere: corrupt, not cut
    with pytest.raises(RasterReadError) as raised:
        TiffRaster(broken)
    assert not isinstance(raised.value, TruncatedFileError)


def test_png_header_claiming_200000_squared_is_refused_without_decoding(tmp_path):
    path = _png_claiming(tmp_path / "bomb.png", 200_000, 200_000)
    message = r"bomb\.png.*200000x200000 pixels \(40000\.0 MP\).*max_pixels=150000000.*only JPEG"
    with pytest.raises(ImageTooLargeError, match=message):
        load_image(path)
    with pytest.raises(ImageTooLargeError, match=message):
        read_metadata(path, max_size=1000)


def test_over_our_limit_under_pillows_is_refused_and_warnings_stay_inside(tmp_path):
    # 13000 x 12000 = 156 MP: above MAX_PIXELS, where Pillow only warns (DecompressionBombWarning).
    path = _png_claiming(tmp_path / "big.png", 13_000, 12_000)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ImageTooLargeError, match=r"13000x12000 pixels"):
            load_image(path)


def test_huge_jpeg_header_is_reduced_with_max_size_else_refused(tmp_path):
    source = tmp_path / "small.jpg"
    _small_real_jpeg(source)
    # 300 MP claimed, past Pillow's own bomb error; padded after the end-of-image marker so the byte
    # count is plausible for that many pixels.
    path = _jpeg_claiming(tmp_path / "huge.jpg", source, 20_000, 15_000)
    path.write_bytes(path.read_bytes() + bytes(100_000))
    with pytest.raises(ImageTooLargeError, match=r"huge\.jpg.*20000x15000.*pass `max_size`"):
        load_image(path)
    meta = read_metadata(path, max_size=2000)
    assert (meta.width, meta.height, meta.reduction) == (20_000, 15_000, 8)
    assert (meta.decoded_width, meta.decoded_height) == (2500, 1875)
    with pytest.raises(ImageTooLargeError, match=r"even reduced by 4 for max_size=4000"):
        read_metadata(path, max_size=4000, max_pixels=10_000_000)


def test_jpeg_header_claiming_more_than_its_bytes_hold_is_refused(tmp_path):
    source = tmp_path / "small.jpg"
    _small_real_jpeg(source)
    path = _jpeg_claiming(tmp_path / "liar.jpg", source, 20_000, 15_000)
    size = path.stat().st_size
    # libjpeg would meet the end-of-image marker early and fill the rest with grey, without an error.
    with pytest.raises(ImageReadError, match=rf"liar\.jpg.*claims 20000x15000 pixels.*only {size} bytes"):
        load_image(path, max_size=2000)


@pytest.mark.parametrize("size", [(1, 1), (1, 7), (9, 1)])
def test_images_thinner_than_two_pixels_are_refused(tmp_path, size):
    for suffix in (".png", ".jpg"):
        path = tmp_path / f"thin{suffix}"
        Image.new("RGB", size, (10, 200, 30)).save(path)
        with pytest.raises(ImageReadError, match=rf"thin\{suffix}.*{size[0]}x{size[1]} pixels.*at least 2x2"):
            load_image(path)


def test_two_by_two_loads_exactly(tmp_path):
    rgb = np.array([[[255, 0, 0], [0, 255, 0]], [[0, 0, 255], [250, 251, 252]]], dtype=np.uint8)
    path = tmp_path / "tiny.png"
    Image.fromarray(rgb).save(path)
    out, meta = load_image(path)
    np.testing.assert_array_equal(out, rgb)
    assert (meta.width, meta.height, meta.decoded_width, meta.decoded_height) == (2, 2, 2, 2)


def test_paths_with_spaces_and_non_ascii(tmp_path):
    folder = tmp_path / "vuelo 3 – ñandú 写真"
    folder.mkdir()
    rgb = _rng_image((20, 30, 3))
    path = folder / "campo de maíz.png"
    Image.fromarray(rgb).save(path)
    for given in (path, str(path)):
        out, meta = load_image(given)
        np.testing.assert_array_equal(out, rgb)
        assert meta.path == str(path)
    with pytest.raises(ImageReadError, match="ñandú 写真"):
        load_image(folder / "falta.jpg")


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"max_size": 3}, r"`max_size` must be >= 16, got 3"),
        ({"max_size": 100.5}, r"`max_size` must be an integer, got 100\.5"),
        ({"gsd": 0}, r"`gsd` must be > 0"),
        ({"gsd": -0.01}, r"`gsd` must be > 0"),
        ({"height_above_ground": float("nan")}, r"`height_above_ground` must be finite"),
        ({"max_pixels": 2}, r"`max_pixels` must be >= 4, got 2"),
    ],
)
def test_settings_are_validated(tmp_path, kwargs, message):
    path = tmp_path / "ok.png"
    Image.new("RGB", (8, 8)).save(path)
    with pytest.raises(CliffTerrainError, match=message):
        load_image(path, **kwargs)


def test_path_type_is_validated():
    with pytest.raises(CliffTerrainError, match=r"`path` must be a str or os\.PathLike, got int"):
        load_image(123)


# ---------------------------------------------------------------------------------------- modes to RGB


def test_rgb_png_round_trip_is_exact_and_contiguous(tmp_path):
    rgb = _rng_image((33, 47, 3))
    path = tmp_path / "rgb.png"
    Image.fromarray(rgb).save(path)
    out, meta = load_image(path)
    assert out.dtype == np.uint8 and out.flags.c_contiguous and out.flags.writeable
    np.testing.assert_array_equal(out, rgb)
    assert (meta.format, meta.mode, meta.valid_fraction, meta.valid_mask) == ("PNG", "RGB", 1.0, None)
    assert meta.gsd_m_per_px is None and meta.gsd_source is None


def test_greyscale_and_bilevel(tmp_path):
    grey = _rng_image((25, 31))
    Image.fromarray(grey).save(tmp_path / "grey.png")
    out, meta = load_image(tmp_path / "grey.png")
    assert meta.mode == "L"
    np.testing.assert_array_equal(out, np.repeat(grey[..., None], 3, axis=2))

    bits = _rng_image((16, 24), high=2).astype(bool)
    Image.fromarray(bits).save(tmp_path / "bits.png")
    out, meta = load_image(tmp_path / "bits.png")
    assert meta.mode == "1"
    np.testing.assert_array_equal(out, np.repeat(bits[..., None], 3, axis=2).astype(np.uint8) * 255)


def test_sixteen_bit_greyscale_is_scaled_not_clipped(tmp_path):
    values = np.linspace(0, 65535, 40 * 50).astype(np.uint16).reshape(40, 50)
    expected = np.round(values / 257.0).astype(np.uint8)
    Image.fromarray(values).save(tmp_path / "g16.png")
    tifffile.imwrite(tmp_path / "g16le.tif", values)
    tifffile.imwrite(tmp_path / "g16be.tif", values, byteorder=">")
    for name in ("g16.png", "g16le.tif", "g16be.tif"):
        out, meta = load_image(tmp_path / name)
        assert meta.mode.startswith("I;16"), meta.mode
        np.testing.assert_array_equal(out[..., 0], expected, err_msg=name)
        np.testing.assert_array_equal(out[..., 2], expected, err_msg=name)
    assert out[0, 0, 0] == 0 and out[-1, -1, 0] == 255
    assert 100 < out[20, 25, 0] < 155  # mid-range stays mid-grey (a clip to 255 would saturate it)


def test_sixteen_bit_colour_png_and_tiff(tmp_path):
    values = _rng_image((30, 40, 3), dtype=np.uint16, high=65536)
    cv2.imwrite(str(tmp_path / "c16.png"), values[..., ::-1])  # OpenCV writes BGR
    tifffile.imwrite(tmp_path / "c16.tif", values, photometric="rgb")
    for name in ("c16.png", "c16.tif"):
        out, _ = load_image(tmp_path / name)
        error = np.abs(out.astype(float) - values / 257.0)
        assert error.max() <= 1.0, name


def test_thirty_two_bit_integers_in_sixteen_bit_range_load_and_beyond_are_refused(tmp_path):
    values = np.linspace(0, 65535, 20 * 30).astype(np.int32).reshape(20, 30)
    tifffile.imwrite(tmp_path / "i32.tif", values)
    out, meta = load_image(tmp_path / "i32.tif")
    assert meta.mode == "I"
    np.testing.assert_array_equal(out[..., 1], np.round(values / 257.0).astype(np.uint8))
    tifffile.imwrite(tmp_path / "counts.tif", values * 1000)
    with pytest.raises(ImageReadError, match=r"counts\.tif.*32-bit integers from 0 to 65535000"):
        load_image(tmp_path / "counts.tif")


def test_float_raster_is_refused_as_not_a_photo(tmp_path):
    tifffile.imwrite(
        tmp_path / "dsm.tif", np.linspace(137.6, 144.6, 30 * 20, dtype=np.float32).reshape(30, 20)
    )
    with pytest.raises(ImageReadError, match=r"dsm\.tif.*floating-point.*DSM, not a photograph"):
        load_image(tmp_path / "dsm.tif")
    with pytest.raises(ImageReadError, match=r"dsm\.tif.*floating-point"):
        read_metadata(tmp_path / "dsm.tif")


def test_palette_with_and_without_transparency(tmp_path):
    palette = _rng_image((256, 3), seed=3)
    index = _rng_image((20, 30), seed=4, high=16)
    im = Image.fromarray(index).convert("P")
    im.putpalette(palette.ravel().tolist())
    im.save(tmp_path / "pal.png")
    out, meta = load_image(tmp_path / "pal.png")
    assert meta.mode == "P"
    np.testing.assert_array_equal(out, palette[index])

    im.save(tmp_path / "pal_t.png", transparency=5)
    out, meta = load_image(tmp_path / "pal_t.png")
    holes = index == 5
    expected = palette[index].copy()
    expected[holes] = 0
    np.testing.assert_array_equal(out, expected)
    np.testing.assert_array_equal(meta.valid_mask, ~holes)
    assert meta.valid_fraction == pytest.approx(1 - holes.mean())


def test_rgba_no_data_is_black_partial_alpha_composited_and_masked(tmp_path):
    rgb = _rng_image((40, 60, 3), seed=5)
    alpha = np.full((40, 60), 255, np.uint8)
    alpha[:, :15] = 0  # outside the surveyed area
    alpha[30:, 40:] = 128  # a feathered edge
    Image.fromarray(np.dstack([rgb, alpha])).save(tmp_path / "ortho.png")
    out, meta = load_image(tmp_path / "ortho.png")
    expected = np.round(rgb * (alpha[..., None] / 255.0)).astype(np.uint8)
    np.testing.assert_array_equal(out, expected)
    assert meta.mode == "RGBA"
    np.testing.assert_array_equal(meta.valid_mask, alpha > 0)
    assert meta.valid_fraction == pytest.approx(45 / 60)

    Image.fromarray(np.dstack([rgb, np.full((40, 60), 255, np.uint8)])).save(tmp_path / "opaque.png")
    out, meta = load_image(tmp_path / "opaque.png")
    np.testing.assert_array_equal(out, rgb)
    assert meta.valid_mask is None and meta.valid_fraction == 1.0


def test_grey_with_alpha(tmp_path):
    grey = _rng_image((20, 20), seed=6)
    alpha = np.where(np.arange(20)[:, None] < 5, 0, 255).astype(np.uint8) * np.ones((1, 20), np.uint8)
    Image.fromarray(np.dstack([grey, alpha])).save(tmp_path / "la.png")
    out, meta = load_image(tmp_path / "la.png")
    assert meta.mode == "LA"
    np.testing.assert_array_equal(out[5:], np.repeat(grey[5:, :, None], 3, axis=2))
    assert not out[:5].any()
    assert meta.valid_fraction == pytest.approx(0.75)


def test_tiff_unspecified_fourth_sample_mask_or_band(tmp_path):
    rgb = _rng_image((30, 40, 3), seed=7)
    mask = np.zeros((30, 40), np.uint8)
    mask[5:25, 8:] = 255
    tifffile.imwrite(tmp_path / "gdal.tif", np.dstack([rgb, mask]), photometric="rgb", extrasamples=[0])
    out, meta = load_image(tmp_path / "gdal.tif")
    np.testing.assert_array_equal(out, np.where(mask[..., None] > 0, rgb, 0))
    np.testing.assert_array_equal(meta.valid_mask, mask > 0)

    nir = _rng_image((30, 40), seed=8)  # a real 4th band (near-infrared): ignored, every pixel is data
    tifffile.imwrite(tmp_path / "rgbn.tif", np.dstack([rgb, nir]), photometric="rgb", extrasamples=[0])
    out, meta = load_image(tmp_path / "rgbn.tif")
    np.testing.assert_array_equal(out, rgb)
    assert meta.valid_mask is None and meta.valid_fraction == 1.0


def _cmyk_to_rgb(cmyk):
    cmyk = cmyk.astype(float)
    return np.round((255 - cmyk[..., :3]) * (255 - cmyk[..., 3:]) / 255)


def test_cmyk_tiff_and_jpeg(tmp_path):
    cmyk = _rng_image((24, 32, 4), seed=9)
    tifffile.imwrite(tmp_path / "cmyk.tif", cmyk, photometric="separated")
    out, meta = load_image(tmp_path / "cmyk.tif")
    assert meta.mode == "CMYK"
    assert np.abs(out - _cmyk_to_rgb(cmyk)).max() <= 1

    Image.frombytes("CMYK", (32, 24), cmyk.tobytes()).save(tmp_path / "cmyk.jpg", quality=95)
    with Image.open(tmp_path / "cmyk.jpg") as im:
        decoded = np.asarray(im)  # the JPEG's own (lossy) CMYK pixels
    out, meta = load_image(tmp_path / "cmyk.jpg")
    assert meta.mode == "CMYK"
    assert np.abs(out - _cmyk_to_rgb(decoded)).max() <= 1


# ------------------------------------------------------------------------------------------- orientation


def _with_orientation(path, rgb, orientation, **save):
    exif = Image.Exif()
    exif[0x0112] = orientation
    Image.fromarray(rgb).save(path, exif=exif.tobytes(), **save)
    return path


@pytest.mark.parametrize("orientation", range(1, 9))
def test_every_exif_orientation_matches_pillow(tmp_path, orientation):
    rgb = _rng_image((12, 17, 3), seed=orientation)
    path = _with_orientation(tmp_path / "o.png", rgb, orientation)
    with Image.open(path) as im:
        expected = np.asarray(ImageOps.exif_transpose(im))
    out, meta = load_image(path)
    np.testing.assert_array_equal(out, expected)
    assert out.flags.c_contiguous
    assert meta.orientation == orientation
    assert (meta.width, meta.height) == (expected.shape[1], expected.shape[0])


def test_orientation_six_jpeg_is_rotated_clockwise(tmp_path):
    source = tmp_path / "plain.jpg"
    _small_real_jpeg(source, size=(160, 120))
    with Image.open(source) as im:
        rgb = np.asarray(im)
    path = _with_orientation(tmp_path / "o6.jpg", rgb, 6, quality=95)
    with Image.open(path) as im:
        stored = np.asarray(im)  # the stored (unrotated) pixels of this JPEG
    out, meta = load_image(path)
    np.testing.assert_array_equal(out, np.rot90(stored, k=-1))
    assert (meta.width, meta.height, meta.orientation) == (120, 160, 6)

    small, meta = load_image(path, max_size=16)
    assert small.shape == (20, 15, 3) and meta.reduction == 8
    assert (meta.decoded_width, meta.decoded_height) == (15, 20)


# --------------------------------------------------------------------------------------------- metadata


def test_dji_xmp_relative_altitude_gives_gsd(tmp_path):
    path = _dji_jpeg(tmp_path / "DJI_0001.JPG", relative_altitude=50.2)
    _, meta = load_image(path)
    assert (meta.camera_make, meta.camera_model) == ("DJI", "FC6310")
    assert meta.focal_length_mm == pytest.approx(8.8)
    assert meta.focal_length_35mm == 24
    assert meta.gps_altitude_m == pytest.approx(350.5)
    assert meta.relative_altitude_m == pytest.approx(50.2)
    assert meta.height_above_ground_m == pytest.approx(50.2)
    assert meta.gsd_source == "exif-xmp"
    assert meta.gsd_m_per_px == pytest.approx(_expected_dji_gsd(50.2), rel=1e-9)
    assert meta.sensor_width_mm == pytest.approx(43.27 / (24 / 8.8) * 640 / 800, rel=1e-4)
    assert read_metadata(path) == meta.__class__(**{**meta.__dict__, "valid_fraction": None})

    _, meta = load_image(path, height_above_ground=30)
    assert meta.gsd_source == "height_above_ground"
    assert meta.height_above_ground_m == 30
    assert meta.gsd_m_per_px == pytest.approx(_expected_dji_gsd(30), rel=1e-9)

    _, meta = load_image(path, gsd=0.011, height_above_ground=30)
    assert (meta.gsd_source, meta.gsd_m_per_px) == ("user", 0.011)


def test_dji_xmp_element_form_and_non_positive_altitude(tmp_path):
    _, meta = load_image(_dji_jpeg(tmp_path / "el.jpg", relative_altitude=12.5, element=True))
    assert meta.relative_altitude_m == pytest.approx(12.5)
    assert meta.gsd_m_per_px == pytest.approx(_expected_dji_gsd(12.5), rel=1e-9)

    _, meta = load_image(_dji_jpeg(tmp_path / "ground.jpg", relative_altitude=-0.3))
    assert meta.relative_altitude_m == pytest.approx(-0.3)
    assert meta.height_above_ground_m is None and meta.gsd_m_per_px is None


def test_gps_altitude_alone_gives_no_gsd(tmp_path):
    _, meta = load_image(_dji_jpeg(tmp_path / "no_xmp.jpg", relative_altitude=None))
    assert meta.gps_altitude_m == pytest.approx(350.5)
    assert meta.relative_altitude_m is None
    assert meta.height_above_ground_m is None
    assert meta.gsd_m_per_px is None and meta.gsd_source is None


def test_corrupt_exif_is_missing_metadata_not_an_error(tmp_path):
    source = tmp_path / "src.jpg"
    rgb = _small_real_jpeg(source)
    data = source.read_bytes()
    payload = b"Exif\x00\x00MM\x00*\x00\x00\x00\x08\xff\xff" + b"\x01" * 40  # IFD claims 65535 entries
    path = tmp_path / "bad_exif.jpg"
    path.write_bytes(data[:2] + b"\xff\xe1" + struct.pack(">H", len(payload) + 2) + payload + data[2:])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out, meta = load_image(path)
    np.testing.assert_array_equal(out, rgb)
    assert meta.camera_make is None and meta.orientation == 1


def test_metadata_is_frozen_and_mask_not_in_equality(tmp_path):
    path = tmp_path / "a.png"
    Image.new("RGB", (4, 4)).save(path)
    _, meta = load_image(path)
    assert isinstance(meta, ImageMetadata)
    with pytest.raises(AttributeError):
        meta.gsd_m_per_px = 1.0
    assert meta == ImageMetadata(**{**meta.__dict__, "valid_mask": np.zeros((4, 4), bool)})


# ------------------------------------------------------------------------------------------ real images


@needs_uav
@pytest.mark.parametrize("path", _uav_photos(), ids=lambda p: p.name)
def test_every_shared_uav_photo_loads(path):
    rgb, meta = load_image(path)
    assert rgb.dtype == np.uint8 and rgb.ndim == 3 and rgb.shape[2] == 3 and rgb.flags.c_contiguous
    assert (meta.decoded_height, meta.decoded_width) == rgb.shape[:2] == (meta.height, meta.width)
    if path.suffix == ".jpg":
        with Image.open(path) as im:
            np.testing.assert_array_equal(rgb, np.asarray(im))
        assert meta.valid_mask is None
        return
    # Orthophotos: compare with tifffile's reading of the four samples; alpha 0 is no-data.
    with tifffile.TiffFile(path) as tif:
        samples = tif.pages[0].asarray()
        scale = tif.geotiff_metadata["ModelPixelScale"]
    valid = samples[..., 3] > 0
    np.testing.assert_array_equal(rgb[valid], samples[..., :3][valid])
    assert not rgb[~valid].any()
    np.testing.assert_array_equal(meta.valid_mask, valid)
    assert meta.valid_fraction == pytest.approx(valid.mean())
    assert 0.3 < meta.valid_fraction < 0.95
    assert meta.gsd_source == "geotiff"
    assert meta.gsd_m_per_px == pytest.approx((scale[0] + scale[1]) / 2)
    assert 0.02 < meta.gsd_m_per_px < 0.03


@needs_uav
def test_real_dsm_is_refused_with_a_clear_message():
    with pytest.raises(ImageReadError, match=r"gray\.tif.*floating-point.*DSM, not a photograph"):
        load_image(DSM)


@needs_uav
@pytest.mark.parametrize("path", [CALITERRA, SENECA], ids=lambda p: p.parent.name)
def test_canon_exif_matches_an_independent_reading(path):
    raw = _raw_exif(path)
    meta = read_metadata(path)
    assert meta.camera_make == raw["ifd0"][0x010F] == "Canon"
    assert meta.camera_model == raw["ifd0"][0x0110]
    assert meta.orientation == raw["ifd0"][0x0112][0] == 1
    assert meta.focal_length_mm == pytest.approx(raw["exif"][0x920A][0])
    assert meta.focal_length_35mm is None and 0xA405 not in raw["exif"]
    assert meta.gps_altitude_m == pytest.approx(raw["gps"][0x06][0])
    assert meta.gsd_m_per_px is None and meta.height_above_ground_m is None  # sea-level altitude unused
    # Sensor width from the focal-plane resolution (pixels per inch at the camera's own pixel count).
    sensor = raw["exif"][0xA002][0] / raw["exif"][0xA20E][0] * 25.4
    assert meta.sensor_width_mm == pytest.approx(sensor)
    assert 5.5 < sensor < 6.5  # a 1/2.3" sensor is 6.17 mm wide

    _, loaded = load_image(path, height_above_ground=100.0)
    assert loaded.gsd_source == "height_above_ground"
    assert loaded.gsd_m_per_px == pytest.approx(100.0 * sensor / (meta.focal_length_mm * meta.width))
    assert loaded.camera_model == meta.camera_model


@needs_uav
def test_caliterra_reduced_decode_is_the_same_photo_with_far_less_memory():
    tracemalloc.start()
    full, full_meta = load_image(CALITERRA)
    full_peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    del full
    tracemalloc.start()
    small, meta = load_image(CALITERRA, max_size=1000, height_above_ground=100.0)
    small_peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()

    assert 1000 <= max(small.shape[:2]) < 2000
    assert small.shape == (750, 1000, 3) and meta.reduction == 4
    assert (meta.width, meta.height) == (4000, 3000)
    assert meta.decoded_gsd_m_per_px == pytest.approx(4 * meta.gsd_m_per_px)
    assert small_peak < full_peak / 4, (small_peak, full_peak)
    # Same picture: libjpeg's 1/4 decode is close to a 4x4 block mean of the full decode.
    full, _ = load_image(CALITERRA)
    blocks = full.reshape(750, 4, 1000, 4, 3).mean(axis=(1, 3))
    assert np.abs(small - blocks).mean() < 3.0
    assert full_meta.reduction == 1


@needs_uav
def test_memory_guard_reduces_a_real_jpeg_only_when_allowed():
    with pytest.raises(
        ImageTooLargeError, match=r"IMG_9370\.jpg.*4000x3000.*max_pixels=5000000.*pass `max_size`"
    ):
        load_image(CALITERRA, max_pixels=5_000_000)
    rgb, meta = load_image(CALITERRA, max_size=1000, max_pixels=5_000_000)
    assert rgb.shape == (750, 1000, 3) and meta.reduction == 4
    with pytest.raises(ImageTooLargeError, match=r"use a smaller max_size"):
        load_image(CALITERRA, max_size=3000, max_pixels=5_000_000)


# ------------------------------------------------------------------------------------ two-step decoding


def _pillow_reference(path, reduction=1):
    """What Pillow alone makes of a JPEG: decoded (reduced by libjpeg), upright, RGB."""
    with Image.open(path) as im:
        if reduction > 1:
            im.draft(im.mode, (im.size[0] // reduction, im.size[1] // reduction))
        return np.asarray(ImageOps.exif_transpose(im).convert("RGB"))


def _jpeg_variants(tmp_path):
    """Colour JPEGs of every chroma subsampling, progressive, greyscale and rotated ones."""
    source = tmp_path / "source.jpg"
    rgb = _small_real_jpeg(source, size=(161, 119))
    paths = [source]
    for subsampling in (0, 1, 2):
        paths.append(tmp_path / f"subsampling{subsampling}.jpg")
        Image.fromarray(rgb).save(paths[-1], quality=88, subsampling=subsampling)
    paths.append(tmp_path / "progressive.jpg")
    Image.fromarray(rgb).save(paths[-1], quality=88, progressive=True)
    paths.append(tmp_path / "grey.jpg")
    Image.fromarray(rgb).convert("L").save(paths[-1], quality=88)
    paths.append(_with_orientation(tmp_path / "o6.jpg", rgb, 6, quality=95))
    paths.append(_with_orientation(tmp_path / "o3.jpg", rgb, 3, quality=95))
    return paths


def test_jpegs_decode_in_one_call_to_exactly_pillows_pixels(tmp_path, monkeypatch):
    import cliff_terrain.io.photo._open as image_io

    pillow_decodes = []
    pillow_decode = image_io.decode_pixels
    monkeypatch.setattr(
        image_io, "decode_pixels", lambda im, name: pillow_decodes.append(name) or pillow_decode(im, name)
    )
    photos = _jpeg_variants(tmp_path) + [p for p in (BROCCOLI, CALITERRA, SENECA) if p.is_file()]
    for path in photos:
        for max_size in (None, 16, 60, 400):
            rgb, meta = load_image(path, max_size=max_size)
            expected = _pillow_reference(path, meta.reduction)
            assert rgb.shape == expected.shape and rgb.flags.c_contiguous, (path.name, max_size)
            np.testing.assert_array_equal(rgb, expected, err_msg=f"{path.name}, max_size={max_size}")
    # Every one of them went through OpenCV, none through Pillow's decoder.
    assert pillow_decodes == []
    # CMYK is Pillow's to convert.
    cmyk = tmp_path / "cmyk.jpg"
    Image.fromarray(_rng_image((20, 30, 3))).convert("CMYK").save(cmyk, quality=95)
    load_image(cmyk)
    assert pillow_decodes == [str(cmyk)]


def test_open_image_knows_the_shape_before_decoding(tmp_path):
    from cliff_terrain.io.photo import OpenImage, open_image

    path = _jpeg_variants(tmp_path)[-2]  # orientation 6: stored 161x119, shown 119x161
    with open_image(path, max_size=16, gsd=0.01) as image:
        assert isinstance(image, OpenImage)
        assert image.shape == (21, 15)  # libjpeg's 1/8, rotated
        assert image.metadata == read_metadata(path, max_size=16, gsd=0.01)
        rgb, meta = image.decode()
        assert rgb.shape[:2] == image.shape and meta == load_image(path, max_size=16, gsd=0.01)[1]
        with pytest.raises(CliffTerrainError, match=r"o6\.jpg' was already decoded or closed"):
            image.decode()
    with open_image(path) as image:
        pass  # closing without decoding is allowed
    with pytest.raises(CliffTerrainError, match="already decoded or closed"):
        image.decode()
    # Header errors come at once, pixel errors from decode().
    with pytest.raises(ImageReadError, match="no such file"):
        open_image(tmp_path / "missing.jpg")
    cut = tmp_path / "cut.jpg"
    cut.write_bytes(path.read_bytes()[:-400])
    with open_image(cut) as image, pytest.raises(ImageReadError, match="the file is truncated"):
        image.decode()
