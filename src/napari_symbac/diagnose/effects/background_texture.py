"""Texture of the background (agar, debris, uneven PDMS)."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from itertools import islice

import numpy as np

from napari_symbac.diagnose.effects.base import Effect
from napari_symbac.diagnose.model import Geometry, weighted_sum

__all__ = ["BackgroundTexture", "mode_images", "support_modes", "texture_basis", "texture_modes"]

#: Shortest wavelength of the texture basis (um) and the most basis functions.
MIN_WAVELENGTH_UM, MAX_TERMS = 1.5, 48
#: Media pixels the fit needs per texture mode.
PIXELS_PER_MODE = 300
#: A mode is kept only if this fraction of its norm on the support is new
#: (not a combination of the lower-frequency modes already kept).
MIN_NEW_FRACTION = 0.3


def _modes(shape: tuple[int, int], pixel_size_um: float) -> list[tuple[int, int]]:
    rows, cols = shape
    ky_max = max(1, int(2 * rows * pixel_size_um / MIN_WAVELENGTH_UM))
    kx_max = max(1, int(2 * cols * pixel_size_um / MIN_WAVELENGTH_UM))
    modes = [(ky, kx) for ky in range(ky_max + 1) for kx in range(kx_max + 1) if ky + kx > 2]
    modes.sort(key=lambda m: m[0] ** 2 / max(rows, 1) ** 2 + m[1] ** 2 / max(cols, 1) ** 2)
    return modes


def mode_images(shape: tuple[int, int], pixel_size_um: float) -> Iterator[np.ndarray]:
    """The cosine (DCT-II) modes of :func:`texture_basis`, one ``(Y, X)`` image at a time.

    Lazy, because a large field has thousands of modes of which at most ``MAX_TERMS``
    are kept: a 512 x 512 field at 80 nm has 3,000, 6 GB as one array.
    """
    rows, cols = shape
    y = (np.arange(rows) + 0.5) / rows
    x = (np.arange(cols) + 0.5) / cols
    for ky, kx in _modes(shape, pixel_size_um):
        yield np.cos(np.pi * ky * y)[:, None] * np.cos(np.pi * kx * x)[None, :]


def texture_basis(shape: tuple[int, int], pixel_size_um: float) -> np.ndarray:
    """Cosine (DCT-II) modes above second order, wavelength >= 1.5 um: ``(K, Y, X)``.

    Ordered from the lowest spatial frequency up.
    """
    return np.stack(list(mode_images(shape, pixel_size_um)))


def _media_weight(geometry: Geometry) -> np.ndarray:
    return (
        geometry.media_fraction.min(0)
        if geometry.media_fraction is not None
        else np.ones(geometry.shape[1:])
    )


def texture_modes(geometry: Geometry) -> list[tuple[int, int]]:
    """``(ky, kx)`` of the modes the effect fits on ``geometry`` (:func:`support_modes`)."""
    shape = geometry.shape[1:]
    kept = support_modes(mode_images(shape, geometry.pixel_size_um), _media_weight(geometry))
    modes = _modes(shape, geometry.pixel_size_um)
    return [modes[k] for k in kept]


def support_modes(basis: Iterable[np.ndarray], weight: np.ndarray) -> np.ndarray:
    """Indices of the modes the media support can tell apart, lowest frequency first.

    Gram-Schmidt (QR) of the modes weighted by ``weight`` (media fraction away from the
    cells) in frequency order: a mode is kept when at least ``MIN_NEW_FRACTION`` of its
    weighted norm is not explained by the modes kept before it, and at most
    ``min(MAX_TERMS, support pixels / PIXELS_PER_MODE)`` are kept. In a narrow trench
    the media is a thin strip, so modes across the trench add nothing and the strip
    holds only a few modes; an open field keeps ``MAX_TERMS``. ``basis`` is read one
    mode at a time and no further than the last mode kept.
    """
    support = weight > 0.5
    limit = min(MAX_TERMS, int(support.sum()) // PIXELS_PER_MODE)
    if limit < 1:
        return np.zeros(0, np.int64)
    kept: list[int] = []
    q = np.zeros((0, int(support.sum())))
    for k, mode in enumerate(basis):
        col = mode[support] * weight[support]
        norm = float(np.linalg.norm(col))
        if norm == 0:
            continue
        new = col - q.T @ (q @ col)
        new_norm = float(np.linalg.norm(new))
        if new_norm < MIN_NEW_FRACTION * norm:
            continue
        kept.append(k)
        q = np.vstack([q, new / new_norm])
        if len(kept) == limit:
            break
    return np.asarray(kept, np.int64)


class BackgroundTexture(Effect):
    """The media is not uniform: ``mu + P_m sum_k c_k B_k(x, y)``.

    ``P_m B_k`` is the media contribution of the base model with the media multiplied
    by ``B_k`` before the optics (:attr:`Geometry.texture_components`: the texture
    passes through the PSF, and in phase contrast through the ring's filtering, like
    the media; wherever the media shows, also in the blur beside and under the cells;
    without them, a geometry from labels alone, the convolved media times ``B_k``),
    and ``B_k`` cosine modes of wavelength 1.5 um and longer, above the second-order surface of
    ``uneven_illumination`` (so the two do not compete). Only the modes that the
    media pixels can tell apart are fitted (:func:`support_modes`), as many as the
    media area supports (one per ``PIXELS_PER_MODE`` pixels, at most 48): a trench's
    media carries a dozen modes, mostly along the trench, an open field the full set.

    The coefficients are a random field (:attr:`Effect.random_field`): tested by the
    ordinary ``chi2(k)`` score test, fitted by empirical Bayes (the free fit shrunk by
    ``1 - k / |z|^2``), so a dozen modes do not overfit the held-out check. The
    reported amplitude is the s.d. of the relative texture over media pixels (from
    the free fit times ``sqrt`` of the shrinkage: unbiased for the field's power); in
    the settings it becomes ``RenderSettings.texture_amplitude``.
    """

    name = "background_texture"
    random_field = True
    explanation = (
        "The background between the cells is not flat: agar, debris or uneven PDMS make a "
        "blotchy texture that the cells do not share."
    )
    signature = "excess low/mid-frequency power of the residual in media pixels"

    def __init__(self, geometry: Geometry) -> None:
        super().__init__(geometry)
        shape, pixel_um = geometry.shape[1:], geometry.pixel_size_um
        kept = support_modes(mode_images(shape, pixel_um), _media_weight(geometry))
        wanted = set(kept.tolist())
        images = islice(mode_images(shape, pixel_um), int(kept.max(initial=-1)) + 1)
        chosen = [image for k, image in enumerate(images) if k in wanted]
        self._basis = np.array(chosen).reshape(len(kept), *shape)
        self._own = geometry.texture_components
        self._probe, self._probe_value = geometry.media_probe

    def n_params(self) -> int:
        return len(self._basis)

    def mean(self, theta, mu, parts, geo):
        if self._own is None or not len(theta):
            return mu + weighted_sum(theta, self._basis)[None] * parts[1]
        if self._probe_value == 0:
            return mu
        intensity = parts[1].ravel()[self._probe] / self._probe_value
        return mu + intensity * weighted_sum(theta, self._own)

    def summary(self, theta, mu):
        field = weighted_sum(theta, self._basis)
        media = self.geometry.labels[0] == 0
        return {"rms_fraction": float(field[media].std()) if media.any() else 0.0}

    def magnitude(self, summary):
        return summary["rms_fraction"]
