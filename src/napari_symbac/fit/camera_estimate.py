"""The camera from the data: censored pixels and photon transfer (eq. 17-19).

A linear camera (EMVA1288, eq. 17 of the supplement) gives every pixel the variance

    var = K (mean - offset) + sigma_r^2        (ADU^2)

with ``K`` the sensitivity (ADU per electron, ``Camera.sensitivity_adu_per_e``),
``offset`` the dark level (``Camera.baseline_adu``) and ``sigma_r = K sigma_d`` the
read noise in ADU. :func:`estimate_camera` measures that line from the data itself.

From images alone only the slope ``K`` and the intercept ``c = sigma_r^2 - K offset``
are identifiable: offset and read noise trade off along the line. The offset must come
from elsewhere (dark frames, the camera settings you pass, or, as a rough last resort,
the image's darkest region), and the result says which.

:func:`censored_pixels` marks the pixels a likelihood must not use: saturated ones
(at the digitiser's maximum, or a spike of the histogram at the image maximum) and
pixels clipped at zero by background subtraction. Their true value is only known to
lie beyond the clip.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy import ndimage

from napari_symbac.optics.camera import calibrate_camera
from napari_symbac.settings import Camera

__all__ = [
    "MIN_UNRESOLVED_DARK_NOISE_E",
    "CameraEstimate",
    "censored_pixels",
    "estimate_camera",
    "read_noise_unmeasured",
    "with_unresolved_dark_noise",
]

#: A clip is a value holding more than this fraction of all pixels ...
SPIKE_FRACTION = 1e-3
#: ... and more than this many times the median count of the ten nearest other values.
SPIKE_RATIO = 5.0
#: High-pass kernel: outer product of second differences. It cancels any intensity that
#: is linear along rows or along columns, and ``sum(w**2) = 36`` makes ``z = (w * y) / 6``
#: carry exactly the local pixel variance.
_HIGH_PASS = np.outer([1.0, -2.0, 1.0], [1.0, -2.0, 1.0]) / 6.0
#: The same second difference at a spacing of 2 pixels: blind to correlation between
#: neighbouring pixels, so the ratio of the two variances tests that the noise is white.
_HIGH_PASS_LAG2 = np.outer([1.0, 0.0, -2.0, 0.0, 1.0], [1.0, 0.0, -2.0, 0.0, 1.0]) / 6.0
#: Ratio of lag-2 to lag-1 high-pass variance beyond which the summary warns.
_WHITE_TOLERANCE = 0.1
#: A photon-transfer slope must lie this many standard errors above 0 to measure a camera
#: (the real recordings of ../shared give 5-63; a flattened bright field 0.2).
MEASURED_SLOPE_SE = 3.0
#: Read noise (e-) given to a camera whose photon transfer finds less (none resolved)
#: while its image holds ADU levels between whole electrons
#: (:func:`with_unresolved_dark_noise`): a Gaussian of 0.5 electrons leaves 0.7 % of the
#: steps of the sensitivity in a histogram (``exp(-2 pi^2 0.5^2)``), and adds 0.25 e-^2 to
#: a pixel's variance. (Found as a user: ColiCoords ds3, measured 19.2 ADU/e- and 0 e-,
#: was rendered in steps of 19.2 ADU, 7 % of the background's levels used against
#: every level in the recording.)
MIN_UNRESOLVED_DARK_NOISE_E = 0.5
#: Truncation of the robust variance (in robust standard deviations).
_CLIP_SD = 4.0
#: Variance of a standard normal truncated to +-4 (corrects the clipped mean square).
_TRUNCATED_VARIANCE = 0.998929


def _as_stack(image: np.ndarray, name: str) -> np.ndarray:
    array = np.asarray(image)
    if array.ndim == 2:
        array = array[None]
    if array.ndim != 3 or min(array.shape[1:]) < 8:
        raise ValueError(
            f"{name} must be a 2D image or a (T, Y, X) stack of at least 8 x 8 pixels, "
            f"got shape {np.shape(image)}"
        )
    if not np.issubdtype(array.dtype, np.number) or np.iscomplexobj(array):
        raise ValueError(f"{name} must hold real numbers, got dtype {array.dtype}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} contains NaN or infinite values: mask or fill them first")
    return array


def _is_spike(values: np.ndarray, counts: np.ndarray, index: int) -> bool:
    """Whether ``values[index]`` holds a clip-like pile of pixels (see module constants)."""
    total = counts.sum()
    if counts[index] <= SPIKE_FRACTION * total:
        return False
    others = np.concatenate([counts[max(0, index - 10) : index], counts[index + 1 : index + 11]])
    return others.size == 0 or counts[index] > SPIKE_RATIO * np.median(others)


def image_bit_depth(image: np.ndarray) -> int:
    """The digitiser's bits a camera measured from ``image`` is recorded with.

    8 for an 8-bit image (a PNG or an 8-bit TIFF: its levels end at 255, and a dataset
    matched to it must clip there too), else 16, the largest a :class:`Camera` holds.
    """
    return 8 if np.asarray(image).dtype == np.uint8 else 16


def censored_pixels(image: np.ndarray, camera: Camera | None = None) -> np.ndarray:
    """Pixels whose value is clipped, to leave out of a likelihood.

    A pixel is censored when it sits

    * at the digitiser's maximum: ``camera.max_adu`` when a camera is given, else the
      largest value of an integer dtype (65535 for uint16);
    * at the image maximum when that value is a spike of the histogram (more than
      0.1 % of all pixels and five times the count of its neighbouring grey values):
      saturation of a camera with fewer bits than its file, or a flattening step;
    * at the image minimum when that minimum is zero or below and is such a spike:
      background subtraction that clipped negative values to zero.

    Parameters
    ----------
    image
        2D image or ``(T, Y, X)`` stack; the rules apply to the stack as a whole.
    camera
        The camera, if known (its bit depth sets the saturation level).

    Returns
    -------
    numpy.ndarray
        Boolean array of the image's shape, True where censored.

    Examples
    --------
    >>> import numpy as np
    >>> image = np.full((16, 16), 65535, np.uint16); image[:8] = 1000
    >>> float(censored_pixels(image).mean())
    0.5
    """
    raw = np.asarray(image)
    _as_stack(raw, "image")
    censored = np.zeros(raw.shape, bool)
    if camera is not None:
        censored |= raw >= camera.max_adu
    elif np.issubdtype(raw.dtype, np.integer):
        censored |= raw >= np.iinfo(raw.dtype).max
    values, counts = np.unique(raw, return_counts=True)
    if values.size >= 2:
        if _is_spike(values, counts, values.size - 1):
            censored |= raw == values[-1]
        if values[0] <= 0 and _is_spike(values, counts, 0):
            censored |= raw == values[0]
    return censored


@dataclass(frozen=True)
class CameraEstimate:
    """A camera measured from the data by photon transfer (eq. 17-19).

    Attributes
    ----------
    camera
        The estimated :class:`~napari_symbac.settings.Camera` (sensitivity from the
        slope, baseline from ``offset_source``, dark noise from the intercept or the
        dark frames).
    sensitivity_se_adu_per_e, baseline_se_adu, dark_noise_se_e
        Standard errors (``nan`` where the quantity was given, not measured).
    variance_intercept_adu2
        The fitted intercept ``c`` of ``var = K mean + c``; ``c = sigma_r^2 - K offset``.
    method
        ``"model residual"`` (the fit's noise-free image was given), ``"high-pass"``
        (one image or a series of frames, no model) and ``+ dark frames`` when those set
        offset and read noise.
    offset_source
        Where the baseline came from: ``"dark frames"``, ``"camera settings"`` or
        ``"darkest region of the image"`` (an upper bound: any light there adds to it).
    n_points
        Pixels used in the photon-transfer fit.
    n_bins
        Mean-level bins the line was fitted through (after dropping outlier bins).
    neighbour_variance_ratio
        High-pass method only (``nan`` otherwise): median over the bins of the variance
        seen by a second difference at a spacing of 2 pixels over that at 1 pixel. 1 for
        white noise; above 1 when neighbouring pixels' noise is positively correlated
        (interpolation, binning, read-out coupling), which biases the single-image gain
        low by about this factor.
    """

    camera: Camera
    sensitivity_se_adu_per_e: float
    baseline_se_adu: float
    dark_noise_se_e: float
    variance_intercept_adu2: float
    method: str
    offset_source: Literal["dark frames", "camera settings", "darkest region of the image"]
    n_points: int
    n_bins: int
    neighbour_variance_ratio: float = math.nan

    def summary(self) -> str:
        """One line for a report."""
        cam = self.camera
        dark = (
            f"{cam.dark_noise_e:.3g} +- {self.dark_noise_se_e:.2g} e-"
            if math.isfinite(self.dark_noise_se_e) and not read_noise_unmeasured(cam)
            # found as a user: "dark noise 0 +- nan e-" where the intercept sat at or below 0
            else f"{cam.dark_noise_e:.3g} e- (too small to measure from this image"
            + (
                "; the image holds levels between whole electrons, so not 0)"
                if cam.dark_noise_e
                else ")"
            )
        )
        text = (
            f"camera ({self.method}, {self.n_points} px): sensitivity "
            f"{cam.sensitivity_adu_per_e:.3g} +- {self.sensitivity_se_adu_per_e:.2g} ADU/e-, "
            f"baseline {cam.baseline_adu:.1f} ADU ({self.offset_source}), dark noise {dark}"
        )
        if abs(self.neighbour_variance_ratio - 1) > _WHITE_TOLERANCE:
            text += (
                f"; the noise is not white (lag-2 / lag-1 variance "
                f"{self.neighbour_variance_ratio:.2f}), so this gain is biased by about that "
                "factor: prefer dark frames or the fit's model residual"
            )
        return text


def _robust_variance(values: np.ndarray) -> float:
    """Variance of mostly Gaussian values with outliers (edges) removed.

    Start from the MAD, drop values beyond 4 robust SDs, take the mean square of the
    rest and undo the truncation (twice, so the cut follows the efficient estimate).
    """
    centre = float(np.median(values))
    sd = 1.4826 * float(np.median(np.abs(values - centre)))
    if sd == 0:
        return float(np.mean((values - centre) ** 2))
    for _ in range(2):
        kept = values[np.abs(values - centre) <= _CLIP_SD * sd]
        centre = float(kept.mean())
        sd = math.sqrt(float(np.mean((kept - centre) ** 2)) / _TRUNCATED_VARIANCE)
    return sd**2


def _binned_variances(
    level: np.ndarray, deviation: np.ndarray, n_bins: int, min_per_bin: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean level, robust variance and its standard error in equal-count bins."""
    n_bins = max(2, min(n_bins, level.size // min_per_bin))
    order = np.argsort(level, kind="stable")
    means, variances, errors = [], [], []
    for chunk in np.array_split(order, n_bins):
        variance = _robust_variance(deviation[chunk])
        means.append(float(level[chunk].mean()))
        variances.append(variance)
        errors.append(variance * math.sqrt(2.0 / chunk.size))
    return np.array(means), np.array(variances), np.array(errors)


def _line_fit(
    x: np.ndarray, y: np.ndarray, se: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weighted line ``y = K x + c`` dropping bins more than 4 SE off (edge-dominated).

    Returns ``(K, c)``, their covariance (scaled by the reduced chi-square when that
    exceeds 1) and the mask of the bins kept.
    """
    if not np.all(np.isfinite(y) & (se > 0)):
        # found as a user: a mask fitted as an image said "SVD did not converge in Linear
        # Least Squares" in report.txt
        raise ValueError(
            "the pixels hold no noise at some grey levels: flat regions of one value, as "
            "a mask or a rendered or processed image has, not a camera's counts"
        )
    kept = np.ones(x.size, bool)
    for _ in range(5):
        design = np.column_stack([x[kept], np.ones(kept.sum())]) / se[kept, None]
        target = y[kept] / se[kept]
        coef, *_ = np.linalg.lstsq(design, target, rcond=None)
        normalised = (y - coef[0] * x - coef[1]) / se
        worst = np.abs(normalised) > 4.0
        if not np.any(worst & kept) or kept.sum() - np.sum(worst & kept) < 3:
            break
        kept &= ~worst
    dof = max(int(kept.sum()) - 2, 1)
    chi2 = float(np.sum(normalised[kept] ** 2)) / dof
    covariance = np.linalg.inv(design.T @ design) * max(chi2, 1.0)
    return coef, covariance, kept


def _high_pass_points(
    stack: np.ndarray, usable: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per-pixel mean level and high-pass residual of every frame (no model).

    ``z = (w * y) / 6`` has the local pixel variance and zero mean wherever the
    intensity is locally linear; the level is the 3 x 3 mean, uncorrelated with ``z``
    for homoscedastic noise because ``sum(w) = 0``. Pixels whose 3 x 3 neighbourhood
    touches a censored or invalid pixel, or the border, are left out; edges are outliers
    that the robust variance drops.

    Returns
    -------
    level, z
        For every usable pixel.
    wide, z_lag2
        A boolean selecting, from those pixels, the ones whose 5 x 5 neighbourhood is
        usable too, and there the same residual at a spacing of 2 pixels (the white-noise
        test of ``neighbour_variance_ratio``).
    """
    levels, residuals, wides, residuals_lag2 = [], [], [], []
    for frame, ok in zip(stack, usable, strict=True):
        ok3 = ndimage.binary_erosion(ok, np.ones((3, 3), bool), border_value=0)
        ok5 = ndimage.binary_erosion(ok, np.ones((5, 5), bool), border_value=0)
        levels.append(ndimage.uniform_filter(frame, 3, mode="reflect")[ok3])
        residuals.append(ndimage.correlate(frame, _HIGH_PASS, mode="reflect")[ok3])
        wides.append(ok5[ok3])
        residuals_lag2.append(ndimage.correlate(frame, _HIGH_PASS_LAG2, mode="reflect")[ok5])
    return (
        np.concatenate(levels),
        np.concatenate(residuals),
        np.concatenate(wides),
        np.concatenate(residuals_lag2),
    )


def _white_noise_ratio(
    level: np.ndarray, z: np.ndarray, z_lag2: np.ndarray, n_bins: int, min_per_bin: int
) -> float:
    """Median over level bins of the lag-2 over the lag-1 high-pass variance."""
    if level.size < 3 * min_per_bin:
        return math.nan
    lag1 = _binned_variances(level, z, n_bins, min_per_bin)[1]
    lag2 = _binned_variances(level, z_lag2, n_bins, min_per_bin)[1]
    return float(np.median(lag2 / np.maximum(lag1, 1e-300)))


def _holds_levels_between_electrons(image: np.ndarray, usable: np.ndarray, gain: float) -> bool:
    """Whether the image's middle half of levels holds more than twice the ADU values a
    camera of ``gain`` ADU/e- without read noise could output (one in ``gain``); False
    when too few pixels to tell (fewer than 10 per level)."""
    values = np.asarray(image, np.float64)[usable]
    values = values[np.isfinite(values)]
    if values.size == 0:
        return False
    low, high = np.percentile(values, (25, 75))
    levels = math.floor(high) - math.ceil(low) + 1
    inside = values[(values >= low) & (values <= high)]
    if levels < 1 or inside.size < 10 * levels:
        return False
    return np.unique(np.rint(inside)).size / levels > 2.0 / gain


def with_unresolved_dark_noise(
    camera: Camera, image: np.ndarray, valid: np.ndarray | None = None
) -> Camera:
    """``camera`` with a read noise of :data:`MIN_UNRESOLVED_DARK_NOISE_E` where the
    measured one is less and the image (``valid`` pixels) holds levels between whole
    electrons: such a camera's read noise is not resolved, not absent (a camera without
    any would output only multiples of its sensitivity). Else ``camera`` itself; a
    photon-counting camera's image, on the electrons' steps, keeps its own."""
    if camera.dark_noise_e >= MIN_UNRESOLVED_DARK_NOISE_E:
        return camera
    usable = np.ones(np.shape(image), bool) if valid is None else np.asarray(valid, bool)
    usable = usable & ~censored_pixels(np.asarray(image), camera)
    if not _holds_levels_between_electrons(image, usable, camera.sensitivity_adu_per_e):
        return camera
    return dataclasses.replace(camera, dark_noise_e=MIN_UNRESOLVED_DARK_NOISE_E)


def read_noise_unmeasured(camera: Camera) -> bool:
    """Whether a camera measured from an image has the read noise given when none is
    resolved: 0 e-, or :data:`MIN_UNRESOLVED_DARK_NOISE_E` (:func:`with_unresolved_dark_noise`)."""
    return camera.dark_noise_e in (0.0, MIN_UNRESOLVED_DARK_NOISE_E)


def estimate_camera(
    image: np.ndarray,
    *,
    valid: np.ndarray | None = None,
    model_mean: np.ndarray | None = None,
    dark_frames: np.ndarray | None = None,
    camera: Camera | None = None,
    bit_depth: int = 16,
    n_bins: int = 30,
) -> CameraEstimate:
    """Measure the camera's sensitivity, offset and read noise from the data (eq. 17-19).

    Photon transfer (EMVA1288): the variance of a pixel is linear in its mean,
    ``var = K (mean - offset) + sigma_r^2`` (eq. 17). The pixels are grouped into
    equal-count bins of mean level, each bin's variance is taken robustly (edges and
    misfit pixels are outliers), and a weighted line is fitted through the bins.

    * With ``model_mean`` (the fit's noise-free image in ADU, offset included) the
      deviation of each pixel is ``y - mu`` and its level ``mu``.
    * Without a model the deviation is a 3 x 3 high-pass residual of each frame and the
      level the 3 x 3 mean (Foi et al. 2008 in spirit); a series of frames pools them.

    Only the slope ``K`` and the intercept ``c = sigma_r^2 - K offset`` are identifiable
    from images: the offset is taken from ``dark_frames`` (eq. 18, which then also give
    the read noise, eq. 19, through :func:`~napari_symbac.optics.calibrate_camera`),
    else from ``camera.baseline_adu``, else from the darkest region of the image (the
    0.5th percentile of the 5 x 5 local mean, an upper bound when any light reaches it).

    Parameters
    ----------
    image
        2D image or ``(T, Y, X)`` stack in ADU (raw counts: a rescaled or denoised image
        has no photon-transfer line).
    valid
        Optional boolean mask of pixels to use, the image's shape. Censored pixels
        (:func:`censored_pixels`) are always left out.
    model_mean
        Noise-free model image of the same shape (the fit's synthetic image).
    dark_frames
        Frames taken with no light, ``(K, M, N)`` or ``(M, N)``.
    camera
        Known camera settings: their ``baseline_adu`` is used when there are no dark
        frames, and their bit depth for saturation.
    bit_depth
        Digitiser bits of the result when ``camera`` is not given.
    n_bins
        Bins of mean level (fewer when pixels are scarce: at least 200 per bin).

    Returns
    -------
    CameraEstimate

    Raises
    ------
    ValueError
        For mismatched shapes, too few usable pixels or mean levels spanning too
        little range, or a variance that does not grow with the mean (rescaled data).
    """
    stack = _as_stack(image, "image").astype(np.float64)
    shape = stack.shape
    reference = camera if camera is not None else Camera(bit_depth=bit_depth, baseline_adu=0.0)
    usable = ~censored_pixels(np.asarray(image).reshape(shape), reference)
    if valid is not None:
        valid = np.asarray(valid, bool)
        if valid.size != stack.size:
            raise ValueError(
                f"valid has shape {valid.shape} but the image has shape {np.shape(image)}"
            )
        usable &= valid.reshape(shape)
    if model_mean is not None:
        mu = np.asarray(model_mean, np.float64)
        if mu.size != stack.size:
            raise ValueError(
                f"model_mean has shape {mu.shape} but the image has shape {np.shape(image)}"
            )
        mu = mu.reshape(shape)
        if not np.all(np.isfinite(mu)):
            raise ValueError("model_mean contains NaN or infinite values")
        level, deviation = mu[usable], (stack - mu)[usable]
        ratio = math.nan
        method = "model residual"
    else:
        level, deviation, wide, deviation_lag2 = _high_pass_points(stack, usable)
        ratio = _white_noise_ratio(level[wide], deviation[wide], deviation_lag2, n_bins, 200)
        method = "high-pass"
    min_per_bin = 200
    if level.size < 3 * min_per_bin:
        raise ValueError(
            f"only {level.size} usable pixels for photon transfer (need {3 * min_per_bin}): "
            "pass a larger image, more frames, or the camera settings"
        )
    means, variances, errors = _binned_variances(level, deviation, n_bins, min_per_bin)
    if np.ptp(means) <= 3 * math.sqrt(max(float(np.median(variances)), 1e-12)):
        raise ValueError(
            "the image's mean levels span less than 3 noise SDs, so the variance-mean "
            "line is not identifiable: pass the camera settings or dark frames"
        )
    (gain, intercept), covariance, kept = _line_fit(means, variances, errors)
    if not gain > 0:
        raise ValueError(
            f"the pixel variance does not grow with the mean (slope {gain:.3g}): the image "
            "is not raw camera counts (rescaled, denoised or averaged?); pass the camera "
            "settings instead"
        )
    gain_se = math.sqrt(covariance[0, 0])
    if gain < MEASURED_SLOPE_SE * gain_se:
        # found calibrating a 192 x 256 crop of ColiCoords' flattened bright field: slope
        # 0.018 +- 0.091, which put the baseline at the image's level and the cells' light
        # at a third of it
        raise ValueError(
            f"the pixel variance does not grow measurably with the mean (slope {gain:.3g} "
            f"+- {gain_se:.2g} ADU/e-, under {MEASURED_SLOPE_SE:g} standard errors): the "
            "image is not raw camera counts (rescaled, denoised or averaged?) or spans too "
            "few levels; pass the camera settings instead"
        )

    if dark_frames is not None:
        dark = calibrate_camera(dark_frames, gain)
        frames = np.asarray(dark_frames)
        n_dark = frames.size
        offset, offset_se = dark.baseline_adu, dark.dark_noise_adu / math.sqrt(n_dark)
        read_adu = dark.dark_noise_adu
        read_adu_se = read_adu / math.sqrt(2.0 * n_dark)
        dark_noise_e = read_adu / gain
        dark_se = dark_noise_e * math.hypot(read_adu_se / max(read_adu, 1e-12), gain_se / gain)
        source = "dark frames"
        method += " + dark frames"
    else:
        if camera is not None:
            offset, offset_se, source = camera.baseline_adu, math.nan, "camera settings"
        else:
            local = np.concatenate(
                [ndimage.uniform_filter(f, 5)[ok] for f, ok in zip(stack, usable, strict=True)]
            )
            offset, offset_se = max(float(np.percentile(local, 0.5)), 0.0), math.nan
            source = "darkest region of the image"
        read_var = intercept + gain * offset
        if read_var > 0:
            dark_noise_e = math.sqrt(read_var) / gain
            # delta method on sqrt(c + K b) / K with (K, c) from the line fit
            grad = np.array(
                [
                    offset / (2 * gain * math.sqrt(read_var)) - math.sqrt(read_var) / gain**2,
                    1 / (2 * gain * math.sqrt(read_var)),
                ]
            )
            dark_se = math.sqrt(float(grad @ covariance @ grad))
        else:
            dark_noise_e, dark_se = 0.0, math.nan
    result_camera = Camera(
        baseline_adu=max(float(offset), 0.0),
        sensitivity_adu_per_e=float(gain),
        dark_noise_e=float(dark_noise_e),
        bit_depth=reference.bit_depth,
    )
    if dark_frames is None:
        result_camera = with_unresolved_dark_noise(result_camera, stack, usable)
    return CameraEstimate(
        camera=result_camera,
        sensitivity_se_adu_per_e=gain_se,
        baseline_se_adu=float(offset_se),
        dark_noise_se_e=float(dark_se),
        variance_intercept_adu2=float(intercept),
        method=method,
        offset_source=source,
        n_points=int(level.size),
        n_bins=int(kept.sum()),
        neighbour_variance_ratio=ratio,
    )
