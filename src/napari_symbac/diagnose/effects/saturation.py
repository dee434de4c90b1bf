"""Saturation / clipping of the recorded values."""

from __future__ import annotations

import numpy as np
from scipy import special, stats

from napari_symbac.diagnose.effects.base import Effect
from napari_symbac.diagnose.model import Censor
from napari_symbac.optics.forward import Stage

__all__ = ["Saturation", "detect"]


class Saturation(Effect):
    """Values beyond a level were recorded as that level (censoring).

    Detected by the count of pixels at the image's extreme value against the count
    the fitted model expects in that one-ADU bin (a Poisson test of the spike); fitted as a censored
    likelihood (clipped pixels contribute ``P(Y >= level)``).
    """

    name = "saturation"
    explanation = (
        "Pixels brighter than the camera's (or a later processing step's) ceiling were "
        "clipped to it; or, after background subtraction, values below zero were set to zero."
    )
    signature = "a spike in the histogram at the image maximum (or minimum)"
    kind = "censor"

    def n_params(self) -> int:
        return 1

    def summary(self, theta, mu):
        return {"clip_level_adu": float(theta[0])}


def detect(y: np.ndarray, mu: np.ndarray, v: np.ndarray) -> tuple[Censor | None, float, float]:
    """Most significant clipping side: ``(censor, -log10 p, observed fraction)``.

    ``y`` and ``mu`` are above the baseline; the p-value is that of the observed
    count at the extreme under a Poisson law with the model's expected count.
    """
    best: tuple[Censor | None, float, float] = (None, 0.0, 0.0)
    for high in (True, False):
        level = float(y.max() if high else y.min())
        censor = Censor(level, high)
        clipped = censor.mask(y)
        count = int(clipped.sum())
        if count < 2:
            continue
        # expected count in the one-ADU bin of the extreme value (a spike, not a tail)
        sd = np.sqrt(v)
        lo, hi = (level - 0.5 - mu) / sd, (level + 0.5 - mu) / sd
        expected = float(np.sum(special.ndtr(hi) - special.ndtr(lo)))
        # the extreme value holds at least one pixel by construction: test the others
        mean = max(expected, 1e-12)
        log_p = stats.poisson.logsf(count - 2, mean)
        if not np.isfinite(log_p):  # far tail: Chernoff bound, so strong spikes stay ranked
            k = count - 1
            log_p = -(k * np.log(k / mean) - k + mean)
        evidence = float(-log_p / np.log(10))
        if evidence > best[1]:
            best = (censor, evidence, count / y.size)
    return best


def stage(parameters: dict) -> Stage:
    """Forward-model stage clipping the recorded image (after the camera's noise, as the
    camera or a background subtraction clipped the recording) at the fitted level (ADU,
    baseline included): a spike of pixels at that value, as in the recording. (Clipping
    the clean image before the noise, as this stage did, left no spike.)"""
    level = round(float(parameters["clip_level_adu"]))
    high = bool(parameters.get("high", True))

    def apply(image: np.ndarray, scene: object) -> np.ndarray:
        return np.minimum(image, level) if high else np.maximum(image, level)

    return Stage(Saturation.name, False, dict(parameters), apply, recorded=True)
