"""Debris: unlabelled out-of-focus particles in the medium of a field.

Real agar-pad fields hold small dim blobs that are not cells (dust, fluorescent
particles, vesicles, out-of-focus debris) and that no annotation marks. A network
trained on clean synthetic pads calls each of them a cell (issue 14, docs/proof.md).
:func:`add_debris` puts such particles into the scene as material of the cells'
optical kind (eq. 3: a particle adds ``b (I_c - I_m)`` at its centre; in phase
contrast it is a weak phase object like a thin cell) but never into the labels, so it
is imaged through the same PSF, defocus and camera and is absent from every mask.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy import ndimage

__all__ = ["add_debris", "debris_rng", "lognormal", "particle_image"]


def debris_rng(seed: int) -> np.random.Generator:
    """The generator of a simulation's debris, ``default_rng(SeedSequence([seed, 3]))``:
    a new one per frame gives the same particles on every frame (the pad's debris
    does not move; particles under a cell are hidden)."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), 3]))


def lognormal(rng: np.random.Generator, median: float, cv: float, size: int) -> np.ndarray:
    """``size`` log-normal draws of the given median and coefficient of variation."""
    if cv == 0:
        return np.full(size, float(median))
    sigma = math.sqrt(math.log1p(cv * cv))
    return median * np.exp(sigma * rng.standard_normal(size))


def particle_image(radius_px: float, blur_px: float) -> np.ndarray:
    """A disk of ``radius_px`` (area-weighted edge) blurred by a Gaussian of ``blur_px``,
    peak of the unblurred disk 1, on a square patch that holds its tails."""
    half = math.ceil(radius_px + 4 * blur_px + 1)
    yy, xx = np.mgrid[-half : half + 1, -half : half + 1]
    disk = np.clip(radius_px + 0.5 - np.hypot(yy, xx), 0.0, 1.0)
    if blur_px > 0:
        disk = ndimage.gaussian_filter(disk, blur_px, mode="constant")
    return disk.astype(np.float32)


def add_debris(scene: Any, render: Any, rng: np.random.Generator) -> Any:
    """Scatter out-of-focus particles over the medium of ``scene`` (module notes).

    Parameters
    ----------
    scene
        The :class:`~napari_symbac.scene.Scene` of one frame.
    render
        :class:`~napari_symbac.settings.RenderSettings`: ``debris_density_per_100um2``
        (a Poisson count over the whole render field, places uniform; those that fall
        on a cell are hidden, so the density holds outside the cells),
        ``debris_diameter_um`` / ``_cv``, ``debris_brightness`` / ``_cv`` (log-normal)
        and ``debris_defocus_sigma_um`` (Gaussian blur of eq. 14 on each particle).
        The drawn brightness ``b`` is that of a particle of the median diameter
        ``d_m``; a particle of diameter ``d`` has ``b (d_m / d)^2``: every particle
        carries the light its draw gives whatever its size, a larger one spreads it.
        (ColiCoords' field 3 shows blobs of 0.2-1.1 um all 80-180 ADU above the pad;
        with ``b`` alone the tail of the diameter draw made 1-1.2 um particles as bright
        as the cells, unlabelled cell-sized blobs.)
    rng
        Every draw (count, places, sizes, brightnesses) comes from it, in that order.

    Returns
    -------
    Scene
        ``scene`` itself when the density is 0 (nothing drawn, bit-identical images);
        otherwise a copy with the particles moved from ``media`` into ``cells`` (the
        fractions still sum to 1) and the same ``labels``. Particles are centred
        outside every cell.
    """
    density = float(render.debris_density_per_100um2)
    if density == 0:
        return scene
    px = float(scene.pixel_size_um)
    free = np.asarray(scene.labels) == 0
    area_um2 = float(free.size) * px * px  # the whole field: the same draws every frame
    n = int(rng.poisson(density * area_um2 / 100.0))
    if n == 0:
        return scene
    rows, cols = free.shape
    centres = rng.integers(0, (rows, cols), size=(n, 2))
    diameters = lognormal(rng, render.debris_diameter_um, render.debris_diameter_cv, n)
    peaks = lognormal(rng, render.debris_brightness, render.debris_brightness_cv, n)
    peaks *= (float(render.debris_diameter_um) / diameters) ** 2  # the same light
    keep = free[centres[:, 0], centres[:, 1]]
    blur_px = float(render.debris_defocus_sigma_um) / px
    material = np.zeros(free.shape, np.float32)
    for (r, c), diameter, peak in zip(centres[keep], diameters[keep], peaks[keep]):
        patch = particle_image(0.5 * diameter / px, blur_px) * np.float32(peak)
        h = patch.shape[0] // 2
        r0, r1, c0, c1 = r - h, r + h + 1, c - h, c + h + 1
        pr0, pc0 = max(0, -r0), max(0, -c0)
        pr1 = patch.shape[0] - max(0, r1 - rows)
        pc1 = patch.shape[1] - max(0, c1 - cols)
        material[max(0, r0) : min(rows, r1), max(0, c0) : min(cols, c1)] += patch[
            pr0:pr1, pc0:pc1
        ]
    media = np.asarray(scene.media, np.float32)
    added = np.minimum(material, media)  # a particle displaces medium, never a cell
    return scene.replace_media(media - added).replace_cells(
        np.asarray(scene.cells, np.float32) + added
    )
