"""A fluorescence background clipped at zero, drawn as the recording shows it.

Background subtraction before a recording is saved sets negative values to 0 (the
ColiCoords fields: 19 % of all pixels at 0). The fit leaves those pixels out
(:func:`~napari_symbac.fit.camera_estimate.censored_pixels`), so the media level it finds
is the mean of the pixels above zero, too high, and the camera's read noise, measured on
pixels that clipping has thinned, too low; a dataset rendered with them has a brighter,
smoother background than the recording and no spike at 0 (on ColiCoords field 1: median
42 against 26 ADU, 2-3 % of pixels at 0 against 19 %).

Here the background is fitted as what it is, a censored normal sample: pixels at the
clip level contribute ``P(Y <= level)``, those above it their density (a Tobit model);
the brightest 5 % (debris, out-of-focus cells) are left out and the rest is taken as
truncated there, so that no outlier sets the spread. Its mean becomes the media
intensity, its variance beyond the camera's shot noise the read noise, and the clip a
``saturation`` stage on the recorded values
(:func:`napari_symbac.diagnose.effects.saturation.stage`), so that the dataset's
background has the recording's level, spread and spike at 0.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from scipy import ndimage, optimize, special

from napari_symbac.settings import Camera, ExtraStage, PipelineSettings, RenderSettings

__all__ = [
    "BACKGROUND_MARGIN_PX",
    "MIN_CLIPPED_FRACTION",
    "ClippedBackground",
    "clip_stage",
    "clipped_background",
    "clipped_render",
    "drawn_clipped",
    "fitted_clip",
    "with_clip",
]

#: Fraction of the background pixels at the image minimum from which the background is
#: taken as clipped.
MIN_CLIPPED_FRACTION = 0.01
#: Pixels within this distance of a cell are not background (the PSF's reach).
BACKGROUND_MARGIN_PX = 6
#: Quantile of the background above which pixels are left out (debris; the sample is
#: taken as truncated there).
_UPPER_QUANTILE = 0.95


@dataclass(frozen=True)
class ClippedBackground:
    """The background of a recording clipped at its minimum (ADU, baseline included).

    Attributes
    ----------
    level_adu
        The value the clipping set (the image minimum, 0 after background subtraction).
    fraction
        Fraction of the background pixels at that value.
    mean_adu, sd_adu
        Mean and standard deviation of the background before the clipping (the censored
        maximum-likelihood estimate).
    """

    level_adu: float
    fraction: float
    mean_adu: float
    sd_adu: float


def clipped_background(
    image: np.ndarray, cells: np.ndarray, censored: np.ndarray
) -> ClippedBackground | None:
    """The clipped background of a fluorescence frame, or None when it is not clipped.

    Parameters
    ----------
    image
        The recording (ADU), one 2D frame.
    cells
        Boolean mask of the cells (fitted or given); pixels within
        :data:`BACKGROUND_MARGIN_PX` of them are left out.
    censored
        The censored pixels (:func:`~napari_symbac.fit.camera_estimate.censored_pixels`):
        those at the image minimum are the clipped ones.

    Returns
    -------
    ClippedBackground or None
        None when fewer than :data:`MIN_CLIPPED_FRACTION` of the background pixels
        are clipped at the minimum, or when there are too few background pixels.
    """
    image = np.asarray(image, np.float64)
    near = ndimage.binary_dilation(np.asarray(cells, bool), iterations=BACKGROUND_MARGIN_PX)
    background = ~near & np.isfinite(image)
    values = image[background]
    if values.size < 100:
        return None
    level = float(np.min(image))
    low = (censored & (image == level))[background]
    fraction = float(low.mean())
    if fraction < MIN_CLIPPED_FRACTION:
        return None
    top = float(np.quantile(values, _UPPER_QUANTILE))
    high = values >= top
    seen = values[~low & ~high]
    if seen.size < 10 or top <= level:
        return None
    n_low, n_kept = int(low.sum()), int((~high).sum())

    def negative_log_likelihood(p: np.ndarray) -> float:
        mean, sd = p[0], math.exp(p[1])
        z = (seen - mean) / sd
        nll = 0.5 * float(np.sum(z * z)) + seen.size * p[1]
        nll -= n_low * float(special.log_ndtr((level + 0.5 - mean) / sd))
        # the pixels above ``top`` are left out: the others are a sample truncated there
        nll += n_kept * float(special.log_ndtr((top - 0.5 - mean) / sd))
        return nll

    start = np.array([float(np.mean(seen)), math.log(max(float(np.std(seen)), 1e-3))])
    best = optimize.minimize(negative_log_likelihood, start, method="Nelder-Mead",
                             options={"xatol": 1e-4, "fatol": 1e-6, "maxiter": 2000})  # fmt: skip
    return ClippedBackground(level, fraction, float(best.x[0]), math.exp(float(best.x[1])))


def clipped_render(
    render: RenderSettings, camera: Camera, clipped: ClippedBackground, *, noise: bool = True
) -> tuple[RenderSettings, Camera, str]:
    """``render`` and ``camera`` whose images have the background of ``clipped`` before
    its clipping, and a sentence.

    The media intensity becomes the background's mean above the camera baseline, and
    (with ``noise``; not for a camera the user gave) the noise beyond the shot noise of
    that level the camera's read noise (the Gaussian noise's s.d. for ``noise_model:
    gaussian``). :func:`clip_stage` then clips them.
    """
    media = max(clipped.mean_adu - camera.baseline_adu, 0.0)
    said = ""
    if noise and render.noise_model == "camera":
        gain = camera.sensitivity_adu_per_e
        read_variance = clipped.sd_adu**2 - gain * media
        if read_variance > 0:
            camera = dataclasses.replace(camera, dark_noise_e=math.sqrt(read_variance) / gain)
            said = f", read noise {camera.dark_noise_e:.2f} e- (the spread beyond shot noise)"
    elif noise and render.noise_model == "gaussian":
        render = dataclasses.replace(render, gaussian_noise_sd_adu=clipped.sd_adu)
        said = f", Gaussian noise {clipped.sd_adu:.1f} ADU"
    sentence = (
        f"background clipped at {clipped.level_adu:g} ADU ({100 * clipped.fraction:.1f} % of "
        f"the background pixels; background subtraction): fitted as censored, mean "
        f"{clipped.mean_adu:.1f} ADU, s.d. {clipped.sd_adu:.1f} (the fit without the clipped "
        f"pixels: media {render.media_intensity:.1f} ADU above the baseline); drawn with media "
        f"{media:.1f} ADU{said} and the recorded values clipped at {clipped.level_adu:g} ADU"
    )
    return dataclasses.replace(render, media_intensity=media), camera, sentence


def clip_stage(clipped: ClippedBackground) -> ExtraStage:
    """The ``saturation`` stage that clips the recorded values as the recording was."""
    return ExtraStage("saturation", {"clip_level_adu": clipped.level_adu, "high": False})


def with_clip(stages: Iterable[ExtraStage], clipped: ClippedBackground) -> tuple[ExtraStage, ...]:
    """``stages`` with :func:`clip_stage` of ``clipped`` in place of any low
    ``saturation`` stage they had (last, so that it clips the recorded values); a clip
    at the top (a saturated camera, which diagnose may accept) is kept."""

    def low_clip(stage: ExtraStage) -> bool:
        return stage.name == "saturation" and not bool(stage.parameters.get("high", True))

    return (*(s for s in stages if not low_clip(s)), clip_stage(clipped))


def fitted_clip(
    frame: np.ndarray, scene, camera: Camera | None, modality: str
) -> ClippedBackground | None:
    """:func:`clipped_background` of a fluorescence ``frame`` around the cells of its
    fitted ``scene`` (``None`` in other modalities): what ``fit``, ``diagnose`` and the
    Diagnose dock draw their settings' background with (found as a user: diagnose's
    settings.yaml kept the fit's unclipped media level, and its export had 2.5 % of
    pixels at 0 against the recording's 19.5 %, median 45 against 28 ADU)."""
    from napari_symbac.fit.camera_estimate import censored_pixels

    if modality != "fluorescence":
        return None
    cells = scene.camera_labels() > 0
    return clipped_background(frame, cells, censored_pixels(frame, camera))


def drawn_clipped(
    settings: PipelineSettings, clipped: ClippedBackground, *, noise: bool = True
) -> tuple[PipelineSettings, str]:
    """``settings`` whose renders have the background of ``clipped`` (:func:`clipped_render`
    and :func:`clip_stage`, in place of any clipping they had), and a sentence."""
    render, camera, sentence = clipped_render(
        settings.render, settings.camera, clipped, noise=noise
    )
    stages = with_clip(settings.extra_stages, clipped)
    drawn = dataclasses.replace(settings, render=render, camera=camera, extra_stages=stages)
    return drawn, sentence
