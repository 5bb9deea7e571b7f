"""bench/bench_cuts.py on the tilted synthetic field of test_validate_real: each edge strip with its
headland and the plots' box, measured as a user would measure the cut, scored on the plots whole in
it against the whole field's aligned two-flight difference."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import REPO, load_script
from test_validate_real import make_tilted_field


@pytest.fixture(scope="module")
def cuts():
    return load_script(REPO / "bench" / "bench_cuts.py", "bench_cuts")


def test_the_cuts_are_the_edge_strips_with_their_headland_the_plots_box_and_the_quarters(cuts):
    labels = np.zeros((100, 200), np.int32)
    labels[20:40, 40:80] = 1
    labels[60:80, 120:160] = 2  # the plots span rows 20-80 and columns 40-160
    windows = cuts.cut_windows(labels, labels.shape)
    assert windows == {
        "west strip": (0, 100, 0, 40 + 30),
        "east strip": (0, 100, 160 - 30, 200),
        "north strip": (0, 20 + 15, 0, 200),
        "south strip": (80 - 15, 100, 0, 200),
        "plots' box": (20, 80, 40, 160),
        "north-west quarter": (0, 50, 0, 100),
        "north-east quarter": (0, 50, 100, 200),
        "south-west quarter": (50, 100, 0, 100),
        "south-east quarter": (50, 100, 100, 200),
        "plots' centre": (20 + 15, 80 - 15, 40 + 30, 160 - 30),
    }


def test_bench_cuts_measures_every_cut_against_the_whole_fields_reference(
    cuts, tmp_path, monkeypatch, capsys
):
    data = tmp_path / "data"
    make_tilted_field(data)
    # Half the plots' extent, so that each strip of this 9 m x 6 m field holds plots whole: the west
    # strip plots 0 and 2, the east plot 3, the north 0 and 1, the south 2 and 3.
    monkeypatch.setattr(cuts, "STRIP_SHARE", 0.5)
    assert cuts.main([str(data), "--json", str(tmp_path / "cuts.json")]) == 0
    records = json.loads((tmp_path / "cuts.json").read_text())
    plots = {r["cut"]: r["plots"] for r in records}
    # The quarters split at the plots' middle (x = 4.25 m), which plot 1 (4-6.5 m) straddles: the
    # north-east quarter holds no plot whole. The plots' centre, half their extent in from each side
    # at this share, is empty. Both are skipped.
    assert plots == {
        "west strip": 2, "east strip": 1, "north strip": 2, "south strip": 2, "plots' box": 4,
        "north-west quarter": 1, "south-west quarter": 1, "south-east quarter": 1,
    }  # fmt: skip
    for r in records:
        assert "refused" not in r, r
        # The early flight's tilt is aligned away: ours agrees in every cut, the baseline runs beside it.
        assert abs(r["ours_bias_cm"]) < 3.0 and r["ours_rmse_cm"] < 4.0, r
        assert np.isfinite(r["baseline_rmse_cm"]) and 0.0 <= r["coverage"] <= 1.0
        assert r["ground"] in ("baseline", "smooth", "detailed") and r["held_out_cm"] >= 0.0
    out = capsys.readouterr().out
    assert out.count("| trial | 60 |") == 8
    assert "8 cuts, 0 refused; ours' RMSE above the baseline's in" in out


def test_bench_cuts_needs_a_fields_folder(cuts, tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        cuts.main([str(tmp_path)])
    assert exit_info.value.code == 2
    assert "is not a folder" in capsys.readouterr().err
