"""Stage drift: the field slides between frames."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from napari_symbac.diagnose.effects.base import Effect
from napari_symbac.optics.forward import Stage

__all__ = ["StageDrift"]


def _gradients(mu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    gy, gx = np.gradient(mu, axis=(1, 2))
    return gx, gy


class StageDrift(Effect):
    """A constant velocity ``(v_x, v_y)`` px/frame: ``mu - t (v_x d_x mu + v_y d_y mu)``.

    First order in the shift, which is what a drift hidden below the noise is.
    """

    name = "stage_drift"
    explanation = (
        "The stage (or the chip) creeps steadily between frames, so the same cells sit a "
        "fraction of a pixel further along in each frame."
    )
    signature = "dipoles at cell edges whose sign follows the frame index"
    needs_series = True

    def n_params(self) -> int:
        return 2

    def steps(self, theta):
        return np.full(2, 0.01)

    def mean(self, theta, mu, parts, geo):
        gx, gy = _gradients(mu)
        return mu - geo.t[:, None, None] * (theta[0] * gx + theta[1] * gy)

    def summary(self, theta, mu):
        return {
            "velocity_x_px_per_frame": float(theta[0]),
            "velocity_y_px_per_frame": float(theta[1]),
            "speed_px_per_frame": float(np.hypot(*theta)),
        }

    def magnitude(self, summary):
        return summary["speed_px_per_frame"]


def stage(parameters: dict, frame: int) -> Stage:
    """Stage for frame ``frame``: the clean image shifted by ``frame`` times the velocity."""
    vx = float(parameters["velocity_x_px_per_frame"])
    vy = float(parameters["velocity_y_px_per_frame"])

    def apply(image: np.ndarray, scene: object) -> np.ndarray:
        return ndimage.shift(image, (vy * frame, vx * frame), order=1, mode="nearest")

    return Stage(StageDrift.name, False, {**parameters, "frame": frame}, apply)
