"""Fixed-pattern noise: per-column offsets of the camera (sCMOS column amplifiers)."""

from __future__ import annotations

import numpy as np

from napari_symbac.diagnose.effects.background_texture import MIN_WAVELENGTH_UM
from napari_symbac.diagnose.effects.base import Confirmation, Effect
from napari_symbac.diagnose.effects.far_from_cells import (
    FAR_FROM_CELLS_PX,
    MIN_FAR_PIXELS,
    far_bins,
)
from napari_symbac.diagnose.model import Geometry
from napari_symbac.optics.forward import Stage

__all__ = ["FixedPatternNoise", "column_basis"]

#: The columns that can be judged must carry this share of the offsets' power.
MIN_JUDGED_POWER = 0.5


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

    def confirm(self, theta, residual_adu, valid, mean_adu):
        """Column offsets of the camera must also fit the columns far from the cells.

        A column offset acts on every pixel of its column, so it must explain the column
        means of the residual (before the offsets) at the pixels at least
        :data:`FAR_FROM_CELLS_PX` from any cell, where the cells' misfit does not reach
        (:mod:`~napari_symbac.diagnose.effects.far_from_cells`). Confirmed when
        subtracting the offsets lowers ``sum_x (m_x - o_x)^2``, the squared column means
        ``m_x`` of those pixels, over the columns with :data:`MIN_FAR_PIXELS` or more of
        them; when those columns carry less than :data:`MIN_JUDGED_POWER` of the
        offsets' power the offsets cannot be confirmed. On the SyMBac trench the offsets
        (a smooth wave of 8-10 columns) took the cells' and the walls' misfit and would
        raise that of the far pixels' column means (docs/diagnosis.md, section 6).
        ``mean_adu`` is not needed: the offsets are ``theta``'s.
        """
        offsets = self.column_offsets(theta)
        columns = np.broadcast_to(np.arange(offsets.size), self.geometry.shape[1:])
        bins = far_bins(self.geometry, valid, columns, offsets.size)
        judged = bins.judged
        power = float(np.sum(offsets**2))
        judged_power = float(np.sum(offsets[judged] ** 2))
        numbers = {
            "far_from_cells_px": FAR_FROM_CELLS_PX,
            "columns_judged": int(judged.sum()),
            "columns": int(offsets.size),
            "judged_share_of_offset_power": judged_power / power if power > 0 else 0.0,
        }
        far_px = f"{FAR_FROM_CELLS_PX:g} px or more from any cell"
        if not judged.any() or judged_power < MIN_JUDGED_POWER * power:
            return Confirmation(
                False,
                f"column offsets cannot be confirmed: only {int(judged.sum())} of "
                f"{offsets.size} columns have {MIN_FAR_PIXELS} or more pixels {far_px}, "
                f"with {numbers['judged_share_of_offset_power']:.0%} of the offsets' power "
                "(a camera's offsets must show there too)",
                numbers,
            )
        means = bins.means(residual_adu + offsets[None, None, :])
        own = offsets[judged]
        without = float(np.mean(means**2))
        with_offsets = float(np.mean((means - own) ** 2))
        correlation = float(np.corrcoef(means, own)[0, 1]) if own.std() > 0 else 0.0
        numbers |= {
            "far_column_mean_rms_adu": float(np.sqrt(without)),
            "far_column_misfit_without_offsets_adu2": without,
            "far_column_misfit_with_offsets_adu2": with_offsets,
            "far_column_mean_correlation": correlation,
        }
        said = (
            f"at the pixels {far_px} ({int(judged.sum())} of {offsets.size} columns have "
            f"{MIN_FAR_PIXELS} or more) the offsets take the columns' mean misfit from "
            f"{without:.0f} to {with_offsets:.0f} ADU^2 (correlation {correlation:.2f})"
        )
        if with_offsets < without:
            return Confirmation(True, f"column offsets confirmed far from cells: {said}", numbers)
        return Confirmation(
            False,
            f"column offsets do not match the columns far from cells: {said}: cell/trench "
            "misfit, not the camera",
            numbers,
        )


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
