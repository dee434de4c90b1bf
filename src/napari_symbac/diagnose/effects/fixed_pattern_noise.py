"""Fixed-pattern noise: per-column offsets of the camera (sCMOS column amplifiers)."""

from __future__ import annotations

import numpy as np

from napari_symbac.diagnose.effects.background_texture import MIN_WAVELENGTH_UM
from napari_symbac.diagnose.effects.base import Effect
from napari_symbac.diagnose.model import Geometry
from napari_symbac.optics.forward import Stage

__all__ = ["FixedPatternNoise", "column_basis"]


def column_basis(cols: int, pixel_size_um: float) -> np.ndarray:
    """``(cols, K)`` orthonormal column patterns that a camera's offsets may take.

    The cosine (DCT-II) modes of the columns above the lowest: a mode of wavelength
    1.5 um or longer (:data:`~.background_texture.MIN_WAVELENGTH_UM`), and always the
    constant, tilt and bow, is a smooth trend across the field, which
    ``uneven_illumination`` and ``background_texture`` describe. Column amplifiers are
    independent of each other, so their offsets spread over all frequencies and lose
    only those few modes' share of their power (4 of 46 columns of a 65 nm trench, 28
    of 256 at 80 nm). Without that split a smooth column profile could be fitted by the
    offsets in the cells and cancelled by the texture in the media, so that the
    offsets absorbed the cells' misfit: +-300 ADU offsets on a ColiCoords field whose
    background columns are flat to 9 ADU.
    """
    lowest = max(2, int(2 * cols * pixel_size_um / MIN_WAVELENGTH_UM))
    k = np.arange(lowest + 1, cols)
    x = (np.arange(cols) + 0.5) / cols
    return np.sqrt(2.0 / cols) * np.cos(np.pi * x[:, None] * k[None, :])


class FixedPatternNoise(Effect):
    """Each camera column adds its own offset ``o_x`` (ADU), the same in every frame.

    The offsets are combinations of :func:`column_basis` (column-to-column structure;
    the mean and smooth trends are the media's and the illumination's business). They
    are a random field (:attr:`Effect.random_field`): one small exchangeable draw per
    mode, fitted by empirical Bayes (the free fit shrunk by ``1 - k / |z|^2``), so
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
        self._basis = column_basis(geometry.shape[2], geometry.pixel_size_um)

    def n_params(self) -> int:
        return self._basis.shape[1]

    def steps(self, theta):
        return np.ones(len(theta))

    def column_offsets(self, theta: np.ndarray) -> np.ndarray:
        """The offset of each column (ADU) for the mode coefficients ``theta``."""
        return self._basis @ np.asarray(theta, float)

    def mean(self, theta, mu, parts, geo):
        return mu + self.column_offsets(theta)[None, None, :]

    def summary(self, theta, mu):
        offsets = self.column_offsets(theta)
        return {
            "rms_column_offset_adu": float(offsets.std()),
            "column_offsets_adu": [round(float(o), 3) for o in offsets],
        }

    def magnitude(self, summary):
        return summary["rms_column_offset_adu"]


def stage(parameters: dict) -> Stage:
    """Forward-model stage adding the fitted column offsets.

    An image of as many columns as the diagnosed one gets exactly those offsets. A
    narrower image gets the first of them and a wider one the offsets repeated (an
    exported frame the size of a simulation, not of the diagnosed window): stripes of
    the fitted size and pattern, where the sensor's own columns beyond the window are
    unknown.
    """
    offsets = np.asarray(parameters["column_offsets_adu"], np.float32)
    if offsets.ndim != 1 or offsets.size == 0:
        raise ValueError("column_offsets_adu must be a list of one offset per column")

    def apply(image: np.ndarray, scene: object) -> np.ndarray:
        cols = image.shape[-1]
        return image + np.tile(offsets, -(-cols // offsets.size))[None, :cols]

    return Stage(FixedPatternNoise.name, False, dict(parameters), apply)
