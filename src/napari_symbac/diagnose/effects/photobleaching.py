"""Photobleaching: cells fading over a time series."""

from __future__ import annotations

import numpy as np

from napari_symbac.diagnose.effects.base import Effect, gaussian
from napari_symbac.optics.forward import Stage, block_average

__all__ = ["Photobleaching"]


class Photobleaching(Effect):
    """The cells' contribution decays as ``exp(-k t)`` (``t`` in frames from the middle).

    The background is unchanged; ``k`` is the bleaching rate per frame.
    """

    name = "photobleaching"
    explanation = (
        "The fluorophores (or, in phase, the illumination of the cells) fade frame after "
        "frame while the background stays the same."
    )
    signature = "frame means of the cell-pixel residual falling with time, background flat"
    needs_series = True
    # bright field: no fluorophore, and the cells' light is the lamp's, the background's
    modalities = ("phase", "fluorescence")

    def n_params(self) -> int:
        return 1

    def clip(self, theta: np.ndarray) -> np.ndarray:
        """Fading only: a rate below 0 (cells brightening with time) is no bleaching
        (found as a user: a synthetic trench series, flat in time, was "bleached" at
        -0.0033 per frame, 5 ADU over four frames, and accepted)."""
        return np.maximum(theta, 0.0)

    def mean(self, theta, mu, parts, geo):
        factor = np.exp(-theta[0] * geo.t) - 1.0
        return mu + factor[:, None, None] * parts[0]

    def summary(self, theta, mu):
        return {"rate_per_frame": float(theta[0])}


def stage(parameters: dict, frame: int) -> Stage:
    """Stage for frame ``frame``: the cells dimmed by ``exp(-k frame)``.

    Needs ``cell_intensity_adu`` in ``parameters``; the cell contribution is
    approximated by the cell fraction blurred by one pixel.
    """
    rate = float(parameters["rate_per_frame"])
    level = float(parameters.get("cell_intensity_adu", 0.0))

    def apply(image: np.ndarray, scene) -> np.ndarray:
        cells = block_average(scene.interior(scene.cells), scene.upsample)[None]
        cells = gaussian(cells, 1.0)[0] * level
        return (image - (1 - np.exp(-rate * frame)) * cells).astype(np.float32)

    return Stage(Photobleaching.name, False, {**parameters, "frame": frame}, apply)
