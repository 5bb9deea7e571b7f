"""quaternion_filter against an independent quaternion-by-quaternion evaluation of Sangwine's mask."""

import numpy as np
import pytest
import quaternion  # numpy-quaternion: Hamilton products, independent of the filter's linear form
from conftest import SHARED_UAV as UAV

from cliff_terrain.errors import CliffTerrainError
from cliff_terrain.photo_heights.quaternion import quaternion_filter

MU = quaternion.quaternion(0, 1, 1, 1) / np.sqrt(3)
SCALE = 1 / np.sqrt(6)  # Sangwine's choice, the documented default


def sangwine_masks(scale=SCALE, orientation="horizontal"):
    """Left mask [R R R; 0 0 0; R* R* R*] with R = scale * exp(mu pi/4); right mask its conjugate."""
    r = scale * np.exp(MU * np.pi / 4)
    zero = quaternion.quaternion(0, 0, 0, 0)
    left = np.array([[r, r, r], [zero, zero, zero], [r.conj()] * 3], dtype=np.quaternion)
    right = np.array([[q.conj() for q in row] for row in left], dtype=np.quaternion)
    if orientation == "vertical":
        left, right = left.T.copy(), right.T.copy()
    return left, right


def qtfm_conv2_same(image, left, right):
    """QTFM's conv2({left, right}, q), pixel by pixel, on the image reflected by one pixel (numpy's
    mode="reflect", the edge pixel not repeated), keeping the part the size of the input.

    QTFM accumulates C(a + i, b + j) += L(a, b) * B(i, j) * R(a, b), so the output pixel (r, c) of
    the padded image's full convolution, shifted by the mask's centre, reads B(r + 2 - a, c + 2 - b).
    """
    p = image.astype(np.float64) / 255.0 if image.dtype == np.uint8 else image.astype(np.float64)
    padded = quaternion.from_vector_part(np.pad(p, ((1, 1), (1, 1), (0, 0)), mode="reflect"))
    rows, cols = p.shape[:2]
    out = np.zeros((rows, cols, 3))
    for r in range(rows):
        for c in range(cols):
            acc = quaternion.quaternion(0, 0, 0, 0)
            for a in range(3):
                for b in range(3):
                    acc += left[a, b] * padded[r + 2 - a, c + 2 - b] * right[a, b]
            out[r, c] = quaternion.as_vector_part(acc)
    return out


def reference(image, scale=SCALE, orientation="horizontal"):
    return qtfm_conv2_same(image, *sangwine_masks(scale, orientation))


@pytest.fixture
def rng():
    return np.random.default_rng(20240611)


@pytest.mark.parametrize("orientation", ["horizontal", "vertical"])
@pytest.mark.parametrize("shape", [(1, 1), (1, 6), (5, 1), (2, 2), (7, 9), (13, 4)])
def test_uint8_matches_quaternion_convolution(rng, shape, orientation):
    image = rng.integers(0, 256, shape + (3,), dtype=np.uint8)
    out = quaternion_filter(image, orientation=orientation)
    assert out.dtype == np.float32 and out.shape == shape + (3,)
    np.testing.assert_allclose(out, reference(image, orientation=orientation), rtol=0, atol=1e-5)


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.float16, np.dtype(">f8")])
@pytest.mark.parametrize("orientation", ["horizontal", "vertical"])
def test_float_taken_as_is_with_other_scale(rng, dtype, orientation):
    # Values beyond [0, 1] and negative ones: float input is not rescaled.
    image = (rng.uniform(-0.5, 2.0, (9, 11, 3))).astype(dtype)
    out = quaternion_filter(image, scale=0.8, orientation=orientation)
    expected = reference(image, scale=0.8, orientation=orientation)
    np.testing.assert_allclose(out, expected, rtol=0, atol=1e-5 * max(1.0, np.abs(expected).max()))


@pytest.mark.parametrize("orientation", ["horizontal", "vertical"])
def test_threaded_strips_match_quaternion_convolution(rng, orientation):
    # Large enough for two threads and many strips in each; the reference is the same sum as in
    # qtfm_conv2_same, done on whole quaternion arrays one tap at a time to keep it fast.
    image = rng.integers(0, 256, (731, 730, 3), dtype=np.uint8)
    left, right = sangwine_masks(orientation=orientation)
    padded = quaternion.from_vector_part(np.pad(image / 255.0, ((1, 1), (1, 1), (0, 0)), mode="reflect"))
    acc = np.zeros(image.shape[:2], dtype=np.quaternion)
    for a in range(3):
        for b in range(3):
            acc += left[a, b] * padded[2 - a : 2 - a + 731, 2 - b : 2 - b + 730] * right[a, b]
    out = quaternion_filter(image, orientation=orientation)
    np.testing.assert_allclose(out, quaternion.as_vector_part(acc), rtol=0, atol=1e-5)


def test_vertical_is_horizontal_on_the_transposed_image(rng):
    image = rng.integers(0, 256, (40, 23, 3), dtype=np.uint8)
    transposed = np.ascontiguousarray(image.transpose(1, 0, 2))
    np.testing.assert_allclose(
        quaternion_filter(image, orientation="vertical"),
        quaternion_filter(transposed).transpose(1, 0, 2),
        rtol=0,
        atol=1e-6,
    )


@pytest.mark.parametrize("orientation", ["horizontal", "vertical"])
@pytest.mark.parametrize("colour", [(200, 40, 90), (0, 0, 0), (255, 255, 255), (7, 130, 255)])
def test_uniform_colour_maps_to_its_grey_everywhere(colour, orientation):
    image = np.empty((6, 8, 3), np.uint8)
    image[:] = colour
    out = quaternion_filter(image, orientation=orientation)
    grey = sum(colour) / 3 / 255
    np.testing.assert_allclose(out, np.full(out.shape, grey), rtol=0, atol=1e-6)


@pytest.mark.parametrize("orientation", ["horizontal", "vertical"])
def test_black_white_edge_stays_grey(orientation):
    image = np.zeros((8, 8, 3), np.uint8)
    if orientation == "horizontal":
        image[4:] = 255  # the mask compares rows: black above white
    else:
        image[:, 4:] = 255
    out = quaternion_filter(image, orientation=orientation)
    np.testing.assert_allclose(out[..., 0], out[..., 1], atol=1e-6)
    np.testing.assert_allclose(out[..., 1], out[..., 2], atol=1e-6)
    # Not trivially so: the edge is there, at half the white level, between black and white.
    line = out[:, 0, 0] if orientation == "horizontal" else out[0, :, 0]
    np.testing.assert_allclose(line, [0, 0, 0, 0.5, 0.5, 1, 1, 1], atol=1e-6)


def test_red_green_edge_turns_coloured():
    image = np.zeros((8, 6, 3), np.uint8)
    image[:4, :, 0] = 255  # red above green
    image[4:, :, 1] = 255
    out = quaternion_filter(image)
    spread = out.max(axis=2) - out.min(axis=2)
    assert np.all(spread[3:5] > 0.8)  # the two rows touching the edge are strongly coloured
    assert np.all(spread[[0, 1, 6, 7]] < 1e-6)  # uniform red or green: grey
    np.testing.assert_allclose(out[0], 1 / 3, atol=1e-6)


def test_true_convolution_not_correlation():
    """The mask is flipped: its Rq row meets the row below. A correlation flips the edge's hue."""
    image = np.zeros((6, 5, 3), np.uint8)
    image[:3, :, 0] = 255
    image[3:, :, 1] = 255
    left, right = sangwine_masks()
    convolution = qtfm_conv2_same(image, left, right)
    correlation = qtfm_conv2_same(image, left[::-1, ::-1], right[::-1, ::-1])
    out = quaternion_filter(image)
    np.testing.assert_allclose(out, convolution, rtol=0, atol=1e-5)
    assert np.abs(out - correlation).max() > 0.5
    # Red over green: blue under convolution (yellow under correlation).
    assert np.all(out[2:4, :, 2] > 0.9) and np.all(out[2:4, :, :2] < 0.05)
    assert np.all(correlation[2:4, :, :2] > 0.6) and np.all(correlation[2:4, :, 2] < 0)


def test_non_contiguous_input(rng):
    image = rng.integers(0, 256, (12, 10, 3), dtype=np.uint8)
    bgr_view = image[:, ::-1, ::-1]
    np.testing.assert_array_equal(quaternion_filter(bgr_view), quaternion_filter(bgr_view.copy()))


def test_input_not_modified(rng):
    image = rng.uniform(0, 1, (5, 7, 3))
    before = image.copy()
    quaternion_filter(image, orientation="vertical")
    np.testing.assert_array_equal(image, before)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"image": [[[0, 0, 0]]]}, "`image` must be a numpy array, got list"),
        ({"image": np.zeros((4, 4), np.uint8)}, r"`image` must have shape \(rows, cols, 3\), got \(4, 4\)"),
        ({"image": np.zeros((4, 4, 4), np.uint8)}, r"`image` must have shape \(rows, cols, 3\)"),
        ({"image": np.zeros((0, 4, 3), np.uint8)}, "`image` must be at least 1x1 pixels, got 0x4"),
        (
            {"image": np.zeros((4, 4, 3), np.int16)},
            "`image` must be uint8 or floating point, got dtype int16",
        ),
        ({"image": np.full((4, 4, 3), np.nan)}, "`image` must hold finite values"),
        ({"scale": 0}, "`scale` must be > 0.0, got 0.0"),
        ({"scale": -0.5}, "`scale` must be > 0.0, got -0.5"),
        ({"scale": float("nan")}, "`scale` must be finite, got nan"),
        ({"scale": "big"}, "`scale` must be a number, got 'big'"),
        (
            {"orientation": "diagonal"},
            "`orientation` must be one of 'horizontal', 'vertical', got 'diagonal'",
        ),
        ({"orientation": None}, "`orientation` must be one of .*, got None"),
    ],
)
def test_bad_arguments(kwargs, match):
    kwargs = {"image": np.zeros((4, 4, 3), np.uint8), **kwargs}
    image = kwargs.pop("image")
    with pytest.raises(CliffTerrainError, match=match):
        quaternion_filter(image, **kwargs)


@pytest.mark.skipif(not UAV.is_dir(), reason=f"real UAV images not found at {UAV} (../shared is absent)")
@pytest.mark.parametrize("orientation", ["horizontal", "vertical"])
def test_real_uav_crop_matches_quaternion_convolution(orientation):
    from PIL import Image

    path = UAV / "broccoli" / "01_clip_raw_test.jpg"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    with Image.open(path) as im:
        # A 64x64 crop across broccoli, ridge and furrow.
        crop = np.asarray(im.convert("RGB"))[700:764, 900:964]
    assert crop.std() > 10  # real texture, not a flat patch
    out = quaternion_filter(crop, orientation=orientation)
    np.testing.assert_allclose(out, reference(crop, orientation=orientation), rtol=0, atol=1e-5)
