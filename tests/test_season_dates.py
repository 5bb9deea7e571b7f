"""The date of each photo of a season (cliff_terrain.season.dates), and the per-image cache's keys."""

from __future__ import annotations

import datetime as dt
import hashlib
import os
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from cliff_terrain.errors import CliffTerrainError
from cliff_terrain.season.cache import Cache, cache_key, file_hash
from cliff_terrain.season.dates import check_given_dates, date_in_name, parse_given_dates, photo_date

RGB = np.full((8, 8, 3), 90, dtype=np.uint8)


def _jpeg_with_exif(path, original=None, stamp=None):
    exif = Image.Exif()
    if stamp is not None:
        exif[0x0132] = stamp
    if original is not None:
        exif.get_ifd(0x8769)[0x9003] = original
    Image.fromarray(RGB).save(path, exif=exif)
    return path


def test_exif_original_wins_over_the_tiff_tag_and_the_name(tmp_path):
    path = _jpeg_with_exif(
        tmp_path / "20180101.jpg", original="2018:08:15 10:31:02", stamp="2019:01:02 00:00:00"
    )
    # Pillow reads back what it wrote, so the reference is independent of our reader.
    with Image.open(path) as im:
        assert im.getexif().get_ifd(0x8769)[0x9003] == "2018:08:15 10:31:02"
    assert photo_date(path) == (dt.date(2018, 8, 15), "exif")


def test_tiff_datetime_when_neither_exif_original_nor_the_name_says(tmp_path):
    path = tmp_path / "field.tif"
    Image.fromarray(RGB).save(path, tiffinfo={306: "2018:09:05 12:00:00"})
    assert photo_date(path) == (dt.date(2018, 9, 5), "tiff")


def test_the_name_beats_the_tiff_datetime_of_a_file_saved_again(tmp_path):
    # An orthomosaic's DateTime is when it was written: re-saved in September, a flight named for
    # June was dated September and every trait's days moved.
    path = tmp_path / "2024-06-22.tif"
    Image.fromarray(RGB).save(path, tiffinfo={306: "2024:09:30 10:00:00"})
    assert photo_date(path) == (dt.date(2024, 6, 22), "filename")


def test_file_name_then_the_option(tmp_path):
    named = tmp_path / "flight_2018-09-25_rgb.png"
    Image.fromarray(RGB).save(named)
    assert photo_date(named) == (dt.date(2018, 9, 25), "filename")
    bare = tmp_path / "flight_a.png"
    Image.fromarray(RGB).save(bare)
    given = parse_given_dates(["flight_a.png=2018-08-22"])
    assert photo_date(bare, given=given) == (dt.date(2018, 8, 22), "option")
    # What the user says wins over the file's own date, by its name or its path as typed.
    assert photo_date(named, given={"flight_2018-09-25_rgb.png": dt.date(2000, 1, 1)}) == (
        dt.date(2000, 1, 1),
        "option",
    )
    relative = os.path.relpath(named)
    assert photo_date(named, given={relative: dt.date(2001, 1, 1)}) == (dt.date(2001, 1, 1), "option")
    linked = tmp_path / "linked"
    linked.symlink_to(tmp_path)  # the photo found through a link, the date given by the real path
    assert photo_date(linked / named.name, given={str(named): dt.date(2002, 1, 1)})[0] == dt.date(2002, 1, 1)


def test_dates_naming_no_input_or_several_are_refused(tmp_path):
    a, b = tmp_path / "a" / "odm_orthophoto.tif", tmp_path / "b" / "odm_orthophoto.tif"
    for photo in (a, b):
        photo.parent.mkdir()
        Image.fromarray(RGB).save(photo)
    given = {"odm_orthophoto.tif": dt.date(2024, 6, 1)}
    with pytest.raises(CliffTerrainError, match=r"names 2 photos .*; give each one's path instead"):
        check_given_dates(given, [a, b])
    with pytest.raises(CliffTerrainError, match=r"--dates typo.tif=\.\.\.: no input photo is 'typo.tif'"):
        check_given_dates({"typo.tif": dt.date(2024, 6, 1)}, [a, b])
    check_given_dates({str(a): dt.date(2024, 6, 1), str(b): dt.date(2024, 6, 8)}, [a, b])


def test_unset_camera_clock_is_no_date(tmp_path):
    path = _jpeg_with_exif(tmp_path / "dji_0001.jpg", original="0000:00:00 00:00:00")
    with pytest.raises(CliffTerrainError, match=r"no date for '.*dji_0001\.jpg'.*--dates .*dji_0001\.jpg="):
        photo_date(path)


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        ("20180815_Lamberton_clipped.tif", dt.date(2018, 8, 15)),
        ("field-2018-09-14.tif", dt.date(2018, 9, 14)),
        ("IMG_12345678_20180917.tif", dt.date(2018, 9, 17)),  # 12345678 is no date
        ("201808150.tif", None),  # nine digits: part of a longer number
        ("2018-0815.tif", None),  # mixed separators
    ],
)
def test_date_in_name(name, expected):
    assert date_in_name(name) == expected


@pytest.mark.parametrize(
    ("item", "message"),
    [
        ("2018-08-15", "must be NAME=YYYY-MM-DD, got '2018-08-15'"),
        ("a.tif=15/08/2018", "'15/08/2018' is not a date"),
    ],
)
def test_bad_dates_option(item, message):
    with pytest.raises(CliffTerrainError, match=message):
        parse_given_dates([item])


def test_cache_key_follows_content_params_and_version(tmp_path):
    a, b = tmp_path / "a.bin", tmp_path / "b.bin"
    a.write_bytes(b"one flight")
    b.write_bytes(b"one flight")
    assert file_hash(a) == hashlib.sha256(b"one flight").hexdigest()
    key = cache_key(image_hash=file_hash(a), params={"max_size": 1000}, version="0.1.0")
    assert key == cache_key(image_hash=file_hash(b), params={"max_size": 1000}, version="0.1.0")
    assert key != cache_key(image_hash=file_hash(a), params={"max_size": 999}, version="0.1.0")
    assert key != cache_key(image_hash=file_hash(a), params={"max_size": 1000}, version="0.1.1")
    b.write_bytes(b"another flight")
    assert key != cache_key(image_hash=file_hash(b), params={"max_size": 1000}, version="0.1.0")

    cache = Cache(tmp_path / "cache")
    assert not cache.has(key)
    heights = np.arange(6, dtype=np.float32).reshape(2, 3)
    cache.store(key, {"ok": True, "rows": [1, 2]}, {"heights": heights})
    assert cache.has(key)
    assert cache.load_record(key) == {"ok": True, "rows": [1, 2]}
    np.testing.assert_array_equal(cache.load_arrays(key)["heights"], heights)
    # Only the two entry files are left: the temporary files were renamed into place.
    assert sorted(p.name for p in (tmp_path / "cache").iterdir()) == [f"{key}.json", f"{key}.npz"]


def test_each_photo_finds_its_dsm(tmp_path):
    from cliff_terrain.season.plan import find_images, pair_dsm

    photos, dsms = tmp_path / "photos", tmp_path / "dsm"
    photos.mkdir()
    dsms.mkdir()
    for name in ("20180815_rgb.tif", "20180822_rgb.tif"):
        (photos / name).write_bytes(b"")
    (dsms / "dsm_2018-08-15.tif").write_bytes(b"")
    (dsms / "20180822_rgb_dsm.tif").write_bytes(b"")
    images = find_images([photos])
    assert [Path(p).name for p in images] == ["20180815_rgb.tif", "20180822_rgb.tif"]
    paired = {Path(k).name: Path(v).name for k, v in pair_dsm(images, dsms).items()}
    assert paired == {"20180815_rgb.tif": "dsm_2018-08-15.tif", "20180822_rgb.tif": "20180822_rgb_dsm.tif"}
    with pytest.raises(CliffTerrainError, match=r"no DSM for '.*20180815_rgb\.tif'"):
        pair_dsm(images, str(dsms / "{stem}_dsm.tif"))
    with pytest.raises(CliffTerrainError, match="must be a folder or a pattern with \\{stem\\} for 2 images"):
        pair_dsm(images, str(dsms / "dsm_2018-08-15.tif"))
    (tmp_path / "empty").mkdir()
    with pytest.raises(CliffTerrainError, match="no images in folder"):
        find_images([tmp_path / "empty"])
