"""Texture of the background (agar, debris, uneven PDMS)."""

from __future__ import annotations

import numpy as np

from napari_symbac.diagnose.effects.base import Effect
from napari_symbac.diagnose.model import Geometry

__all__ = ["BackgroundTexture", "texture_basis"]

#: Shortest wavelength of the texture basis (um) and the most basis functions.
MIN_WAVELENGTH_UM, MAX_TERMS = 1.5, 48
#: Pixels closer than this to a cell edge carry no texture term.
AWAY_PX = 2.5


def texture_basis(shape: tuple[int, int], pixel_size_um: float) -> np.ndarray:
    """Cosine (DCT-II) modes above second order, wavelength >= 1.5 um: ``(K, Y, X)``."""
    rows, cols = shape
    ky_max = max(1, int(2 * rows * pixel_size_um / MIN_WAVELENGTH_UM))
    kx_max = max(1, int(2 * cols * pixel_size_um / MIN_WAVELENGTH_UM))
    modes = [(ky, kx) for ky in range(ky_max + 1) for kx in range(kx_max + 1) if ky + kx > 2]
    modes.sort(key=lambda m: m[0] ** 2 / max(rows, 1) ** 2 + m[1] ** 2 / max(cols, 1) ** 2)
    modes = modes[:MAX_TERMS]
    y = (np.arange(rows) + 0.5) / rows
    x = (np.arange(cols) + 0.5) / cols
    return np.stack(
        [np.cos(np.pi * ky * y)[:, None] * np.cos(np.pi * kx * x)[None, :] for ky, kx in modes]
    )


class BackgroundTexture(Effect):
    """The media is not uniform: ``mu + P_m sum_k c_k B_k(x, y)``.

    ``P_m`` is the media contribution more than 2.5 px from any cell and ``B_k``
    cosine modes of wavelength 1.5 um
    and longer, above the second-order surface of ``uneven_illumination`` (so the
    two do not compete). The reported amplitude is the s.d. of the fitted relative
    texture over media pixels; in the settings it becomes
    ``RenderSettings.texture_amplitude``.
    """

    name = "background_texture"
    explanation = (
        "The background between the cells is not flat: agar, debris or uneven PDMS make a "
        "blotchy texture that the cells do not share."
    )
    signature = "excess low/mid-frequency power of the residual in media pixels"

    def __init__(self, geometry: Geometry) -> None:
        super().__init__(geometry)
        self._basis = texture_basis(geometry.shape[1:], geometry.pixel_size_um)
        # away from cell edges, so that edge dipoles (curvature, drift) are not texture
        self._away = (geometry.distance_px > AWAY_PX).astype(np.float64)

    def n_params(self) -> int:
        return len(self._basis)

    def mean(self, theta, mu, parts, geo):
        return mu + np.tensordot(theta, self._basis, axes=1)[None] * parts[1] * self._away

    def summary(self, theta, mu):
        field = np.tensordot(theta, self._basis, axes=1)
        media = self.geometry.labels[0] == 0
        return {"rms_fraction": float(field[media].std()) if media.any() else 0.0}

    def magnitude(self, summary):
        return summary["rms_fraction"]
