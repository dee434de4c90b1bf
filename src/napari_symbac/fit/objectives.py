"""Objectives that compare a synthetic image with a real one (eq. 20 and better).

Every term is a non-negative, dimensionless number that is 0 for a perfect match;
``docs/fitting.md`` gives the formulas. Two kinds of comparison exist:

* *statistics* (``eq20``, ``class_stats``, ``spectrum``, ``histogram``,
  ``edge_profile``) compare summaries of the two images, so the synthetic scene
  may be a different random arrangement of cells than the real one (the usual
  SyMBac situation);
* the *pixel* term compares the images pixel by pixel and is only meaningful
  when the synthetic scene reproduces the real one (scene fitting,
  :func:`~napari_symbac.fit.fit_scene`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from scipy import ndimage

from napari_symbac.fit.inputs import CLASS_VALUES, as_single_image
from napari_symbac.optics.matching import rotational_spectrum

__all__ = [
    "DEFAULT_TERMS",
    "TERM_NAMES",
    "class_masks",
    "edge_profile",
    "measured_noise_sd_adu",
    "noise_variance",
    "objective_terms",
    "total_objective",
]

#: Every term :func:`objective_terms` knows.
TERM_NAMES = ("eq20", "class_stats", "spectrum", "histogram", "edge_profile", "pixel")
#: Terms (and weights) used when a fit is not told otherwise: the statistics that
#: matter for training data, valid for a synthetic scene unrelated to the real one.
DEFAULT_TERMS: dict[str, float] = {
    "class_stats": 1.0,
    "spectrum": 1.0,
    "histogram": 1.0,
    "edge_profile": 1.0,
}

#: Left edges of the unit-wide signed-distance bins of the edge profile (pixels,
#: negative inside cells): ``[-3, -2), ..., [5, 6)``.
EDGE_BINS_PX = np.arange(-3.0, 6.0, 1.0)
_N_SPECTRUM_BINS = 24
_QUANTILES = np.linspace(0.01, 0.99, 99)

ClassInput = Any  # class map (int array of CLASS_VALUES) or {name: bool mask}


def class_masks(labels_or_masks: ClassInput, shape: tuple[int, int]) -> dict[str, np.ndarray]:
    """Boolean masks ``{"cell", "media", "device"}`` from a class map or a mask dict.

    Parameters
    ----------
    labels_or_masks
        A 2D class map holding :data:`~napari_symbac.fit.CLASS_VALUES` (0 = unpainted)
        or a mapping from class name to a boolean mask.
    shape
        Shape of the image the masks belong to.
    """
    if isinstance(labels_or_masks, Mapping):
        unknown = sorted(set(labels_or_masks) - set(CLASS_VALUES))
        if unknown:
            raise ValueError(f"unknown class name(s) {unknown}; use {sorted(CLASS_VALUES)}")
        masks = {}
        for name, mask in labels_or_masks.items():
            mask = np.asarray(mask, dtype=bool)
            if mask.shape != tuple(shape):
                raise ValueError(
                    f"the {name} mask has shape {mask.shape}, the image {tuple(shape)}"
                )
            masks[name] = mask
        return masks
    classes = np.asarray(labels_or_masks)
    if classes.shape != tuple(shape):
        raise ValueError(
            f"labels of shape {classes.shape} do not match the image of shape {tuple(shape)}"
        )
    return {name: classes == value for name, value in CLASS_VALUES.items()}


def _class_mean_sd(image: np.ndarray, masks: dict[str, np.ndarray]) -> dict[str, tuple]:
    out = {}
    for name, mask in masks.items():
        if mask.sum() >= 2:
            pixels = image[mask]
            out[name] = (float(pixels.mean()), float(pixels.std()))
    return out


def edge_profile(
    image: np.ndarray, masks: dict[str, np.ndarray], bins_px: np.ndarray = EDGE_BINS_PX
) -> np.ndarray | None:
    """Mean intensity against signed distance to the nearest cell boundary.

    The signed distance ``d`` (Euclidean, pixels) is negative inside the ``cell`` mask
    and positive outside; only pixels of the cell and media classes count (the device
    and unpainted pixels are left out). Returns the mean in each unit-wide bin starting
    at ``bins_px``, ``nan`` in bins without pixels (rough strokes that never meet a
    cell's edge leave the bins near 0 empty), or ``None`` without both classes.
    """
    cell = masks.get("cell")
    media = masks.get("media")
    if cell is None or media is None or not cell.any() or not media.any():
        return None
    inside = ndimage.distance_transform_edt(cell)
    outside = ndimage.distance_transform_edt(~cell)
    # Pixel centres: first pixel inside the boundary is at -0.5, first outside at +0.5.
    signed = np.where(cell, -(inside - 0.5), outside - 0.5)
    use = cell | media
    index = np.floor(signed[use] - bins_px[0]).astype(int)
    value = image[use]
    ok = (index >= 0) & (index < bins_px.size)
    total = np.bincount(index[ok], value[ok], minlength=bins_px.size)
    count = np.bincount(index[ok], minlength=bins_px.size)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / np.maximum(count, 1), np.nan)


def noise_variance(image: np.ndarray) -> float:
    """Robust white-noise variance of an image (MAD of a second difference)."""
    d = image[:, 2:] - 2 * image[:, 1:-1] + image[:, :-2]
    mad = np.median(np.abs(d - np.median(d)))
    return float(max((1.4826 * mad) ** 2 / 6.0, 1e-12))


def measured_noise_sd_adu(image: np.ndarray) -> float:
    """The recording's Gaussian pixel noise beyond its quantisation (ADU): the robust
    :func:`noise_variance` less 1/12 ADU^2, 0 below one grey level."""
    return float(np.sqrt(max(noise_variance(image) - 1 / 12, 0.0)))


def objective_terms(
    synthetic: np.ndarray,
    real: np.ndarray,
    labels_or_masks: ClassInput | tuple[ClassInput, ClassInput],
    *,
    terms: tuple[str, ...] | Mapping[str, float] | None = None,
    variance: np.ndarray | float | None = None,
) -> dict[str, float]:
    """Compare a synthetic image with a real one, term by term.

    Parameters
    ----------
    synthetic, real
        2D images in the same units (ADU, baseline included). They may differ in shape
        unless the ``pixel`` term is asked for.
    labels_or_masks
        Class map (values of :data:`~napari_symbac.fit.CLASS_VALUES`) or mapping of
        boolean masks, used for both images; or a pair ``(real_classes,
        synthetic_classes)`` when the two images show different scenes.
    terms
        Names (or ``{name: weight}``) of the terms to compute; default: all that apply
        (``pixel`` only when the shapes agree).
    variance
        Per-pixel noise variance of ``real`` for the ``pixel`` term (a map or a
        number); default: a robust estimate from the real image.

    Returns
    -------
    dict
        ``{name: value}``, each dimensionless and 0 for a perfect match; ``nan`` where
        a term cannot be computed (a class missing, no cell edge in the labels).

    Notes
    -----
    With ``I_k`` the real mean of class ``k`` (eq. 2), ``S_k`` and ``s_k`` the mean and
    standard deviation of the synthetic image over its class-``k`` mask:

    * ``eq20 = sum_k |I_k - S_k| / I_k`` (eq. 20 of the supplement);
    * ``class_stats = sum_k ((S_k - I_k) / I_k)^2 + ((s_k - r_k) / r_k)^2``, with
      ``r_k`` the real standard deviation;
    * ``spectrum = mean_f (log10 P_syn(f) - log10 P_real(f))^2`` over the rotationally
      averaged power spectrum (24 radial bins in cycles per pixel, DC left out);
    * ``histogram = mean_q |Q_syn(q) - Q_real(q)| / (Q_real(0.95) - Q_real(0.05))``
      over the quantiles ``q = 0.01 .. 0.99`` (a normalised 1-Wasserstein distance);
    * ``edge_profile = rms_d (E_syn(d) - E_real(d)) / |I_media - I_cell|``, ``E(d)`` the
      mean intensity at signed distance ``d`` from the cell boundary (see
      :func:`edge_profile`), over the distance bins that both images fill; with
      fewer than 3 such bins (rough strokes that never meet a cell's edge) it falls
      back to the error of the edge's contrast, ``|(S_media - S_cell) - (I_media -
      I_cell)| / |I_media - I_cell|``, so it is defined whenever both classes are;
    * ``pixel = mean((syn - real)^2 / variance)`` (1 for a perfect model at the noise).
    """
    syn = as_single_image(synthetic, name="synthetic")
    ref = as_single_image(real, name="real")
    if isinstance(labels_or_masks, tuple) and len(labels_or_masks) == 2:
        real_masks = class_masks(labels_or_masks[0], ref.shape)
        syn_masks = class_masks(labels_or_masks[1], syn.shape)
    else:
        real_masks = class_masks(labels_or_masks, ref.shape)
        syn_masks = class_masks(labels_or_masks, syn.shape) if syn.shape == ref.shape else None
        if syn_masks is None:
            raise ValueError(
                f"the synthetic image {syn.shape} and the real one {ref.shape} differ in shape: "
                "give labels_or_masks as a pair (real_classes, synthetic_classes)"
            )
    if terms is None:
        names = [t for t in TERM_NAMES if t != "pixel" or syn.shape == ref.shape]
    else:
        names = list(terms)
        unknown = sorted(set(names) - set(TERM_NAMES))
        if unknown:
            raise ValueError(f"unknown objective term(s) {unknown}; choose from {TERM_NAMES}")
    out: dict[str, float] = {}
    real_stats = _class_mean_sd(ref, real_masks)
    syn_stats = _class_mean_sd(syn, syn_masks)
    shared = [k for k in real_stats if k in syn_stats]
    for name in names:
        value = np.nan
        if name == "eq20" and shared:
            value = sum(
                abs(real_stats[k][0] - syn_stats[k][0]) / max(abs(real_stats[k][0]), 1e-12)
                for k in shared
            )
        elif name == "class_stats" and shared:
            value = sum(
                ((syn_stats[k][0] - real_stats[k][0]) / max(abs(real_stats[k][0]), 1e-12)) ** 2
                + ((syn_stats[k][1] - real_stats[k][1]) / max(real_stats[k][1], 1e-12)) ** 2
                for k in shared
            )
        elif name == "spectrum":
            ps = rotational_spectrum(syn, _N_SPECTRUM_BINS)[1:]
            pr = rotational_spectrum(ref, _N_SPECTRUM_BINS)[1:]
            ok = (ps > 0) & (pr > 0)
            if ok.any():
                value = float(np.mean((np.log10(ps[ok]) - np.log10(pr[ok])) ** 2))
        elif name == "histogram":
            qs = np.quantile(syn, _QUANTILES)
            qr = np.quantile(ref, _QUANTILES)
            spread = max(float(qr[94] - qr[4]), 1e-12)
            value = float(np.mean(np.abs(qs - qr)) / spread)
        elif name == "edge_profile":
            er = edge_profile(ref, real_masks)
            es = edge_profile(syn, syn_masks)
            if er is not None and es is not None and {"cell", "media"} <= set(shared):
                contrast = max(abs(real_stats["media"][0] - real_stats["cell"][0]), 1e-12)
                both = np.isfinite(er) & np.isfinite(es)
                if both.sum() >= 3:
                    value = float(np.sqrt(np.mean((es[both] - er[both]) ** 2)) / contrast)
                else:
                    syn_contrast = syn_stats["media"][0] - syn_stats["cell"][0]
                    real_contrast = real_stats["media"][0] - real_stats["cell"][0]
                    value = abs(syn_contrast - real_contrast) / contrast
        elif name == "pixel":
            if syn.shape != ref.shape:
                raise ValueError(
                    f"the pixel term needs images of one shape, got {syn.shape} and {ref.shape}"
                )
            var = noise_variance(ref) if variance is None else np.asarray(variance, float)
            value = float(np.mean((syn - ref) ** 2 / np.maximum(var, 1e-12)))
        out[name] = float(value)
    return out


def total_objective(terms: Mapping[str, float], weights: Mapping[str, float]) -> float:
    """Weighted sum of the finite terms, ``sum_k w_k T_k`` (nan terms are left out)."""
    return float(
        sum(weights.get(k, 0.0) * v for k, v in terms.items() if np.isfinite(v) and k in weights)
    )
