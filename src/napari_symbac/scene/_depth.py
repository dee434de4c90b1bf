"""Where the stain sits in depth: the cells' stain in slabs through the optical depth
(fluorescence, eq. 16 of the supplement).

The drawn cells image holds each pixel's chord ``c = 2 h`` through its cell (eq. OPL2),
the cell's material filling ``[-h, h]`` about the cells' mid-plane (the middle of the
scene's optical depth). The part of it in a slab ``[z0, z1]`` is
``max(0, min(h, z1) - max(-h, z0))``; a stain in the envelope is the cell less the cell
``t`` narrower (:func:`~napari_symbac.scene.shell_chord_um`), whose half-chord is
``sqrt(h^2 - t (2 r - t))``. So the slabs follow from the drawn chord and the cell's
radius pixel by pixel, and they add up to the 2-D stain of
:func:`~napari_symbac.scene.stained_fraction`. :func:`depth_stain` gives a drawn scene
its :attr:`~napari_symbac.scene.Scene.depth_profile`, the share of each pixel's stain
in each slab, which the forward model images slab by slab.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from napari_symbac.scene._stain import (
    ENVELOPE_THICKNESS_UM,
    cell_radius_um,
    check_stain,
    envelope_stain,
    envelope_weight,
    stained_fraction,
)

__all__ = ["depth_layer_centres_um", "depth_stain", "stain_layers"]


def _check_layers(n_layers: int) -> None:
    if isinstance(n_layers, bool) or not isinstance(n_layers, (int, np.integer)) or n_layers < 1:
        raise ValueError(f"n_layers must be an integer >= 1, got {n_layers!r}")


def depth_layer_centres_um(depth_um: float, n_layers: int) -> np.ndarray:
    """Heights (um) of the middles of ``n_layers`` equal slabs through ``depth_um``, from
    the cells' mid-plane (the middle of the depth; negative: below it)."""
    _check_layers(n_layers)
    return (np.arange(n_layers) + 0.5 - n_layers / 2) * (depth_um / n_layers)


def _slab(half: np.ndarray, z0: float, z1: float) -> np.ndarray:
    """Length of ``[-half, half]`` inside ``[z0, z1]``."""
    return np.clip(np.minimum(half, z1) - np.maximum(-half, z0), 0.0, None)


def stain_layers(
    cells: np.ndarray,
    radius_um: np.ndarray | float,
    fraction: float,
    depth_um: float,
    n_layers: int,
    thickness_um: float = ENVELOPE_THICKNESS_UM,
) -> np.ndarray:
    """The stain of :func:`~napari_symbac.scene.stained_fraction` in ``n_layers`` slabs.

    ``(n_layers, *cells.shape)`` float32, slab ``k`` the part of each pixel's stain
    between heights ``depth (k / n - 1/2)`` and ``depth ((k + 1) / n - 1/2)``: the
    volume's ``min(h, z1) - max(-h, z0)`` (``h = cells x depth / 2``) and the envelope's
    the same less the inner cell's (half-chord ``sqrt(h^2 - t (2 r - t))``), weighted as
    in :func:`~napari_symbac.scene.stained_fraction`, over the depth. The slabs add up
    to its 2-D stain (to float rounding).

    Parameters
    ----------
    cells
        Cells fractions (chord over depth, at most 1).
    radius_um
        Radius of each pixel's cell (only read where ``fraction > 0``).
    fraction
        Fraction of the stain in the envelope, in ``[0, 1]``.
    depth_um
        Optical depth of the scene.
    n_layers
        Number of slabs.
    thickness_um
        Thickness of the envelope.
    """
    _check_layers(n_layers)
    cells = np.asarray(cells, np.float32)
    out = np.zeros((n_layers, *cells.shape), np.float32)
    inside = np.flatnonzero(cells)
    if inside.size == 0:
        return out
    half = cells.ravel()[inside].astype(np.float64) * (depth_um / 2)
    edges = (np.arange(n_layers + 1) / n_layers - 0.5) * depth_um
    inner = weight = None
    if fraction:
        radius = np.broadcast_to(np.asarray(radius_um, np.float64), cells.shape).ravel()[inside]
        t = np.minimum(thickness_um, radius)
        inner = np.sqrt(np.maximum(np.square(half) - t * (2 * radius - t), 0.0))
        weight = envelope_weight(radius, thickness_um)
    flat = out.reshape(n_layers, -1)
    for k in range(n_layers):
        volume = _slab(half, edges[k], edges[k + 1])
        stain = volume
        if inner is not None:
            shell = volume - _slab(inner, edges[k], edges[k + 1])
            stain = (1 - fraction) * volume + fraction * weight * shell
        flat[k, inside] = (stain / depth_um).astype(np.float32)
    return out


def midplane_share(n_layers: int) -> np.ndarray:
    """Share of each slab for light at the cells' mid-plane: the middle slab, or the
    two middle ones alike."""
    share = np.zeros(n_layers, np.float32)
    share[(n_layers - 1) // 2 : n_layers // 2 + 1] = 1.0
    return share / share.sum()


def depth_stain(
    scene: Any,
    fraction: float,
    n_layers: int,
    thickness_um: float = ENVELOPE_THICKNESS_UM,
) -> Any:
    """The scene stained as :func:`~napari_symbac.scene.envelope_stain` stains it, with
    the stain's :attr:`~napari_symbac.scene.Scene.depth_profile` in ``n_layers`` slabs.

    The profile is each pixel's share of its stain in each slab
    (:func:`stain_layers` over the 2-D stain); a pixel without stain (where a later
    stage may put light: debris) has its share at the cells' mid-plane. Per-pixel
    gains drawn after it (per-cell brightness) keep it. Radii as
    :func:`~napari_symbac.scene.envelope_stain` takes them: half the thickest chord of
    each cell.

    Parameters
    ----------
    scene
        A drawn :class:`~napari_symbac.scene.Scene` (cells image: chords over the depth).
    fraction
        Fraction of the stain in the envelope, in ``[0, 1]``.
    n_layers
        Number of slabs through the scene's depth.
    thickness_um
        Thickness of the envelope.
    """
    _check_layers(n_layers)
    check_stain(fraction, thickness_um)
    radius = cell_radius_um(scene)
    labelled = radius is not None
    radius = radius if labelled else np.zeros(scene.shape)
    layers = stain_layers(scene.cells, radius, fraction, scene.depth_um, n_layers, thickness_um)
    total = stained_fraction(scene.cells, radius, fraction, scene.depth_um, thickness_um)
    # the 2-D stain is that same image: made once (radius and stain each cost as much as
    # the slabs' shares on a large field)
    stained = envelope_stain(
        scene, fraction, thickness_um, stained_cells=total if labelled else None
    )
    # every pixel at the mid-plane, then the stained ones their own shares (flat indices:
    # boolean masks over the whole frame cost more than the division)
    profile = np.empty_like(layers)
    profile[:] = midplane_share(n_layers)[:, None, None]
    some = np.flatnonzero(total)
    flat = profile.reshape(n_layers, -1)
    flat[:, some] = layers.reshape(n_layers, -1)[:, some] / total.ravel()[some]
    return stained.with_depth_profile(profile)
