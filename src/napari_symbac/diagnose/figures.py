"""PNG figures of a diagnosis (numpy only: no plotting library needed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy import ndimage

from napari_symbac.diagnose.run import Diagnosis

__all__ = ["diverging", "line_plot", "write_figures"]

#: The discrepancy statistic shown with each accepted effect (a key of ``Mismatch.where``).
REVEALING = {
    "uneven_illumination": "along the field (rows)",
    "defocus_gradient": "along the field (rows)",
    "halo": "distance to the nearest cell edge",
    "stray_light": "distance to the nearest cell edge",
    "cell_curvature": "distance to the nearest cell edge",
    "camera_noise": "intensity level",
    "fixed_pattern_noise": "across the field (columns)",
    "background_texture": "across the field (columns)",
    "cell_intensity_variability": "distance to the nearest cell edge",
    "saturation": "intensity level",
    "photobleaching": "along the field (rows)",
    "stage_drift": "distance to the nearest cell edge",
}


def diverging(image: np.ndarray, limit: float) -> np.ndarray:
    """Blue-white-red RGB (uint8) of ``image`` clipped to ``[-limit, limit]``."""
    t = np.clip(np.asarray(image, float) / max(limit, 1e-12), -1, 1)
    r = np.where(t > 0, 1.0, 1.0 + t)
    b = np.where(t < 0, 1.0, 1.0 - t)
    g = 1.0 - np.abs(t)
    return (np.stack([r, g, b], axis=-1) * 255).astype(np.uint8)


def grey(image: np.ndarray) -> np.ndarray:
    lo, hi = np.percentile(image, (0.5, 99.5))
    t = np.clip((image - lo) / max(hi - lo, 1e-12), 0, 1)
    return np.repeat((t * 255).astype(np.uint8)[..., None], 3, axis=-1)


def line_plot(
    values: np.ndarray, height: int = 120, width: int = 320, band: float | None = None
) -> np.ndarray:
    """A white RGB panel with ``values`` drawn as a black polyline; zero as a grey line.

    ``band`` draws the +-band (e.g. the noise s.e.) as light grey lines.
    """
    panel = np.full((height, width, 3), 255, np.uint8)
    v = np.asarray(values, float)
    if v.size < 2:
        return panel
    span = max(np.abs(v).max(), band or 0.0, 1e-12) * 1.1

    def row(x: np.ndarray) -> np.ndarray:
        return np.clip(((1 - (x / span + 1) / 2) * (height - 1)).round().astype(int), 0, height - 1)

    panel[row(np.zeros(1))[0], :] = 180
    if band:
        panel[row(np.array([band]))[0], :] = 220
        panel[row(np.array([-band]))[0], :] = 220
    xs = np.linspace(0, width - 1, v.size)
    for i in range(v.size - 1):
        n = int(abs(xs[i + 1] - xs[i])) + 2
        px = np.linspace(xs[i], xs[i + 1], n).round().astype(int)
        py = row(np.linspace(v[i], v[i + 1], n))
        panel[py, px] = 0
    return panel


def _upscale(rgb: np.ndarray, factor: int) -> np.ndarray:
    return np.repeat(np.repeat(rgb, factor, axis=0), factor, axis=1)


def _row_of(panels: list[np.ndarray], gap: int = 6) -> np.ndarray:
    h = max(p.shape[0] for p in panels)
    out = []
    for p in panels:
        pad = np.full((h - p.shape[0], p.shape[1], 3), 255, np.uint8)
        out += [np.concatenate([p, pad]), np.full((h, gap, 3), 255, np.uint8)]
    return np.concatenate(out[:-1], axis=1)


def write_figures(result: Diagnosis, image: np.ndarray, out: Path) -> list[str]:
    """Write ``residuals.png`` (image, residual before, after) and ``effect_<name>.png``.

    Residuals are standardised and smoothed (Gaussian, 2 px) so that structure below
    the pixel noise shows; the colour limit (shared by both panels) is 4 noise s.e. of
    the smoothed mean or the 98th percentile of the smoothed base residual if larger.
    """
    import imageio.v3 as iio

    out = Path(out)
    frame = np.asarray(image, float).reshape((-1, *image.shape[-2:]))[0]
    factor = max(1, int(np.ceil(200 / max(frame.shape))))
    sigma = 2.0
    limit = 4.0 / (2 * np.sqrt(np.pi) * sigma)  # s.d. of a Gaussian-smoothed white field
    before = ndimage.gaussian_filter(result.residual_before[0], sigma)
    after = ndimage.gaussian_filter(result.residual_after[0], sigma)
    # one colour scale for both panels, wide enough for the larger misfit
    limit = max(limit, float(np.percentile(np.abs(before), 98)))
    panels = [grey(frame), diverging(before, limit), diverging(after, limit)]
    iio.imwrite(out / "residuals.png", _upscale(_row_of(panels), factor))
    written = ["residuals.png"]
    for effect in result.accepted:
        parts = []
        if effect.effect_map is not None:
            emap = effect.effect_map[0]
            parts.append(_upscale(diverging(emap, max(np.abs(emap).max(), 1e-12)), factor))
        key = REVEALING.get(effect.name, "")
        stat = next((m for m in result.mismatches if m.where.startswith(key) and m.profile), None)
        if stat is not None:
            profile = np.asarray(stat.profile)
            if profile.size > 40:  # smooth long line-mean profiles so a trend shows
                profile = ndimage.uniform_filter1d(profile, max(3, profile.size // 16))
            parts.append(line_plot(profile))
        if parts:
            name = f"effect_{effect.name}.png"
            iio.imwrite(out / name, _row_of(parts))
            written.append(name)
    return written
