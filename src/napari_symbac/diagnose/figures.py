"""PNG figures of a diagnosis.

``residuals.png`` shows the frame and the standardised residual of the base fit and of
the fit with the accepted effects; ``effect_<name>.png`` an accepted effect's map (the
change it makes to the model) beside the discrepancy profile of the base fit that
revealed it. Every panel is titled, every map has a colour bar with its unit, every
curve labelled axes, and each figure a heading naming the image or the effect; the
layout is :mod:`napari_symbac.figure_layout`'s (a 256 x 46 trench is drawn 1024 px
tall; the same diagnosis gives the same PNG bytes).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from scipy import ndimage

from napari_symbac.diagnose.run import RESIDUAL_SMOOTHING_PX
from napari_symbac.diagnose.statistics import significance_words
from napari_symbac.figure_layout import (
    ColourBar,
    diverging,
    grey,
    line_plot,
    map_body,
    map_scale,
    titled_grid,
    upscale,
    with_heading,
)

if TYPE_CHECKING:
    from napari_symbac.diagnose.run import Diagnosis

__all__ = ["REVEALING", "write_figures"]

#: The discrepancy statistic shown with each accepted effect (a key of ``Mismatch.where``;
#: ``None``: no profile shows what revealed it).
REVEALING = {
    "uneven_illumination": "along the field (rows)",
    "defocus_gradient": "along the field (rows)",
    "halo": "distance to the nearest cell edge",
    "stray_light": "distance to the nearest cell edge",
    "cell_curvature": "distance to the nearest cell edge",
    "camera_noise": "intensity level",
    "fixed_pattern_noise": "across the field (columns)",
    "background_texture": "across the field (columns)",
    # revealed by their own score tests (per-cell mean residuals; a spike of pixels at
    # the clip level), which no base-fit profile shows (found as a user: the ring profile
    # and the photon-transfer bins were shown for them as if they had revealed them)
    "cell_intensity_variability": None,
    "saturation": None,
    "photobleaching": "along the field (rows)",
    "stage_drift": "distance to the nearest cell edge",
}

_RESIDUAL = "mean standardised residual (s.d.)"
#: For each profile (a prefix of ``Mismatch.where``): x label, y label, the value that
#: means "as modelled", and the x of bin ``i``.
_PROFILE_AXES = {
    "along the field (rows)": ("row (px)", _RESIDUAL, 0.0, lambda i: i),
    "across the field (columns)": ("column (px)", _RESIDUAL, 0.0, lambda i: i),
    "distance to the nearest cell edge": (
        "distance to the nearest cell edge (px; < 0 inside a cell)",
        _RESIDUAL,
        0.0,
        lambda i: i - 5.5,  # 1-px rings from -6 px (bin 0 holds everything deeper)
    ),
    "intensity level": (
        "model mean: quantile bin (1 darkest, 8 brightest)",
        "variance ratio, mean r^2 (1 = as modelled)",
        1.0,
        lambda i: i + 1,
    ),
}

def _profile_panel(stat) -> tuple[str, np.ndarray]:
    key = next((k for k in _PROFILE_AXES if stat.where.startswith(k)), None)
    xlabel, ylabel, reference, x_of = _PROFILE_AXES.get(
        key, ("bin", "mean standardised residual (s.d.)", 0.0, lambda i: i)
    )
    raw = np.asarray(stat.profile, float)
    profile, faint, smoothing = raw, None, ""
    if raw.size > 40:  # smooth long line-mean profiles so a trend shows
        size = max(3, raw.size // 16)
        profile, faint = ndimage.uniform_filter1d(raw, size), raw
        smoothing = f"; black: running mean over {size} lines, grey: each line"
    plot = line_plot(
        profile,
        x=np.array([x_of(i) for i in range(raw.size)], float),
        xlabel=xlabel,
        ylabel=ylabel,
        reference=reference,
        faint=faint,
    )
    title = (
        f"what revealed it (base fit), {stat.where}: {stat.statistic} = {stat.value:.4g}, "
        f"-log10 p = {significance_words(stat.significance)}{smoothing}"
    )
    return title, plot


def write_figures(
    result: Diagnosis, image: np.ndarray, out: Path, *, name: str | None = None
) -> list[str]:
    """Write ``residuals.png`` (image, residual before, after) and ``effect_<name>.png``.

    Residuals are standardised and smoothed (Gaussian, 2 px) so that structure below
    the pixel noise shows; the colour limit (shared by both panels) is 4 noise s.e. of
    the smoothed mean or the 98th percentile of the smoothed base residual if larger.
    ``name`` (the image file's name) goes into the headings. Returns the names written.
    """
    import imageio.v3 as iio

    from napari_symbac.diagnose.effects import CATALOGUE

    out = Path(out)
    stack = np.asarray(image, float).reshape((-1, *image.shape[-2:]))
    frame = stack[0]
    rows, cols = frame.shape
    factor = map_scale(frame.shape)
    # tall maps (a trench) side by side, wide ones (a field) one below the other
    columns = 3 if rows * 2 >= cols else 1
    sigma = RESIDUAL_SMOOTHING_PX
    limit = 4.0 / (2 * np.sqrt(np.pi) * sigma)  # s.d. of a Gaussian-smoothed white field
    before = ndimage.gaussian_filter(result.residual_before[0], sigma)
    after = ndimage.gaussian_filter(result.residual_after[0], sigma)
    # one colour scale for both panels, wide enough for the larger misfit
    limit = max(limit, float(np.percentile(np.abs(before), 98)))
    low, high = (float(v) for v in np.percentile(frame, (0.5, 99.5)))
    residual_bar = ColourBar("diverging", -limit, limit, "s.d.")
    what = f"{name} ({rows} x {cols} px)" if name else f"a {rows} x {cols} px frame"
    frames = f", frame 1 of {len(stack)}" if len(stack) > 1 else ""
    accepted = result.accepted
    after_title = "after the accepted effects" if accepted else "after the accepted effects (none)"
    image_bar = ColourBar("grey", low, high, "ADU")
    before_bar = None if columns == 3 else residual_bar  # side by side: one bar for both
    items = [
        (
            f"image (ADU, 0.5-99.5 percentiles){frames}",
            map_body(upscale(grey(frame, low, high), factor), image_bar),
        ),
        (
            f"standardised residual, base fit; held-out deviance {result.base_fit['held_out']:.4g}",
            map_body(upscale(diverging(before, limit), factor), before_bar),
        ),
        (
            f"{after_title}; held-out deviance {result.final_fit['held_out']:.4g}",
            map_body(upscale(diverging(after, limit), factor), residual_bar),
        ),
    ]
    names = ", ".join(e.name for e in accepted) or "none"
    figure = with_heading(
        titled_grid(items, columns),
        f"Diagnosis of {what}: residuals before and after the accepted effects",
        "Standardised residual (image - model) / model noise s.d., Gaussian-smoothed "
        f"(sigma {sigma:g} px); one colour scale for both residual maps; red: image brighter "
        f"than the model, blue: darker. Accepted effects: {names}.",
    )
    iio.imwrite(out / "residuals.png", figure)
    written = ["residuals.png"]
    for k, effect in enumerate(accepted, start=1):
        items = []
        if effect.effect_map is not None:
            emap = np.asarray(effect.effect_map[0], float)
            peak = max(float(np.abs(emap).max()), 1e-12)
            kind = getattr(CATALOGUE.get(effect.name), "kind", "mean")
            what_map = "model mean" if kind == "mean" else "model noise s.d."
            effect_bar = ColourBar("diverging", -peak, peak, "ADU")
            body = map_body(upscale(diverging(emap, peak), factor), effect_bar)
            # the change when it is added, the model refitted with it (found as a user: a
            # stray light of -196 ADU shown mostly red, +138 ADU, as the intensities moved)
            title = f"change of the {what_map} when added, model refitted (ADU){frames}"
            items.append((title, body))
        key = REVEALING.get(effect.name, "")
        stat = None
        if key is not None:
            stat = next(
                (m for m in result.mismatches if m.where.startswith(key) and m.profile), None
            )
        if stat is not None:
            items.append(_profile_panel(stat))
        if not items:
            continue
        heading = f"Accepted effect {k}: {effect.name}" + (f" ({name})" if name else "")
        note = (
            f"{effect.explanation} Evidence {significance_words(effect.evidence)} (-log10 p"
            + ("" if stat is not None else "; its own score test, which no profile shows")
            + f"); held-out deviance {effect.held_out_before:.4g} -> "
            f"{effect.held_out_after:.4g} per pixel."
        )
        file = f"effect_{effect.name}.png"
        grid = titled_grid(items, len(items) if columns == 3 else 1)
        iio.imwrite(out / file, with_heading(grid, heading, note))
        written.append(file)
    return written
