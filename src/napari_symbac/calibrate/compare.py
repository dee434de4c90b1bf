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

__all__ = [
    "CLI_WORDS",
    "GUI_WORDS",
    "MEDIAN_TOLERANCE",
    "NOISE_FACTOR",
    "SPECTRUM_FACTOR",
    "AdviceWords",
    "Check",
    "Comparison",
    "band_coefficients",
    "compare_images",
    "montage",
    "radial_power",
]

#: Largest difference of the normalised class medians (real - synthetic) called a match:
#: the project's goal for phase colonies (issue 16). A median over n pixels of noise
#: sigma varies by about 1.25 sigma / sqrt(n), under 0.01 for the background noise of
#: a recording (~0.08) and 100 pixels, so a larger difference is the model's, not chance.
MEDIAN_TOLERANCE = 0.05
#: Largest factor between the background noises called a match: the robust noise of n
#: neighbour differences varies by about 1.2 / sqrt(n) (relative), under 4 % for 1000
#: pairs, so 1.2 leaves the sampling several standard errors; the tolerance widens to
#: 3 standard errors of the ratio where there are too few pairs.
NOISE_FACTOR = 1.2
#: Largest factor between the spectra's shares in one frequency band called a match:
#: a band's mean power over m independent Fourier coefficients (each exponentially
#: distributed) varies by 1 / sqrt(m) (relative), and real and synthetic fields hold
#: different cells; 1.5 is 3 standard errors of the ratio for m = 50 (a band of a
#: 128 px image), and the tolerance widens to 3 standard errors for smaller bands.
SPECTRUM_FACTOR = 1.5


@dataclass(frozen=True)
class AdviceWords:
    """How the advice of a :class:`Comparison` names what the user can do: the words of
    the interface the comparison is shown in.

    Attributes
    ----------
    masks
        Giving the cells' masks (``"pass --masks"``).
    montage
        The picture of real against synthetic (``"the montage (report.png)"``).
    camera
        Giving the real camera.
    """

    masks: str
    montage: str
    camera: str


#: ``napari-symbac calibrate``'s words.
CLI_WORDS = AdviceWords(
    masks="pass --masks",
    montage="the montage (report.png)",
    camera="give the real camera (--camera C.yaml)",
)
#: The Calibrate dock's words (it shows item 0 of the dataset as a layer over the recording).
GUI_WORDS = AdviceWords(
    masks="choose the cell masks",
    montage="the calibrated layer against the recording",
    camera="give the real camera (`napari-symbac calibrate --camera C.yaml`; the dock "
    "measures it from the recording)",
)


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
    edges, index, ok = _bands(image.shape, n_bins)
    total = np.bincount(index[ok], spectrum.ravel()[ok], minlength=n_bins)
    count = np.bincount(index[ok], minlength=n_bins)
    power = total / np.maximum(count, 1)
    return (edges[:-1] + edges[1:]) / 2, power / max(power.sum(), 1e-300)


def _bands(shape: tuple[int, int], n_bins: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The annuli of :func:`radial_power`: band edges (cycles/px), each Fourier
    coefficient's band (flattened) and which coefficients count (not the mean)."""
    fy = np.fft.fftfreq(shape[0])[:, None]
    fx = np.fft.fftfreq(shape[1])[None, :]
    radius = np.hypot(fy, fx).ravel()
    edges = np.linspace(0.0, 0.5, n_bins + 1)
    index = np.digitize(radius, edges) - 1
    return edges, index, (index >= 0) & (index < n_bins) & (radius > 0)


def band_coefficients(shape: tuple[int, int], n_bins: int = 16) -> np.ndarray:
    """Number of Fourier coefficients in each band of :func:`radial_power`."""
    _, index, ok = _bands(shape, n_bins)
    return np.bincount(index[ok], minlength=n_bins)


def _classes(
    images: list[np.ndarray], labels: list[np.ndarray], far_px: float
) -> tuple[float, float, float, int]:
    """Cells' and far background's medians over the pixels of all ``images`` (each
    normalised on its own), the median of their background noises and the pixel pairs
    those were measured on in all."""
    cells, far, noises, pairs = [], [], [], 0
    for norm, label in zip(images, labels, strict=True):
        cell = np.asarray(label) > 0
        background = ndimage.distance_transform_edt(~cell) >= far_px
        cells.append(norm[cell])
        far.append(norm[background])
        noises.append(pixel_noise(norm, background))
        pairs += int(np.count_nonzero(background[:, 1:] & background[:, :-1]))
    cell_pixels, far_pixels = np.concatenate(cells), np.concatenate(far)
    return (
        float(np.median(cell_pixels)) if cell_pixels.size else float("nan"),
        float(np.median(far_pixels)) if far_pixels.size else float("nan"),
        float(np.median(noises)),
        pairs,
    )


@dataclass(frozen=True)
class Check:
    """One compared quantity: whether the synthetic data match the recording.

    Attributes
    ----------
    quantity
        What was compared ("cells median", ...).
    matched
        Whether the difference is within the tolerance.
    finding
        The numbers and the tolerance, in words.
    advice
        What a user can do when it does not match (empty when it does).
    """

    quantity: str
    matched: bool
    finding: str
    advice: str = ""

    def line(self) -> str:
        """``quantity: MATCH|MISMATCH: finding`` for the report."""
        word = "MATCH" if self.matched else "MISMATCH"
        return f"{self.quantity}: {word}: {self.finding}"


def _factor_allowed(base: float, relative_se: float) -> float:
    """A ratio's tolerance: ``base``, widened to 3 standard errors of the ratio of two
    estimates of relative standard error ``relative_se`` each."""
    return max(base, float(np.exp(3 * np.sqrt(2) * relative_se)))


def _median_check(quantity: str, real: float, synthetic: float, advice: str) -> Check:
    difference = synthetic - real
    matched = bool(abs(difference) <= MEDIAN_TOLERANCE)
    finding = (
        f"synthetic {synthetic:.3f} against real {real:.3f} (difference {difference:+.3f}; "
        f"tolerance +-{MEDIAN_TOLERANCE:g} in 1-99 % normalised units, far above a "
        "median's sampling noise: a larger difference is the model's, not chance)"
    )
    return Check(quantity, matched, finding, "" if matched else advice)


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
    noise_pairs
        Neighbour pairs the smaller noise estimate was measured on (its sampling).
    band_coefficients
        Fourier coefficients per band of the smaller image (the spectra's sampling).
    masks_given
        Whether the real cells are the user's masks (the advice then does not ask for
        them) or the fit's.
    words
        The interface's words in the advice (:data:`CLI_WORDS`, :data:`GUI_WORDS`).
    """

    cells: tuple[float, float]
    background: tuple[float, float]
    noise: tuple[float, float]
    frequencies: np.ndarray = field(repr=False)
    power_real: np.ndarray = field(repr=False)
    power_synthetic: np.ndarray = field(repr=False)
    noise_pairs: int = 10_000
    band_coefficients: np.ndarray | None = field(default=None, repr=False)
    masks_given: bool = False
    words: AdviceWords = CLI_WORDS
    sub_level_noise: bool = False

    def _masks_advice(self, why: str) -> str:
        """``pass --masks ... (why), and `` unless they were given."""
        if self.masks_given:
            return ""
        return f"{self.words.masks} if you have them ({why}), and "

    def band_factors(self) -> np.ndarray:
        """Each band's tolerated factor: :data:`SPECTRUM_FACTOR`, or 3 standard errors
        of the ratio where the band holds too few coefficients."""
        counts = self.band_coefficients
        if counts is None:
            counts = np.full(self.frequencies.size, 10_000)
        independent = np.maximum(np.asarray(counts, float) / 2, 1.0)  # F(-k) = F(k)*
        return np.array([_factor_allowed(SPECTRUM_FACTOR, 1 / np.sqrt(m)) for m in independent])

    def band_ratios(self) -> np.ndarray:
        """Synthetic over real share of the power in each band."""
        tiny = 1e-300
        return np.maximum(self.power_synthetic, tiny) / np.maximum(self.power_real, tiny)

    def checks(self) -> list[Check]:
        """Cells median, background median, noise and spectrum, each matched or not."""
        return [
            _median_check(
                "cells median", *self.cells,
                "the cells' contrast against the background differs: "
                + self._masks_advice("the cells as annotated")
                + f"look at {self.words.montage} for cells the fit missed or drew too "
                "bright or too dark",
            ),
            _median_check(
                "background median", *self.background,
                "the background level differs: "
                + self._masks_advice("cells are then not counted as background")
                + f"look at {self.words.montage} for debris or uneven illumination",
            ),
            self._noise_check(),
            self._spectrum_check(),
        ]

    def _noise_check(self) -> Check:
        real, synthetic = self.noise
        allowed = _factor_allowed(NOISE_FACTOR, 1.2 / np.sqrt(max(self.noise_pairs, 1)))
        if not (np.isfinite(real) and np.isfinite(synthetic)) or min(real, synthetic) <= 0:
            advice = "a field with more background between the cells"
            if not self.masks_given:
                advice = f"{self.words.masks}, or {advice}"
            return Check("background noise", False, "not measured (too little background)",
                         advice)
        factor = max(real, synthetic) / min(real, synthetic)
        matched = bool(factor <= allowed)
        finding = (
            f"synthetic {synthetic:.3f} against real {real:.3f} (factor {factor:.2f}; "
            f"tolerance x{allowed:.2f}: {NOISE_FACTOR:g}, or 3 standard errors of the "
            "ratio when few background pixels, the sampling of a robust noise)"
        )
        advice = "" if matched else (
            f"the noise differs: {self.words.camera} and check the pixel size (noise per "
            "pixel scales with it)"
        )
        if not matched and self.sub_level_noise and synthetic > real:  # found as a user:
            # an 8-bit colony was told to give a camera that no PNG has
            from napari_symbac.fit.colony import MIN_NOISE_ADU

            advice = (
                "the recording's noise is under one grey level (quantised, as in an 8-bit "
                "export), where a noise drawn and then rounded reads higher than it was "
                f"drawn; the dataset draws at least {MIN_NOISE_ADU:g} ADU so that its "
                "images are not flat; no camera given would change that"
            )
        return Check("background noise", matched, finding, advice)

    def _spectrum_check(self) -> Check:
        ratios, allowed = self.band_ratios(), self.band_factors()
        off = np.abs(np.log(ratios)) > np.log(allowed)
        tolerance = (
            f"tolerance per band x{SPECTRUM_FACTOR:g}, or 3 standard errors of the ratio "
            "for bands of few Fourier coefficients"
        )
        if not off.any():
            return Check("power spectrum", True, f"all {ratios.size} bands within "
                         f"x{allowed.max():.2g} ({tolerance})")
        bands = ", ".join(
            f"{f:.3f} (synthetic x{r:.2g})"
            for f, r in zip(self.frequencies[off], ratios[off], strict=True)
        )
        finding = f"{int(off.sum())} of {ratios.size} bands out ({tolerance}): {bands}"
        low = ratios[off] < 1
        high = self.frequencies[off] > 0.1
        if (low & high).sum() >= (~low & high).sum() and high.any():
            advice = (
                "the synthetic image lacks fine detail (too smooth): check the pixel size "
                f"and the camera's noise, and compare the sharpness in {self.words.montage}"
            )
        else:
            advice = (
                "the spread of power over spatial frequencies differs: check the pixel size "
                f"and the cells' size and layout in {self.words.montage}"
            )
        return Check("power spectrum", False, finding, advice)

    def verdict(self) -> str:
        """One line: in how many comparisons the synthetic data match, and what to do."""
        checks = self.checks()
        failed = [c for c in checks if not c.matched]
        line = (
            f"the synthetic data match the recording in {len(checks) - len(failed)} of "
            f"{len(checks)} comparisons"
        )
        if not failed:
            return line + "; mismatched: none"
        advice = "; ".join(dict.fromkeys(c.advice for c in failed))
        return (
            f"{line}; mismatched: {', '.join(c.quantity for c in failed)}. What to do: {advice}"
        )

    @property
    def spectrum_log_ratio(self) -> float:
        """Largest ``|log10(P_synthetic / P_real)|`` over the frequency bins."""
        return float(np.max(np.abs(np.log10(self.band_ratios()))))

    def table(self) -> str:
        """The comparison as plain text: the numbers, then each quantity matched or not,
        then the summary line (:meth:`verdict`)."""
        lines = [
            "                      real   synthetic",
            f"cells median        {self.cells[0]:6.3f}   {self.cells[1]:6.3f}",
            f"background median   {self.background[0]:6.3f}   {self.background[1]:6.3f}",
            f"background noise    {self.noise[0]:6.3f}   {self.noise[1]:6.3f}",
            "power spectrum (share of power per band, cycles/px; ratio synthetic/real):",
        ]
        out = np.abs(np.log(self.band_ratios())) > np.log(self.band_factors())
        for f, a, b, r, bad in zip(
            self.frequencies, self.power_real, self.power_synthetic, self.band_ratios(), out,
            strict=True,
        ):
            flag = "  MISMATCH" if bad else ""
            lines.append(f"  {f:5.3f}          {a:8.2e}   {b:8.2e}   x{r:5.2f}{flag}")
        lines.append(f"largest |log10 ratio| of the spectra: {self.spectrum_log_ratio:.2f}")
        lines += ["", "DO THE SYNTHETIC DATA MATCH THE RECORDING?"]
        lines += [f"- {check.line()}" for check in self.checks()]
        lines.append(self.verdict())
        return "\n".join(lines)


def _normalised(image: np.ndarray, what: str, meaning: str) -> np.ndarray:
    """``image`` at its 1-99 percentiles (:func:`~napari_symbac.fit.masks.normalise_percentiles`).

    Raises
    ------
    ValueError
        When one grey level holds 98 % of its pixels (nothing to normalise by), naming
        ``what`` it is, the level (and the saturation when it is its type's top) and
        ``meaning``: why that happens and the fix.
    """
    low, high = np.percentile(image, [1.0, 99.0])
    if high > low:
        return normalise_percentiles(image)
    top = np.issubdtype(image.dtype, np.integer) and high == np.iinfo(image.dtype).max
    level = f"{high:g} ADU" + (f", the top of {image.dtype}: saturated" if top else "")
    raise ValueError(
        f"{what} is one grey level ({level}) over 98 % of its pixels, nothing to compare "
        f"the two by: {meaning}"
    )


def compare_images(
    real: np.ndarray,
    real_masks: np.ndarray,
    synthetic: np.ndarray | list[np.ndarray],
    synthetic_labels: np.ndarray | list[np.ndarray],
    *,
    far_px: float = 6.0,
    n_bins: int = 16,
    masks_given: bool = False,
    words: AdviceWords = CLI_WORDS,
    sub_level_noise: bool = False,
) -> Comparison:
    """Compare a real image and a synthetic one, or several (module notes); shapes may
    differ.

    Several synthetic images (a list, with a list of their labels) are pooled, each
    normalised on its own: the class medians over all their pixels, the median of their
    background noises, the mean of their spectra (each a distribution over the bands).
    One image of a dataset is one draw of its layout and light: on a sparse field, whether
    its cells fill the 1st percentile moves its normalised medians by up to 0.4
    (ColiCoords' bright field: -0.47 to -0.07 over 6 items of one calibration).

    ``masks_given``: ``real_masks`` are the user's (:attr:`Comparison.masks_given`);
    ``words``: the interface's, in the advice (:attr:`Comparison.words`);
    ``sub_level_noise``: the synthetic images draw a Gaussian noise under one grey level
    (at least :data:`~napari_symbac.fit.colony.MIN_NOISE_ADU`), which the advice then
    names instead of a camera.
    """
    if isinstance(synthetic, np.ndarray) and synthetic.ndim == 2:
        synthetic, synthetic_labels = [synthetic], [synthetic_labels]
    if not len(synthetic) or len(synthetic) != len(synthetic_labels):
        raise ValueError("give as many synthetic images as label images, at least one")
    real_n = _normalised(
        real,
        "the recording",
        "its cells and their contrast cover under 2 % of it: give a field, or a crop, "
        "with more cells",
    )
    synth_n = [
        _normalised(
            image,
            f"synthetic item {k}",
            "the fitted settings do not reproduce the recording: check the modality "
            "(bright field given as phase saturates) and the pixel size",
        )
        for k, image in enumerate(synthetic)
    ]
    rc, rb, rn, r_pairs = _classes([real_n], [real_masks], far_px)
    sc, sb, sn, s_pairs = _classes(synth_n, list(synthetic_labels), far_px)
    f, pr = radial_power(real_n, n_bins)
    ps = np.mean([radial_power(image, n_bins)[1] for image in synth_n], axis=0)
    synthetic_counts = sum(band_coefficients(image.shape, n_bins) for image in synth_n)
    counts = np.minimum(band_coefficients(real.shape, n_bins), synthetic_counts)
    return Comparison(
        (rc, sc), (rb, sb), (rn, sn), f, pr, ps, min(r_pairs, s_pairs), counts, masks_given,
        words, sub_level_noise,
    )


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
    *,
    real_masks_fitted: bool = False,
) -> np.ndarray:
    """8-bit RGB figure: real | synthetic side by side, each titled and at its own
    0.5-99.5 percentiles with a grey colour bar (ADU), under a heading; when masks are
    given a second row shows each with its mask outlines in green (a trench's four
    panels stand in one row), the real image's titled as the fit's cells when
    ``real_masks_fitted`` (no masks were given: found as a user, the panel said "its
    masks"). Shapes are cropped to the smaller; small images are enlarged by whole
    pixels (nearest neighbour).
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
            mask_word = "its masks" if what.startswith("real") else "its labels"
            if what.startswith("real") and real_masks_fitted:
                mask_word = "the fitted cells"
            title = f"{what} with {mask_word} outlined (green)"
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
