"""Fixed-pattern noise: per-column offsets of the camera (sCMOS column amplifiers)."""

from __future__ import annotations

import numpy as np

from napari_symbac.diagnose.effects.base import Effect
from napari_symbac.diagnose.model import Geometry
from napari_symbac.optics.forward import Stage

__all__ = ["FixedPatternNoise"]


class FixedPatternNoise(Effect):
    """Each camera column adds its own offset ``o_x`` (ADU), the same in every frame.

    The offsets are centred (their mean is the media intensity's business). They are
    a random field (:attr:`Effect.random_field`): one small exchangeable draw per
    column, fitted by empirical Bayes (the free fit shrunk by ``1 - k / |z|^2``), so
    forty-odd offsets do not pay one free parameter each on held-out pixels. The
    reported rms is the free fit's times the square root of the shrinkage.
    """

    name = "fixed_pattern_noise"
    random_field = True
    explanation = (
        "The camera adds a slightly different offset to each column of pixels (column "
        "amplifiers of sCMOS sensors): faint vertical stripes, identical in every frame."
    )
    signature = "column means of the residual scattered more than the noise allows"

    def __init__(self, geometry: Geometry) -> None:
        super().__init__(geometry)
        self._cols = geometry.shape[2]

    def n_params(self) -> int:
        return self._cols

    def steps(self, theta):
        return np.ones(len(theta))

    def mean(self, theta, mu, parts, geo):
        return mu + (theta - theta.mean())[None, None, :]

    def summary(self, theta, mu):
        offsets = theta - theta.mean()
        return {
            "rms_column_offset_adu": float(offsets.std()),
            "column_offsets_adu": [round(float(o), 3) for o in offsets],
        }

    def magnitude(self, summary):
        return summary["rms_column_offset_adu"]


def stage(parameters: dict) -> Stage:
    """Forward-model stage adding the fitted column offsets."""
    offsets = np.asarray(parameters["column_offsets_adu"], np.float32)

    def apply(image: np.ndarray, scene: object) -> np.ndarray:
        if image.shape[-1] != offsets.size:
            raise ValueError(
                f"fixed_pattern_noise was fitted on {offsets.size} columns, the image has "
                f"{image.shape[-1]}: re-run the diagnosis on images of this size"
            )
        return image + offsets[None, :]

    return Stage(FixedPatternNoise.name, False, dict(parameters), apply)
