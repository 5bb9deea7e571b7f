"""``ruler.png``: each plot's height from the DSM against the breeder's ruler, with the agreement (Pillow only).

A scatter of ``height_p90_m`` (and, with ``--calibrate``, the calibrated height) against the
measured height, the 1:1 line, each point's standard error as a vertical bar, and r, RMSE, bias
and Lin's CCC written above: what a breeder checks before trusting a trial's numbers.
"""

from __future__ import annotations

import numpy as np

from .drawing import GRID, INK, PAPER, load_font, text_size
from .legends import format_value, nice_step

OURS = (31, 119, 180)
CALIBRATED = (214, 39, 40)


def ruler_figure(
    ours, measured, *, err=None, agreement, calibrated=None, calibration=None, calibrated_err=None, size=720
):
    """The chart as an RGB Pillow image of `size` x `size` pixels.

    Parameters
    ----------
    ours, measured : (n,) float arrays
        Heights in metres per plot (NaN where a plot has none): the DSM's and the ruler's.
    err : (n,) float array, optional
        The standard error of `ours` (drawn as +-1 bars).
    agreement : dict
        :func:`cliff_terrain.measure.ruler.agreement` of `ours` against `measured`.
    calibrated : (n,) float array, optional
        The calibrated heights, drawn in red, with `calibration`
        (:func:`cliff_terrain.measure.ruler.calibrate`) in the title.
    calibrated_err : (n,) float array, optional
        The standard error of `calibrated` (drawn as +-1 bars).

    The third line says how many plots each uncertainty covers (``coverage``: within 1.645 standard
    errors; the calibration's by leave-one-out).

    Examples
    --------
    >>> from cliff_terrain.measure.ruler import agreement
    >>> x = np.array([0.5, 0.6, 0.7, 0.8]); y = x + 0.1
    >>> ruler_figure(x, y, agreement=agreement(x, y)).size
    (720, 720)
    """
    from PIL import Image, ImageDraw

    ours = np.asarray(ours, np.float64)
    measured = np.asarray(measured, np.float64)
    image = Image.new("RGB", (size, size), PAPER)
    draw = ImageDraw.Draw(image)
    font = load_font(max(12, size // 40))
    small = load_font(max(11, size // 50))
    both = np.isfinite(ours) & np.isfinite(measured)
    values = [ours[both], measured[both]]
    if calibrated is not None:
        values.append(np.asarray(calibrated, np.float64)[both])
    pool = np.concatenate(values) * 100 if both.any() else np.array([0.0, 100.0])
    pool = pool[np.isfinite(pool)]
    low, high = float(pool.min()), float(pool.max())
    step = nice_step(max(high - low, 1.0))
    low, high = step * np.floor(low / step), step * np.ceil(high / step)
    left, top, right, bottom = size * 0.14, size * 0.2, size * 0.95, size * 0.86

    def xy(x_cm, y_cm):
        fx = (x_cm - low) / (high - low)
        fy = (y_cm - low) / (high - low)
        return left + fx * (right - left), bottom - fy * (bottom - top)

    for tick in np.arange(low, high + step / 2, step):
        x, _ = xy(tick, low)
        _, y = xy(low, tick)
        draw.line((x, top, x, bottom), fill=GRID)
        draw.line((left, y, right, y), fill=GRID)
        label = format_value(tick, step)
        draw.text((x, bottom + 4), label, font=small, fill=INK, anchor="ma")
        draw.text((left - 6, y), label, font=small, fill=INK, anchor="rm")
    draw.line((*xy(low, low), *xy(high, high)), fill=INK, width=1)  # 1:1
    draw.rectangle((left, top, right, bottom), outline=INK)
    radius = max(2, size // 180)
    series = [(ours, OURS)]
    if calibrated is not None:
        series.append((np.asarray(calibrated, np.float64), CALIBRATED))
    bars = [err, None if calibrated is None else calibrated_err]
    for (heights, colour), sd in zip(series, bars, strict=False):
        sd = None if sd is None else np.asarray(sd, np.float64)
        for i in np.flatnonzero(both & np.isfinite(heights)):
            x, y = xy(measured[i] * 100, heights[i] * 100)
            if sd is not None and np.isfinite(sd[i]):
                _, y0 = xy(measured[i] * 100, (heights[i] - sd[i]) * 100)
                _, y1 = xy(measured[i] * 100, (heights[i] + sd[i]) * 100)
                draw.line((x, y0, x, y1), fill=colour)
            draw.ellipse((x - radius, y - radius, x + radius, y + radius), fill=colour)
    draw.text(((left + right) / 2, size - 6), "ruler height (cm)", font=font, fill=INK, anchor="md")
    label = "DSM height p90 (cm)"
    w, h = text_size(draw, label, font)
    rotated = Image.new("RGB", (w + 4, h + 8), PAPER)
    ImageDraw.Draw(rotated).text((2, 2), label, font=font, fill=INK)
    rotated = rotated.rotate(90, expand=True)
    image.paste(rotated, (4, int((top + bottom) / 2 - rotated.size[1] / 2)))

    def line(a, name):
        if a.get("r") is None:
            return f"{name}: too few plots to compare ({a.get('n', 0)})"
        return (
            f"{name}: {a['n']} plots, r {a['r']:.2f}, RMSE {a['rmse_m'] * 100:.1f} cm, "
            f"bias {a['bias_m'] * 100:+.1f} cm, CCC {a['ccc']:.2f}"
        )

    draw.text(
        (size * 0.04, size * 0.03), line(agreement, "DSM height against the ruler"), font=font, fill=OURS
    )
    if calibration is not None:
        text = (
            f"calibrated {calibration['a_m'] * 100:+.1f} cm + {calibration['b']:.2f} x DSM: "
            f"leave-one-out RMSE {calibration['loo_rmse_m'] * 100:.1f} cm"
        )
        draw.text((size * 0.04, size * 0.03 + font.size * 1.5), text, font=font, fill=CALIBRATED)
    covers = []
    if agreement.get("coverage") is not None:
        covers.append(f"DSM {agreement['coverage']:.0%}")
    if calibration is not None and calibration.get("coverage") is not None:
        covers.append(f"calibrated {calibration['coverage']:.0%} (leave-one-out)")
    legend = "black: 1:1; bars +-1 s.e."
    if covers:
        legend += "; within 1.645 s.e. of the ruler: " + ", ".join(covers)
    draw.text((size * 0.04, size * 0.03 + font.size * 3.0), legend, font=small, fill=INK)
    return image


def plot_rows_ruler_figure(rows, record):
    """ruler.png from a plot table's rows (``height_p90_m``, ``ruler_height_m``, ``height_p90_err_m``
    and, calibrated, ``height_calibrated_m`` and ``height_calibrated_err_m``) and the ruler's record
    (:func:`cliff_terrain.measure.ruler.ruler_columns`): :func:`ruler_figure`."""

    def column(name):
        return np.array([float(r.get(name, "nan")) for r in rows])

    calibrated = column("height_calibrated_m") if "calibration" in record else None
    calibrated_err = column("height_calibrated_err_m") if "calibration" in record else None
    return ruler_figure(
        column("height_p90_m"),
        column("ruler_height_m"),
        err=column("height_p90_err_m"),
        agreement=record["height_p90_m"],
        calibrated=calibrated,
        calibration=record.get("calibration"),
        calibrated_err=calibrated_err,
    )
