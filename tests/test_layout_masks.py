"""bench/layout_masks.py's converters: a source's annotation format into the layout's plant mask."""

from __future__ import annotations

import pytest
from conftest import REPO, load_script


@pytest.fixture(scope="module")
def layout():
    return load_script(REPO / "bench" / "layout_masks.py", "layout_masks")


def test_yolo_polygons_fill_every_class_and_skip_degenerate_lines(layout):
    # A crop square (class 0) and a weed triangle (class 1) in a 100 x 50 (width x height) frame.
    text = "0 0.1 0.2 0.3 0.2 0.3 0.6 0.1 0.6\n1 0.6 0.2 0.9 0.2 0.75 0.8\n1 0.5 0.5 0.6 0.6\n\n"
    mask = layout.yolo_polygons_mask(text, (100, 50))
    assert mask.shape == (50, 100)
    assert mask[10:30, 10:30].all() and not mask[35:, :55].any()
    square = mask[:, :50].sum()
    assert square == pytest.approx(21 * 21, abs=2)  # 20 x 20 plus the outline PIL draws
    triangle = mask[:, 55:].sum()
    assert triangle == pytest.approx(0.5 * 30 * 30, rel=0.1)
    assert not mask[24:26, 49:56].any()  # the two-point line is no polygon


def test_spread_keeps_the_ends_and_spaces_the_rest(layout):
    names = [f"{k:03d}" for k in range(10)]
    assert layout.spread(names, 4) == ["000", "003", "006", "009"]
    assert layout.spread(names, 20) == names


def test_stover_frames_keep_plants_among_residue_only(layout):
    table = (
        "name,label,train,val,test,true_soil,true_plant,true_residue,pred_soil,pred_plant,pred_residue\n"
        "image_0001.jpg,label_0001.png,True,False,False,69.59,14.52,15.89,69.92,14.24,15.84\n"
        "image_0002.jpg,label_0002.png,True,False,False,98.00,1.00,1.00,98.0,1.0,1.0\n"  # 1 %: not more
        "image_0003.jpg,label_0003.png,True,False,False,0.00,85.00,15.00,0.0,85.0,15.0\n"
        "image_0004.jpg,label_0004.png,True,False,False,5.00,90.00,5.00,5.0,90.0,5.0\n"  # little residue
        "image_0005.jpg,label_0005.png,True,False,False,0.00,0.50,99.50,0.0,0.5,99.5\n"  # no plants
        "image_0006.jpg,label_0006.png,True,False,False,80.00,10.00,10.00,80.0,10.0,10.0\n"  # 10 %: not more
    )
    frames = layout.stover_frames(table)
    assert sorted(frames) == ["image_0001.jpg", "image_0003.jpg"]
    assert frames["image_0003.jpg"]["label"] == "label_0003.png"
