"""bench/validate_real.py on a small data folder made here: masks scored, and a field whose second flight
is tilted against the first (as two real flights without ground control were) scored against both the
raw and the aligned difference."""

from __future__ import annotations

import importlib.util
import json

import numpy as np
import pytest
from conftest import REPO
from PIL import Image
from test_measured_heights import FIELD_TRANSFORM, UTM16N, write_synthetic_pair

from cliff_terrain.data.synthetic import synthetic_field
from cliff_terrain.io.geotiff import write_geotiff


@pytest.fixture(scope="module")
def validate():
    spec = importlib.util.spec_from_file_location("validate_real", REPO / "bench" / "validate_real.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_stable_alignment_recovers_a_tilt_between_flights(validate):
    rows, cols = np.mgrid[:120, :200]
    tilt = (0.25 * rows / 120 - 0.1 * cols / 200).astype(np.float32)
    difference = tilt.copy()
    plots = (rows % 40 > 10) & (cols % 50 > 10)
    difference[plots] += 0.6  # plants stand on the plots only
    outside = ~plots
    difference[outside & (rows % 7 == 0) & (cols % 5 == 0)] += 0.4  # a few weeds outside the plots
    aligned = difference - validate.stable_alignment(difference, outside)
    assert np.abs(aligned[outside & (difference - tilt < 0.1)]).max() < 1e-3
    assert np.median(aligned[plots]) == pytest.approx(0.6, abs=1e-3)


def test_validate_real_scores_masks_and_a_tilted_second_flight(validate, tmp_path):
    data = tmp_path / "data"
    # Two photos with their annotated masks.
    masks = data / "masks" / "synthetic"
    masks.mkdir(parents=True)
    for seed in (0, 1):
        image, truth = synthetic_field(shape=(160, 200), seed=seed)
        Image.fromarray(image).save(masks / f"field{seed}.png")
        Image.fromarray(truth.mask.astype(np.uint8) * 255).save(masks / f"field{seed}_mask.png")
    # A field: the early flight is the bare ground tilted by up to 20 cm; the later one the surface.
    field = data / "fields" / "trial"
    field.mkdir(parents=True)
    truth = write_synthetic_pair(field, dsm_name="late.tif")
    t = FIELD_TRANSFORM
    rows, cols = np.mgrid[:300, :450]
    early = truth.ground - 0.2 * cols / 450  # the first flight stands lower towards the east
    write_geotiff(field / "early.tif", early.astype(np.float32), transform=t, crs=UTM16N)
    features = []
    for k, (x, y) in enumerate([(1.0, 1.0), (4.0, 1.0), (1.0, 3.5), (5.0, 3.5)]):
        ring = [[500000 + x, 4000000 - y], [500002.5 + x, 4000000 - y], [500002.5 + x, 4000000 - y - 1.5]]
        ring += [[500000 + x, 4000000 - y - 1.5], [500000 + x, 4000000 - y]]
        features.append(
            {
                "type": "Feature",
                "properties": {"id": k},
                "geometry": {"type": "Polygon", "coordinates": [ring]},
            }
        )
    crs = {"type": "name", "properties": {"name": "EPSG:32616"}}
    (field / "plots.geojson").write_text(
        json.dumps({"type": "FeatureCollection", "crs": crs, "features": features})
    )
    spec = {
        "plots": "plots.geojson",
        "reference": "early.tif",
        "dates": {"60": {"ortho": "ortho.tif", "dsm": "late.tif"}},
        "holdout": ["60"],
    }
    (field / "field.json").write_text(json.dumps(spec))

    record = validate.main([str(data), "--json", str(tmp_path / "out.json")])
    images = record["images"]
    assert [row["half"] for row in images] == ["tune", "holdout"]
    assert all(row["iou"] > 0.85 and row["volume_on_plants"] > 0.9 for row in images)
    assert json.loads((tmp_path / "out.json").read_text())["summary"]["synthetic/holdout"]["images"] == 1
    (row,) = record["fields"]
    assert row["half"] == "holdout" and row["plots"] == 4
    # The tilt makes the raw difference taller than the plants by up to 20 cm; aligned, ours agrees.
    raw, aligned = row["against"]["raw"], row["against"]["aligned"]
    assert raw["ours"]["bias_cm"] < -5.0
    assert abs(aligned["ours"]["bias_cm"]) < 3.0 and aligned["ours"]["rmse_cm"] < 4.0
    # The peers run on the same grid in the same run; ours beats the naive baseline here.
    assert aligned["baseline"]["rmse_cm"] > aligned["ours"]["rmse_cm"]
    assert aligned["plantcv"]["n"] == aligned["ours"]["n"] == 4
    assert row["ground_method"] in ("baseline", "smooth", "detailed") and 0 <= aligned["coverage"] <= 1
