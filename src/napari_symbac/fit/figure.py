"""A before/after figure of a fit that can be read: upscaled panels, titles, colour bar.

Drawn with numpy and Pillow (a dependency of imageio), so the core needs no matplotlib.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from napari_symbac.figure_layout import grey, panel_scale, upscale

__all__ = ["before_after_figure"]

_TITLE_PX = 28
_GAP_PX = 8
_BAR_PX = 18
_BAR_TEXT_PX = 78
_FONT_PX = 16


def _diverging(values: np.ndarray, limit: float) -> np.ndarray:
    """Blue (negative) - white (0) - red (positive), saturating at +-limit."""
    t = np.clip(np.asarray(values, np.float64) / max(limit, 1e-12), -1, 1)
    pos, neg = np.clip(t, 0, 1), np.clip(-t, 0, 1)
    red = 1 - 0.75 * neg
    green = 1 - 0.75 * (pos + neg)
    blue = 1 - 0.75 * pos
    return (255 * np.stack([red, green, blue], axis=-1)).astype(np.uint8)


def before_after_figure(
    real: np.ndarray,
    fitted: np.ndarray,
    residual: np.ndarray,
    start: np.ndarray | None = None,
    *,
    titles: Sequence[str] | None = None,
    residual_unit: str = "ADU",
) -> np.ndarray:
    """Real image, start, fit and residual side by side, as an RGB uint8 array.

    The real, start and fitted panels share one grey scale (the real image's 0.5th to
    99.5th percentiles); the residual ``real - fit`` is blue (fit too bright) to red
    (fit too dark), symmetric about zero at its 99th percentile of ``|residual|``, with
    a labelled colour bar. Panels are upscaled by whole pixels (nearest neighbour) so a
    thin trench is readable; tall panels sit side by side, wide ones in two columns.

    Parameters
    ----------
    real, fitted, residual
        2D arrays of one shape (ADU).
    start
        The model before fitting (``SceneFit.synthetic_before``); left out when ``None``.
    titles
        Panel titles; default "real", "start", "fit", "residual (real - fit)".
    residual_unit
        Unit printed on the colour bar.

    Returns
    -------
    numpy.ndarray
        ``(H, W, 3)`` uint8.
    """
    from PIL import Image, ImageDraw, ImageFont

    images = [real] + ([] if start is None else [start]) + [fitted]
    shape = np.shape(real)
    if any(np.shape(a) != shape for a in [*images, residual]) or len(shape) != 2:
        raise ValueError("real, start, fitted and residual must be 2D arrays of one shape")
    if titles is None:
        titles = ["real"] + ([] if start is None else ["start"]) + ["fit", "residual (real - fit)"]
    low, high = np.percentile(np.asarray(real, np.float64), [0.5, 99.5])
    limit = float(np.percentile(np.abs(residual), 99.0)) or 1.0
    scale = panel_scale(shape)
    panels = [upscale(grey(a, low, high), scale) for a in images]
    panels.append(upscale(_diverging(residual, limit), scale))
    height, width = panels[0].shape[:2]
    # Tall panels (a trench) side by side; wide ones (a field) in two columns.
    columns = len(panels) if height >= width else 2
    rows = math.ceil(len(panels) / columns)
    cell_h, cell_w = _TITLE_PX + height + _GAP_PX, width + _GAP_PX
    bar_x = columns * cell_w
    font = ImageFont.load_default(size=_FONT_PX)
    # whole numbers above 1000 ADU (found as a user: "+1.26e+04" was cut off at the edge)
    ticks = [(v, f"{v:+.3g}" if abs(v) < 1000 else f"{v:+,.0f}") for v in (limit, 0.0, -limit)]
    text_px = max(_BAR_TEXT_PX, 8 + max(math.ceil(font.getlength(t)) for _, t in ticks))
    canvas = np.full((rows * cell_h, bar_x + _BAR_PX + text_px, 3), 255, np.uint8)
    origins = [(cell_h * (i // columns), cell_w * (i % columns)) for i in range(len(panels))]
    for (y, x), panel in zip(origins, panels, strict=True):
        canvas[y + _TITLE_PX : y + _TITLE_PX + height, x : x + width] = panel
    bar_y = origins[-1][0] + _TITLE_PX  # beside the residual's row
    ramp = np.linspace(limit, -limit, height)[:, None] * np.ones((1, _BAR_PX))
    canvas[bar_y : bar_y + height, bar_x : bar_x + _BAR_PX] = _diverging(ramp, limit)

    picture = Image.fromarray(canvas)
    draw = ImageDraw.Draw(picture)
    for (y, x), title in zip(origins, titles, strict=False):
        draw.text((x + 2, y + 4), title, fill=(0, 0, 0), font=font)
    for (_, text), row in zip(ticks, (0, height // 2, height - 1), strict=True):
        y = bar_y + min(max(row - _FONT_PX // 2, 0), height - _FONT_PX)
        draw.text((bar_x + _BAR_PX + 4, y), text, fill=(0, 0, 0), font=font)
    draw.text((bar_x, bar_y - _TITLE_PX + 4), residual_unit, fill=(0, 0, 0), font=font)
    return np.asarray(picture)
