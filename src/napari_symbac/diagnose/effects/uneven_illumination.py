"""Uneven illumination (vignetting, a tilted lamp or condenser)."""

from __future__ import annotations

import numpy as np

from napari_symbac.diagnose.effects.base import Confirmation, Effect
from napari_symbac.diagnose.effects.far_from_cells import (
    FAR_FROM_CELLS_PX,
    MIN_FAR_PIXELS,
    far_bins,
)
from napari_symbac.diagnose.model import Geometry, weighted_sum
from napari_symbac.optics.forward import Stage

__all__ = ["UnevenIllumination"]

#: Side (px) of the square tiles of the field whose far-from-cells pixels are averaged:
#: the residual's large-scale part, which a surface of the whole field can explain.
TILE_PX = 8
#: Tiles with far pixels needed to fit the far pixels' own surface (its 5 terms and a
#: level, twice over).
MIN_TILES = 12
#: The surface must vary over those tiles at least this fraction (rms) of its variation
#: over the field's tiles.
MIN_VISIBLE = 0.5
#: The far pixels' own surface may differ from the fitted one, beyond their noise, by
#: less than this fraction (rms) of the fitted surface's change there.
MAX_DISAGREEMENT = 0.5
#: The darkest place of a diagnosed window gets at least this fraction of the brightest
#: place's light: a window is tens of um of a field of view of hundreds, over which a
#: lamp or condenser varies by tens of % (found as a user: ColiCoords ds2 00066's
#: fluorescence window was given a 210 % swing by cells cut at its lower edge).
MIN_LIGHT_RATIO = 0.5

TERMS = ("x", "y", "x^2", "y^2", "xy")


def _basis(yn: np.ndarray, xn: np.ndarray) -> np.ndarray:
    """Low-order surface ``x, y, x^2, y^2, xy`` (centred squares), ``(5, Y, X)``."""
    x2, y2 = xn**2, yn**2
    return np.stack([xn, yn, x2 - x2.mean(), y2 - y2.mean(), xn * yn])


class UnevenIllumination(Effect):
    """The light reaching the sample is not flat: ``mu (1 + sum_k c_k P_k(x, y))``.

    ``P_k`` are the low-order polynomials ``x, y, x^2, y^2, xy`` over the field
    (coordinates scaled to [-1, 1]); ``c`` are fractions of the local brightness.
    """

    name = "uneven_illumination"
    explanation = (
        "The illumination is brighter on one side or in the middle of the field (vignetting, "
        "a tilted lamp or condenser): every pixel, cell or background, is scaled by a smooth "
        "surface."
    )
    signature = "row/column trends of the standardised residual in media and cells alike"

    def __init__(self, geometry: Geometry) -> None:
        super().__init__(geometry)
        self._basis = _basis(geometry.yn, geometry.xn)

    def n_params(self) -> int:
        return 5

    def mean(self, theta, mu, parts, geo):
        return mu * (1.0 + weighted_sum(theta, self._basis))[None]

    def summary(self, theta, mu):
        surface = weighted_sum(theta, self._basis)
        return {
            "peak_to_peak_fraction": float(surface.max() - surface.min()),
            "coefficients": [float(c) for c in theta],
            "terms": list(TERMS),
        }

    def magnitude(self, summary):
        return summary["peak_to_peak_fraction"]

    def confirm(self, theta, residual_adu, valid, mean_adu):
        """One light field must explain the cells and the pixels far from them alike.

        The light multiplies every pixel, so the fitted surface must also explain the
        residual at the pixels :data:`FAR_FROM_CELLS_PX` or more from any cell (PDMS,
        empty media), where the cells' misfit does not reach
        (:mod:`~napari_symbac.diagnose.effects.far_from_cells`), at least in its large
        scale: the far pixels' means over tiles of :data:`TILE_PX` px (the tiles with
        :data:`MIN_FAR_PIXELS` or more), each tile counting alike, their common level
        left out (the base model's media and device intensities set it). On those tile
        means of the residual without the surface the check fits the far pixels' own
        surface (the same 5 terms, acting on the mean without the surface) and compares
        its change there with the fitted surface's change ``c``: confirmed when their
        rms difference ``D``, less the far pixels' noise in it (its expectation ``N^2``,
        from each tile's scatter over its pixel count), is below
        :data:`MAX_DISAGREEMENT` of ``C``, the rms of ``c``: ``D^2 - N^2 < (C / 2)^2``.
        A true field gives ``D^2 ~ N^2``; a surface the far pixels do not show gives
        ``D^2 ~ C^2 + N^2``. On the SyMBac trench the far pixels ask for another surface
        at every step (``D`` 42-53 ADU against ``C`` 42-47 ADU, ``N`` 3 ADU): the fit
        took the cells' and the trench's misfit and drew a bow across the columns that
        the PDMS above the closed end does not have (docs/diagnosis.md, section 2).

        **Cannot be confirmed, so not accepted** (as the column offsets of
        ``fixed_pattern_noise`` whose columns cannot judge them) when the far pixels
        cannot judge the surface: fewer than :data:`MIN_TILES` tiles have them; the
        surface varies over those tiles less than :data:`MIN_VISIBLE` (rms) of its
        variation over the field's tiles (it acts where the cells are); or its change
        there is below their noise (``C < N``, a dim fluorescence background: there the
        comparison above passes a surface the far pixels do not show the more often the
        smaller ``C``, up to even odds). A surface the far pixels cannot judge cannot be
        told from the cells' misfit, which is what a flexible surface takes on the
        held-out pixels when it is not the light, and drawn into a dataset it is wrong
        data that nothing flags. The refusal and its reason are in the report; a user
        who knows the illumination can add the stage to settings.yaml. The price,
        measured on concealed surfaces at 0.3 noise s.d. in a trench (seeds
        2000-2011): of 12 in fluorescence, one refused (``D`` 1.4 against ``C`` 1.3
        ADU, ``N`` 1.1) and one below its noise (``C`` 1.0, ``N`` 1.1), both accepted
        by the diagnosis before this check (``cell_intensity_variability`` instead
        now); of 12 in phase, none.
        """
        theta = np.asarray(theta, float)
        geo = self.geometry
        surface = weighted_sum(theta, self._basis)
        rows, cols = surface.shape
        tiles_x = -(-cols // TILE_PX)
        n_tiles = -(-rows // TILE_PX) * tiles_x
        tile = (np.arange(rows)[:, None] // TILE_PX) * tiles_x + np.arange(cols)[None, :] // TILE_PX
        bins = far_bins(geo, valid, tile, n_tiles)
        judged = int(bins.judged.sum())
        far_px = f"{FAR_FROM_CELLS_PX:g} px or more from any cell"
        numbers: dict[str, float] = {
            "far_from_cells_px": FAR_FROM_CELLS_PX,
            "tile_px": float(TILE_PX),
            "tiles_judged": judged,
            "tiles": n_tiles,
        }
        gain = 1.0 + surface
        if np.any(gain <= 0):
            return Confirmation(
                False,
                "illumination refused: the fitted surface darkens part of the field to "
                "zero or below, which no light does",
                numbers,
            )
        if gain.min() < MIN_LIGHT_RATIO * gain.max():
            return Confirmation(
                False,
                f"illumination refused: the fitted light varies "
                f"{gain.max() / gain.min():.1f}-fold across the {rows} x {cols} px window, "
                "more than a lamp or condenser does across a field of view: the surface "
                "takes up misfit (cells cut at the window's edge, a missing cell) rather "
                "than the light",
                numbers,
            )
        if judged < MIN_TILES:
            return Confirmation(
                False,
                f"illumination cannot be confirmed: only {judged} of {n_tiles} tiles of "
                f"{TILE_PX} px have {MIN_FAR_PIXELS} or more pixels {far_px} (a light "
                "field must show there too)",
                numbers,
            )
        # the surface's large-scale variation where the far pixels are, against the field's
        all_tiles = np.bincount(tile.ravel(), surface.ravel(), n_tiles) / np.bincount(
            tile.ravel(), minlength=n_tiles
        )
        seen = bins.means(surface)
        spread = float(np.mean((all_tiles - all_tiles.mean()) ** 2))
        visible = float(np.sqrt(np.mean((seen - seen.mean()) ** 2) / max(spread, 1e-300)))
        numbers["visible_fraction"] = visible
        if visible < MIN_VISIBLE:
            return Confirmation(
                False,
                f"illumination cannot be confirmed: over the {judged} tiles of {TILE_PX} px "
                f"with pixels {far_px} the surface varies by {visible:.0%} (rms) of its "
                "variation over the field (a light field must show there too)",
                numbers,
            )
        without = mean_adu / gain[None]  # the mean the surface acts on
        change = mean_adu - without
        before = residual_adu + change  # the residual without the surface
        m = bins.means(before)
        c = bins.means(change)
        design = np.stack([bins.means(without * p[None]) for p in self._basis], axis=1)
        m, c, design = m - m.mean(), c - c.mean(), design - design.mean(axis=0)
        u, sv, vt = np.linalg.svd(design, full_matrices=False)
        keep = sv > sv[0] * 1e-9 if sv.size and sv[0] > 0 else np.zeros(sv.size, bool)
        u, sv, vt = u[:, keep], sv[keep], vt[keep]
        own = u @ (u.T @ m)  # the far pixels' own surface (its change at the tiles)
        noise2 = float(np.sum(np.sum(u**2, axis=1) * bins.variances_of_means(before))) / judged
        change_rms = float(np.sqrt(np.mean(c**2)))
        differ = float(np.sqrt(np.mean((own - c) ** 2)))
        noise = float(np.sqrt(noise2))
        excess = float(np.sqrt(max(differ**2 - noise2, 0.0)))
        numbers |= {
            "far_change_rms_adu": change_rms,
            "far_disagreement_rms_adu": differ,
            "far_noise_rms_adu": noise,
            "far_disagreement_beyond_noise_adu": excess,
        }
        if change_rms < noise:
            return Confirmation(
                False,
                f"illumination cannot be confirmed: its change at the pixels {far_px} "
                f"({change_rms:.1f} ADU rms over {judged} tiles of {TILE_PX} px, common "
                f"level left out) is below their noise ({noise:.1f} ADU)",
                numbers,
            )
        coefficients = vt.T @ ((u.T @ m) / sv)  # the far pixels' own surface
        numbers |= {f"far_surface_{t}": float(v) for t, v in zip(TERMS, coefficients)}
        said = (
            f"at the pixels {far_px} ({judged} of {n_tiles} tiles of {TILE_PX} px have "
            f"{MIN_FAR_PIXELS} or more) the surface they ask for differs from the fitted "
            f"one by {differ:.1f} ADU rms (their noise {noise:.1f}) against its change "
            f"there of {change_rms:.1f} ADU rms"
        )
        if excess < MAX_DISAGREEMENT * change_rms:
            return Confirmation(True, f"illumination confirmed far from cells: {said}", numbers)
        return Confirmation(
            False,
            f"illumination does not match the pixels far from cells: {said}: cell/trench "
            "misfit, not the light",
            numbers,
        )


def stage(parameters: dict) -> Stage:
    """Forward-model stage multiplying the clean image by the fitted surface: the
    diagnosis' (5 ``coefficients``), or with an ``order`` the scene fit's surface of
    that degree (:func:`~napari_symbac.fit.illumination.illumination_stage`, which
    ``napari-symbac fit --illumination-order`` writes into its settings.yaml)."""
    if "order" in parameters:
        from napari_symbac.fit.illumination import illumination_stage

        return illumination_stage(parameters["coefficients"], int(parameters["order"]))
    coeffs = np.asarray(parameters["coefficients"], float)

    def apply(image: np.ndarray, scene: object) -> np.ndarray:
        rows, cols = image.shape[-2:]
        yn = np.broadcast_to(np.linspace(-1, 1, rows)[:, None], (rows, cols))
        xn = np.broadcast_to(np.linspace(-1, 1, cols)[None, :], (rows, cols))
        return image * (1.0 + np.tensordot(coeffs, _basis(yn, xn), axes=1)).astype(np.float32)

    return Stage(UnevenIllumination.name, False, dict(parameters), apply)
