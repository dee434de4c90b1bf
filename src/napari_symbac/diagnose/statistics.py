"""Discrepancy statistics of the base fit, each with its significance.

All pool the standardised residual ``r = (y - mu) / sqrt(v)`` of the base fit (``v``
the camera variance of eq. 17), which is standard normal, pixel by pixel
independent, where the model is right. Each statistic therefore has an exact null:
a pooled mean of ``n`` pixels is ``N(0, 1/n)``; a sum of ``k`` squared
standardised pooled means is ``chi2(k)``; a mean of ``r^2`` over ``n`` pixels has
s.d. ``sqrt(2 / n)``. The significance is ``-log10 p`` (two-sided for a single
mean), computed from log survival functions so it does not underflow.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from napari_symbac.diagnose.model import Geometry

__all__ = [
    "Mismatch",
    "discrepancy_statistics",
    "neg_log10_p_chi2",
    "neg_log10_p_z",
    "significance_words",
]

LN10 = float(np.log(10.0))


def neg_log10_p_chi2(value: float, dof: int) -> float:
    """``-log10`` of the upper tail of ``chi2(dof)`` at ``value``.

    Far in the tail, where the log survival function underflows, the Wilson-Hilferty
    normal approximation of the chi-square keeps strong effects ranked instead of tied.
    """
    k = max(dof, 1)
    log_sf = float(stats.chi2.logsf(max(value, 0.0), k))
    if not np.isfinite(log_sf):
        z = ((max(value, 0.0) / k) ** (1 / 3) - (1 - 2 / (9 * k))) / np.sqrt(2 / (9 * k))
        log_sf = float(stats.norm.logsf(z))
    return float(-log_sf / LN10)


def neg_log10_p_z(z: float) -> float:
    """``-log10`` of the two-sided normal p-value of ``z``."""
    return float(-(stats.norm.logsf(abs(z)) + np.log(2.0)) / LN10)


def significance_words(neg_log10_p: float) -> str:
    """``-log10 p`` as a report prints it: two decimals below 1000, three significant
    digits from there (found as a user: "149969.40", decimals of a p-value of 1e-149969,
    now "1.5e+05")."""
    return f"{neg_log10_p:.2f}" if abs(neg_log10_p) < 1000 else f"{neg_log10_p:.3g}"


@dataclass(frozen=True)
class Mismatch:
    """One discrepancy statistic: where, what, its value and ``-log10 p``."""

    where: str
    statistic: str
    value: float
    significance: float
    profile: tuple[float, ...] = ()

    def as_dict(self) -> dict:
        return {
            "where": self.where,
            "statistic": self.statistic,
            "value": self.value,
            "significance": self.significance,
        }


def _pooled_chi2(
    r: np.ndarray, groups: np.ndarray, valid: np.ndarray
) -> tuple[float, int, np.ndarray]:
    """Sum over groups of ``n_g mean_g^2`` (chi2 with one dof per group) and the means."""
    g = groups[valid]
    counts = np.bincount(g)
    sums = np.bincount(g, weights=r[valid])
    used = counts > 0
    means = np.where(used, sums / np.maximum(counts, 1), 0.0)
    return float(np.sum(sums[used] ** 2 / counts[used])), int(used.sum()), means


def _trend(r: np.ndarray, coord: np.ndarray, valid: np.ndarray) -> float:
    """z of the regression slope of ``r`` on a coordinate (unit-variance residuals)."""
    c = coord[valid] - coord[valid].mean()
    denom = np.sqrt(np.sum(c**2))
    return float(np.sum(r[valid] * c) / denom) if denom > 0 else 0.0


def discrepancy_statistics(
    r: np.ndarray, mu: np.ndarray, geometry: Geometry, valid: np.ndarray
) -> list[Mismatch]:
    """All statistics of the standardised residual ``r`` (``(T, Y, X)``), strongest first.

    Parameters
    ----------
    r
        Standardised residual of the base fit.
    mu
        Fitted mean (for the intensity-level statistic).
    geometry
        Regions, distances and coordinates.
    valid
        Pixels to use (not clipped, not masked).
    """
    out: list[Mismatch] = []
    d = geometry.distance_px
    n_t, rows, cols = r.shape
    # --- by region
    regions = {
        "cell interior": d < -1.5,
        "cell edge band": (d >= -1.5) & (d < 1.5),
        "media near cells": (d >= 1.5) & (d < 15) & (mu > 0),
        "background far from cells": d >= 15,
    }
    for name, where in regions.items():
        m = where & valid
        n = int(m.sum())
        if n < 10:
            continue
        z = float(r[m].sum() / np.sqrt(n))
        out.append(Mismatch(name, "mean standardised residual x sqrt(n)", z, neg_log10_p_z(z)))
        excess = float((np.mean(r[m] ** 2) - 1.0) / np.sqrt(2.0 / n))
        out.append(
            Mismatch(name, "variance excess z (mean r^2 - 1)", excess, neg_log10_p_z(excess))
        )
    # --- along / across the field
    yy = np.broadcast_to(np.arange(rows)[None, :, None], r.shape)
    xx = np.broadcast_to(np.arange(cols)[None, None, :], r.shape)
    for name, coord in (("along the field (rows)", yy), ("across the field (columns)", xx)):
        z = _trend(r, coord.astype(float), valid)
        out.append(Mismatch(name, "trend z of residual vs position", z, neg_log10_p_z(z)))
        chi2, k, means = _pooled_chi2(r, coord.astype(np.int64), valid)
        out.append(
            Mismatch(
                name, f"chi2 of line means ({k} dof)", chi2, neg_log10_p_chi2(chi2, k), tuple(means)
            )
        )
    # --- distance to the nearest cell edge
    if (d < 0).any():
        bins = np.clip(np.floor(d + 6).astype(np.int64), 0, 26)
        chi2, k, means = _pooled_chi2(r, bins, valid)
        out.append(
            Mismatch(
                "distance to the nearest cell edge (-6..20 px)",
                f"chi2 of 1-px ring means ({k} dof)",
                chi2,
                neg_log10_p_chi2(chi2, k),
                tuple(means),
            )
        )
    # --- spatial frequency: periodogram of r (zero where not valid)
    rr = np.where(valid, r, 0.0)
    power = np.abs(np.fft.fft2(rr - rr.mean(axis=(1, 2), keepdims=True))) ** 2 / valid[0].sum()
    fy = np.fft.fftfreq(rows)[:, None]
    fx = np.fft.fftfreq(cols)[None, :]
    radius = np.hypot(fy, fx)
    for lo, hi, name in ((0.0, 0.05, "low"), (0.05, 0.15, "mid"), (0.15, 0.71, "high")):
        band = (radius > lo) & (radius <= hi)
        m = int(band.sum()) * n_t
        if m < 4:
            continue
        mean_power = float(power[:, band].mean())
        # exponential periodogram ordinates: 2 m * mean ~ chi2(2 m)
        chi2 = 2 * m * mean_power
        out.append(
            Mismatch(
                f"spatial frequency {lo:.2f}-{hi:.2f} cycles/px ({name})",
                "mean periodogram power (1 = white noise)",
                mean_power,
                neg_log10_p_chi2(chi2, 2 * m),
            )
        )
    # --- intensity level: variance vs mean (photon transfer)
    levels = mu[valid]
    edges = np.quantile(levels, np.linspace(0, 1, 9))
    idx = np.clip(np.searchsorted(edges, levels, side="right") - 1, 0, 7)
    r2 = r[valid] ** 2
    counts = np.bincount(idx, minlength=8)
    means = np.bincount(idx, weights=r2, minlength=8) / np.maximum(counts, 1)
    zs = (means - 1.0) / np.sqrt(2.0 / np.maximum(counts, 1))
    chi2 = float(np.sum(zs[counts > 0] ** 2))
    out.append(
        Mismatch(
            "intensity level (8 quantile bins of the mean)",
            "chi2 of variance ratio z-scores (8 dof)",
            chi2,
            neg_log10_p_chi2(chi2, int((counts > 0).sum())),
            tuple(means),
        )
    )
    # --- time
    if n_t > 1:
        tt = np.broadcast_to(geometry.t[:, None, None], r.shape)
        for name, where in (("cells over time", d < 0), ("background over time", d >= 0)):
            m = where & valid
            z = _trend(r, tt.astype(float), m)
            out.append(Mismatch(name, "trend z of residual vs frame", z, neg_log10_p_z(z)))
    out.sort(key=lambda m: -m.significance)
    return out
