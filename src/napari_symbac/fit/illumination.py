"""Uneven illumination as a stage of the scene fit: a smooth surface times the image.

The light reaching the sample is rarely flat (vignetting, a tilted lamp or condenser):
the clean image is ``mu (1 + sum_k c_k P_k(x, y))`` with ``P_k`` low-order
polynomials over the frame (coordinates scaled to [-1, 1], each term centred over
the frame's pixels). It multiplies eq. 3 pixel by pixel, so the intensities stay
linear and are still solved in closed form; the coefficients ``c_k`` are fitted
with the scene (:class:`~napari_symbac.fit.engine.Layout`, ``illumination``).

Order 2 is the surface of the diagnosis' ``uneven_illumination`` effect (terms
``x, y, x^2, y^2, xy`` in that order, the same centring), so its coefficients feed
:func:`napari_symbac.diagnose.stage_for` unchanged; higher orders add the terms of
each degree ``d`` as ``x^d, y^d, x^(d-1) y, ..., x y^(d-1)``.
"""

from __future__ import annotations

import numpy as np

from napari_symbac.optics.forward import Stage

__all__ = ["illumination_basis", "illumination_stage", "illumination_terms"]

#: Highest polynomial degree of the surface (a 256 x 46 trench supports 4 along it).
MAX_ORDER = 6


def _check_order(order: int) -> None:
    if not (isinstance(order, (int, np.integer)) and 0 <= order <= MAX_ORDER):
        raise ValueError(
            f"illumination_order must be an integer from 0 (off) to {MAX_ORDER}, got {order!r}"
        )


def illumination_terms(order: int) -> tuple[str, ...]:
    """Names of the surface's terms up to degree ``order`` (``()`` for 0)."""
    _check_order(order)
    return tuple(_name(px, py) for px, py in _powers(order))


def _name(px: int, py: int) -> str:
    part = [f"x^{px}" if px > 1 else "x"] * (px > 0) + [f"y^{py}" if py > 1 else "y"] * (py > 0)
    return "".join(part)


def _powers(order: int) -> list[tuple[int, int]]:
    out: list[tuple[int, int]] = []
    for degree in range(1, order + 1):
        out += [(degree, 0), (0, degree)]
        out += [(degree - j, j) for j in range(1, degree)]
    return out


def illumination_basis(shape: tuple[int, int], order: int) -> np.ndarray:
    """``(K, Y, X)`` float64 surface terms ``P_k`` of :func:`illumination_terms` order.

    Coordinates run over [-1, 1] across the frame's pixel centres; each term minus
    its mean over the frame, so the coefficients change the shape of the light, not
    its level (which the intensities carry).
    """
    _check_order(order)
    rows, cols = shape
    yn = np.linspace(-1.0, 1.0, rows)[:, None] * np.ones((1, cols))
    xn = np.ones((rows, 1)) * np.linspace(-1.0, 1.0, cols)[None, :]
    terms = [xn**px * yn**py for px, py in _powers(order)]
    if not terms:
        return np.zeros((0, rows, cols))
    basis = np.stack(terms)
    return basis - basis.mean(axis=(1, 2), keepdims=True)


def illumination_stage(coefficients: np.ndarray, order: int) -> Stage:
    """Forward-model stage multiplying the clean image by the fitted surface.

    Parameters
    ----------
    coefficients
        ``c_k`` in the order of :func:`illumination_terms` (fractions of the local
        brightness), e.g. ``SceneFit.illumination``.
    order
        The surface's degree.
    """
    coeffs = np.asarray(coefficients, float)
    if coeffs.shape != (len(illumination_terms(order)),):
        raise ValueError(
            f"order {order} needs {len(illumination_terms(order))} coefficients, got "
            f"{coeffs.shape}"
        )

    def apply(image: np.ndarray, scene: object) -> np.ndarray:
        basis = illumination_basis(image.shape[-2:], order)
        return image * (1.0 + np.tensordot(coeffs, basis, axes=1)).astype(np.float32)

    parameters = {"coefficients": coeffs.tolist(), "order": int(order)}
    return Stage("uneven_illumination", False, parameters, apply)
