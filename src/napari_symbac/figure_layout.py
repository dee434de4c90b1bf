"""PNG figures laid out with numpy and Pillow (no plotting library needed).

Titled panels on a white page, colour bars with their unit, line plots with labelled
axes, wrapped text and headings: what ``napari-symbac diagnose`` (``residuals.png``,
``effect_<name>.png``) and ``napari-symbac calibrate`` (``report.png``) draw with. Small
maps are enlarged by whole pixels (nearest neighbour, as
:func:`napari_symbac.fit.figure.before_after_figure` does); text is Pillow's bundled
font, so the same input gives the same PNG bytes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

__all__ = [
    "FONT_PX",
    "HEADING_PX",
    "ColourBar",
    "diverging",
    "grey",
    "line_plot",
    "map_body",
    "map_scale",
    "panel_scale",
    "text_block",
    "titled_grid",
    "upscale",
    "with_heading",
]

FONT_PX = 16
HEADING_PX = 20
_PAD = 10
_BAR_PX = 18
_BLACK = (0, 0, 0)
_WHITE = (255, 255, 255)


def _font(size: int = FONT_PX):
    from PIL import ImageFont

    return ImageFont.load_default(size=size)


def _line_px(size: int) -> int:
    return round(1.3 * size)


def diverging(image: np.ndarray, limit: float) -> np.ndarray:
    """Blue-white-red RGB (uint8) of ``image`` clipped to ``[-limit, limit]``."""
    t = np.clip(np.asarray(image, float) / max(limit, 1e-12), -1, 1)
    r = np.where(t > 0, 1.0, 1.0 + t)
    b = np.where(t < 0, 1.0, 1.0 - t)
    g = 1.0 - np.abs(t)
    return (np.stack([r, g, b], axis=-1) * 255).astype(np.uint8)


def grey(image: np.ndarray, low: float | None = None, high: float | None = None) -> np.ndarray:
    """Grey RGB (uint8) from ``low`` to ``high`` (default the 0.5th to 99.5th percentiles)."""
    image = np.asarray(image, float)
    if low is None or high is None:
        low, high = np.percentile(image, (0.5, 99.5))
    t = np.clip((image - low) / max(high - low, 1e-12), 0, 1)
    return np.repeat((t * 255).astype(np.uint8)[..., None], 3, axis=-1)


def panel_scale(shape: tuple[int, int], *, min_side_px: int = 200, max_side_px: int = 1200) -> int:
    """Integer upscaling so a panel's short side reaches ``min_side_px`` (long side capped)."""
    short, long = min(shape), max(shape)
    up = math.ceil(min_side_px / short)
    cap = max(1, max_side_px // long)
    return max(1, min(up, cap))


def map_scale(shape: tuple[int, int], *, min_long_px: int = 400) -> int:
    """Whole-pixel enlargement of a map: :func:`panel_scale`
    (short side to 200 px, long side at most 1200 px), and the long side at least
    ``min_long_px`` where that cap allows."""
    long = max(shape)
    cap = max(1, 1200 // long)
    return max(panel_scale(shape), min(math.ceil(min_long_px / long), cap))


def upscale(rgb: np.ndarray, factor: int) -> np.ndarray:
    return np.repeat(np.repeat(rgb, factor, axis=0), factor, axis=1)


def _wrap(text: str, font, width: float) -> list[str]:
    lines: list[str] = []
    for paragraph in text.split("\n"):
        line = ""
        for word in paragraph.split():
            trial = f"{line} {word}" if line else word
            if line and font.getlength(trial) > width:
                lines.append(line)
                line = word
            else:
                line = trial
        lines.append(line)
    return lines


def text_block(text: str, width: int, size: int = FONT_PX) -> np.ndarray:
    """White RGB strip, at least ``width`` px wide, with ``text`` wrapped to it."""
    from PIL import Image, ImageDraw

    font = _font(size)
    longest = max((font.getlength(w) for w in text.split()), default=0.0)
    width = max(int(width), math.ceil(longest) + 2)
    lines = _wrap(text, font, width)
    step = _line_px(size)
    picture = Image.new("RGB", (width, step * len(lines) + 4), _WHITE)
    draw = ImageDraw.Draw(picture)
    for k, line in enumerate(lines):
        draw.text((0, 2 + k * step), line, fill=_BLACK, font=font)
    return np.asarray(picture)


def _pad_to(image: np.ndarray, height: int, width: int) -> np.ndarray:
    out = np.full((height, width, 3), 255, np.uint8)
    out[: image.shape[0], : image.shape[1]] = image
    return out


def _stack(parts: Sequence[np.ndarray], *, axis: int, gap: int = 0) -> np.ndarray:
    """Parts one below the other (``axis=0``) or side by side, top/left aligned."""
    height = max(p.shape[0] for p in parts) if axis == 1 else None
    width = max(p.shape[1] for p in parts) if axis == 0 else None
    out = []
    for p in parts:
        out.append(_pad_to(p, height or p.shape[0], width or p.shape[1]))
        shape = (gap, width, 3) if axis == 0 else (height, gap, 3)
        out.append(np.full(shape, 255, np.uint8))
    return np.concatenate(out[:-1], axis=axis)


class ColourBar:
    """A colour bar: ``"diverging"`` (symmetric about 0) or ``"grey"``, ``low`` to
    ``high`` in ``unit``."""

    def __init__(self, kind: str, low: float, high: float, unit: str) -> None:
        if kind not in ("diverging", "grey"):
            raise ValueError(f"colour bar kind {kind!r}: 'diverging' or 'grey'")
        self.kind, self.low, self.high, self.unit = kind, float(low), float(high), unit

    def colours(self, values: np.ndarray) -> np.ndarray:
        if self.kind == "diverging":
            return diverging(values, max(abs(self.low), abs(self.high)))
        return grey(values, self.low, self.high)


def _colour_bar(bar: ColourBar, height: int, top: int) -> np.ndarray:
    """The bar ``height`` px tall starting ``top`` px down (the unit above it), with
    its top, middle and bottom values written beside it."""
    from PIL import Image, ImageDraw

    font = _font()
    values = (bar.high, (bar.high + bar.low) / 2, bar.low)
    labels = [f"{v + 0.0:+.3g}" if bar.kind == "diverging" else f"{v + 0.0:.4g}" for v in values]
    label_w = math.ceil(max(font.getlength(s) for s in labels))
    width = max(_BAR_PX + 6 + label_w + 2, math.ceil(font.getlength(bar.unit)) + 2)
    canvas = np.full((top + height + FONT_PX, width, 3), 255, np.uint8)
    ramp = np.linspace(bar.high, bar.low, height)[:, None] * np.ones((1, _BAR_PX))
    canvas[top : top + height, :_BAR_PX] = bar.colours(ramp)
    picture = Image.fromarray(canvas)
    draw = ImageDraw.Draw(picture)
    draw.rectangle((0, top, _BAR_PX - 1, top + height - 1), outline=_BLACK)
    draw.text((0, top - _line_px(FONT_PX) - FONT_PX // 2 + 2), bar.unit, fill=_BLACK, font=font)
    for label, row in zip(labels, (0, (height - 1) // 2, height - 1), strict=True):
        draw.line((_BAR_PX, top + row, _BAR_PX + 3, top + row), fill=_BLACK)
        draw.text((_BAR_PX + 6, top + row - FONT_PX // 2 - 2), label, fill=_BLACK, font=font)
    return np.asarray(picture)


def map_body(rgb: np.ndarray, bar: ColourBar | None = None) -> np.ndarray:
    """A map (already coloured and enlarged) with its colour bar to the right.

    Space for the bar's unit is kept above every map, with or without a bar, so maps
    titled side by side line up.
    """
    top = _line_px(FONT_PX) + FONT_PX // 2
    body = np.full((top + rgb.shape[0] + FONT_PX, rgb.shape[1], 3), 255, np.uint8)
    body[top : top + rgb.shape[0]] = rgb
    if bar is None:
        return body
    return _stack([body, _colour_bar(bar, rgb.shape[0], top)], axis=1, gap=6)


def titled_grid(
    items: Sequence[tuple[str, np.ndarray]], columns: int, *, min_title_px: int = 200
) -> np.ndarray:
    """Panels ``(title, body)`` in rows of ``columns``, each under its wrapped title.

    Titles in a row are padded to one height and panels in a column to one width, so
    the bodies line up.
    """
    columns = max(1, min(columns, len(items)))
    titles = [text_block(t, max(b.shape[1], min_title_px)) for t, b in items]
    cells = [(t, b) for t, (_, b) in zip(titles, items, strict=True)]
    widths = [
        max(max(t.shape[1], b.shape[1]) for t, b in cells[c::columns]) for c in range(columns)
    ]
    rows = []
    for r in range(0, len(cells), columns):
        row = cells[r : r + columns]
        title_h = max(t.shape[0] for t, _ in row)
        body_h = max(b.shape[0] for _, b in row)
        rows.append(
            _stack(
                [
                    np.concatenate([_pad_to(t, title_h, w), _pad_to(b, body_h, w)])
                    for (t, b), w in zip(row, widths, strict=False)
                ],
                axis=1,
                gap=2 * _PAD,
            )
        )
    return _stack(rows, axis=0, gap=_PAD)


def with_heading(figure: np.ndarray, heading: str, note: str = "") -> np.ndarray:
    """``figure`` under a heading (20 px) and a note (16 px), with a white margin."""
    width = max(figure.shape[1], 480)
    parts = [text_block(heading, width, HEADING_PX)]
    if note:
        parts.append(text_block(note, width))
    parts.append(figure)
    body = _stack(parts, axis=0, gap=_PAD // 2)
    return np.pad(body, ((_PAD, _PAD), (_PAD, _PAD), (0, 0)), constant_values=255)


def _ticks(low: float, high: float, n: int = 5) -> np.ndarray:
    span = high - low if high > low else 1.0
    raw = span / n
    magnitude = 10.0 ** math.floor(math.log10(raw))
    step = next(m * magnitude for m in (1, 2, 2.5, 5, 10) if m * magnitude >= raw * 0.999)
    first = math.ceil(low / step - 1e-9) * step
    ticks = np.arange(first, high + step * 1e-6, step)
    return np.round(ticks / step) * step


def _tick_label(value: float) -> str:
    return f"{round(value, 10) + 0.0:.4g}"


def line_plot(
    values: np.ndarray,
    height: int = 260,
    width: int = 420,
    band: float | None = None,
    *,
    x: np.ndarray | None = None,
    xlabel: str = "",
    ylabel: str = "",
    reference: float = 0.0,
    faint: np.ndarray | None = None,
) -> np.ndarray:
    """A curve of ``values`` against ``x`` on labelled axes, as an RGB uint8 array.

    The plotting area is ``height`` x ``width`` px; tick values, ``xlabel`` below and
    ``ylabel`` (turned) at the left are drawn around it. ``reference`` (the value that
    means "as modelled") is a grey line, ``band`` a light grey ``reference +- band``,
    and ``faint`` (e.g. the unsmoothed values) a light grey curve under the black one.
    """
    from PIL import Image, ImageDraw

    font = _font()
    v = np.asarray(values, float)
    xs = np.arange(v.size, dtype=float) if x is None else np.asarray(x, float)
    shown = [v, [reference]] + ([] if faint is None else [np.asarray(faint, float)])
    if band:
        shown.append([reference - band, reference + band])
    finite = np.concatenate([np.ravel(s) for s in shown])
    finite = finite[np.isfinite(finite)]
    low, high = (float(finite.min()), float(finite.max())) if finite.size else (-1.0, 1.0)
    margin = 0.08 * (high - low) or max(abs(high), 1.0) * 0.1
    low, high = low - margin, high + margin
    x0, x1 = (float(xs.min()), float(xs.max())) if xs.size > 1 else (0.0, 1.0)
    if x1 <= x0:
        x1 = x0 + 1.0
    yticks, xticks = _ticks(low, high), _ticks(x0, x1)
    ylabels = [_tick_label(t) for t in yticks]
    left = math.ceil(max(font.getlength(s) for s in ylabels)) + _line_px(FONT_PX) + 12
    bottom = 2 * _line_px(FONT_PX) + 8
    canvas = Image.new("RGB", (left + width + 16, 8 + height + bottom), _WHITE)
    draw = ImageDraw.Draw(canvas)
    top = 8

    def px(xv: float) -> float:
        return left + (xv - x0) / (x1 - x0) * (width - 1)

    def py(yv: float) -> float:
        return top + (high - yv) / (high - low) * (height - 1)

    for t, label in zip(yticks, ylabels, strict=True):
        y = round(py(t))
        draw.line((left, y, left + width - 1, y), fill=(235, 235, 235))
        draw.line((left - 4, y, left, y), fill=_BLACK)
        lw = font.getlength(label)
        draw.text((left - 6 - lw, y - FONT_PX // 2 - 2), label, fill=_BLACK, font=font)
    for t in xticks:
        xx = round(px(t))
        draw.line((xx, top + height - 1, xx, top + height + 3), fill=_BLACK)
        label = _tick_label(t)
        draw.text((xx - font.getlength(label) / 2, top + height + 5), label, fill=_BLACK, font=font)
    if band:
        for yv in (reference - band, reference + band):
            draw.line((left, round(py(yv)), left + width - 1, round(py(yv))), fill=(200, 200, 200))
    yr = round(py(reference))
    draw.line((left, yr, left + width - 1, yr), fill=(140, 140, 140))

    def curve(ys: np.ndarray, colour: tuple[int, int, int], line_width: int) -> None:
        points = [(px(a), py(b)) for a, b in zip(xs, ys, strict=True) if np.isfinite(b)]
        if len(points) > 1:
            draw.line(points, fill=colour, width=line_width)
        if len(points) <= 30:
            for a, b in points:
                draw.ellipse((a - 3, b - 3, a + 3, b + 3), fill=colour)

    if faint is not None:
        curve(np.asarray(faint, float), (170, 170, 170), 1)
    curve(v, _BLACK, 2)
    draw.rectangle((left, top, left + width - 1, top + height - 1), outline=_BLACK)
    xl = font.getlength(xlabel)
    xy = (left + (width - xl) / 2, top + height + 8 + _line_px(FONT_PX))
    draw.text(xy, xlabel, fill=_BLACK, font=font)
    if ylabel:
        size = (math.ceil(font.getlength(ylabel)) + 2, _line_px(FONT_PX))
        turned = Image.new("RGB", size, _WHITE)
        ImageDraw.Draw(turned).text((0, 0), ylabel, fill=_BLACK, font=font)
        turned = turned.rotate(90, expand=True)
        ty = max(0, round(top + (height - turned.height) / 2))
        canvas.paste(turned, (2, ty))
    return np.asarray(canvas)
