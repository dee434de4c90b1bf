"""Real against synthetic: class medians, noise, radially averaged power spectrum, montage.

Both images are compared after the normalisation a segmentation network applies
(1-99 percentiles, :func:`~napari_symbac.fit.masks.normalise_percentiles`), so that a
synthetic image matched to a real one shows the same contrast between cells and
background, the same noise relative to that contrast and the same distribution of
power over spatial frequencies.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from napari_symbac.export.visibility import pixel_noise
from napari_symbac.fit.masks import normalise_percentiles

__all__ = ["Comparison", "compare_images", "montage", "radial_power"]


def radial_power(image: np.ndarray, n_bins: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """Radially averaged power spectrum of the mean-free image, per unit variance.

    Returns
    -------
    frequencies, power
        Bin centres in cycles per pixel (0 to 0.5) and the mean ``|F|^2`` in each
        annulus, divided by its sum (the shape of the spectrum, not its level).
    """
    image = np.asarray(image, np.float64)
    image = image - image.mean()
    spectrum = np.abs(np.fft.fft2(image)) ** 2
    fy = np.fft.fftfreq(image.shape[0])[:, None]
    fx = np.fft.fftfreq(image.shape[1])[None, :]
    radius = np.hypot(fy, fx)
    edges = np.linspace(0.0, 0.5, n_bins + 1)
    index = np.digitize(radius.ravel(), edges) - 1
    ok = (index >= 0) & (index < n_bins) & (radius.ravel() > 0)
    total = np.bincount(index[ok], spectrum.ravel()[ok], minlength=n_bins)
    count = np.bincount(index[ok], minlength=n_bins)
    power = total / np.maximum(count, 1)
    return (edges[:-1] + edges[1:]) / 2, power / max(power.sum(), 1e-300)


def _classes(norm: np.ndarray, labels: np.ndarray, far_px: float) -> tuple[float, float, float]:
    cells = labels > 0
    far = ndimage.distance_transform_edt(~cells) >= far_px
    noise = pixel_noise(norm, far)
    return float(np.median(norm[cells])), float(np.median(norm[far])), noise


@dataclass(frozen=True)
class Comparison:
    """Real against synthetic, each normalised to its 1-99 percentiles.

    Attributes
    ----------
    cells, background
        ``(real, synthetic)`` medians over cells and far background.
    noise
        ``(real, synthetic)`` background pixel noise (normalised units).
    frequencies, power_real, power_synthetic
        Radially averaged power spectra (shape, each summing to 1).
    """

    cells: tuple[float, float]
    background: tuple[float, float]
    noise: tuple[float, float]
    frequencies: np.ndarray = field(repr=False)
    power_real: np.ndarray = field(repr=False)
    power_synthetic: np.ndarray = field(repr=False)

    @property
    def spectrum_log_ratio(self) -> float:
        """Largest ``|log10(P_synthetic / P_real)|`` over the frequency bins."""
        tiny = 1e-300
        ratio = np.log10(np.maximum(self.power_synthetic, tiny) / np.maximum(self.power_real, tiny))
        return float(np.max(np.abs(ratio)))

    def table(self) -> str:
        """The comparison as plain text."""
        lines = [
            "                      real   synthetic",
            f"cells median        {self.cells[0]:6.3f}   {self.cells[1]:6.3f}",
            f"background median   {self.background[0]:6.3f}   {self.background[1]:6.3f}",
            f"background noise    {self.noise[0]:6.3f}   {self.noise[1]:6.3f}",
            "power spectrum (share of power per band, cycles/px):",
        ]
        for f, a, b in zip(self.frequencies, self.power_real, self.power_synthetic, strict=True):
            lines.append(f"  {f:5.3f}          {a:8.2e}   {b:8.2e}")
        lines.append(f"largest |log10 ratio| of the spectra: {self.spectrum_log_ratio:.2f}")
        return "\n".join(lines)


def compare_images(
    real: np.ndarray,
    real_masks: np.ndarray,
    synthetic: np.ndarray,
    synthetic_labels: np.ndarray,
    *,
    far_px: float = 6.0,
    n_bins: int = 16,
) -> Comparison:
    """Compare a real image and a synthetic one (module notes); shapes may differ."""
    real_n, synth_n = normalise_percentiles(real), normalise_percentiles(synthetic)
    rc, rb, rn = _classes(real_n, np.asarray(real_masks), far_px)
    sc, sb, sn = _classes(synth_n, np.asarray(synthetic_labels), far_px)
    f, pr = radial_power(real_n, n_bins)
    _, ps = radial_power(synth_n, n_bins)
    return Comparison((rc, sc), (rb, sb), (rn, sn), f, pr, ps)


def _outline(labels: np.ndarray) -> np.ndarray:
    labels = np.asarray(labels)
    eroded = ndimage.grey_erosion(labels, size=3)
    dilated = ndimage.grey_dilation(labels, size=3)
    return (labels > 0) & ((eroded != labels) | (dilated != labels))


def montage(
    real: np.ndarray,
    synthetic: np.ndarray,
    real_masks: np.ndarray | None = None,
    synthetic_labels: np.ndarray | None = None,
) -> np.ndarray:
    """8-bit RGB figure: real | synthetic side by side, each titled and at its own
    0.5-99.5 percentiles with a grey colour bar (ADU), under a heading; when masks are
    given a second row shows each with its mask outlines in green (a trench's four
    panels stand in one row). Shapes are cropped to the smaller; small images are
    enlarged by whole pixels (nearest neighbour).
    """
    from napari_symbac.figure_layout import (
        ColourBar,
        grey,
        map_body,
        map_scale,
        titled_grid,
        upscale,
        with_heading,
    )

    h = min(real.shape[0], synthetic.shape[0])
    w = min(real.shape[1], synthetic.shape[1])
    scale = map_scale((h, w))
    cropped = "" if real.shape == synthetic.shape else f" (both cropped to {h} x {w} px)"
    plain, outlined = [], []
    for image, labels, what in (
        (real, real_masks, "real image"),
        (synthetic, synthetic_labels, "synthetic image (dataset item)"),
    ):
        image = np.asarray(image, float)[:h, :w]
        low, high = (float(v) for v in np.percentile(image, [0.5, 99.5]))
        bar = ColourBar("grey", low, high, "ADU")
        shown = grey(image, low, high)
        plain.append((what, map_body(upscale(shown, scale), bar)))
        if labels is not None:
            overlay = shown.copy()
            overlay[_outline(np.asarray(labels)[:h, :w])] = (0, 255, 0)
            overlay = upscale(overlay, scale)
            mask_word = "masks" if what.startswith("real") else "labels"
            title = f"{what} with its {mask_word} outlined (green)"
            outlined.append((title, map_body(overlay, bar)))
    items = plain + outlined
    columns = len(items) if h >= 2 * w else 2  # a trench: all panels in one row
    return with_heading(
        titled_grid(items, columns),
        f"Real against synthetic, {h} x {w} px{cropped}",
        "The real recording, then the synthetic image (a dataset item), each shown "
        "at its own 0.5-99.5 percentiles (grey bars, ADU)"
        + ("; then the same with mask outlines in green." if outlined else "."),
    )
