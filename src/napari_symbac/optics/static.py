"""Static layers of bulk rendering: what does not move is convolved once.

A scene drawn by :func:`~napari_symbac.scene.draw_scene` has ``media = open - cells``
exactly (``open`` the fraction of each pixel not filled by the device, the same
read-only array for every frame of one geometry), so eq. 3 splits into a part that
changes every frame and one that does not:

``I_c C + I_m M + I_t D = (I_c - I_m) C + (I_m O + I_t D)``.

By the linearity of eq. 15 the camera image is ``(I_c - I_m) conv(C) + I_m conv(O) + I_t
conv(D)`` (with separate phase amplitudes also ``- P_c conv_ring(C) - P_t
conv_ring(D)``): the open and device images are convolved once per geometry and
kernel (the forward model's cache), and each frame transforms only the cells. The
cells are zero wherever the open fraction is (``C = min(thickness / depth, O)``), so
along each axis they lie inside the open region's extent, and a *circular*
convolution shorter than the frame gives the exact linear result over the camera
pixels (:func:`axis_window`): a trench's cells need 162 transform columns instead of
240.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
from scipy import fft as sp_fft

__all__ = ["AxisWindow", "StaticLayers", "axis_window", "static_layers"]


@dataclass(frozen=True)
class AxisWindow:
    """Where, along one axis, the cells' circular transform reads and writes.

    Attributes
    ----------
    start, stop
        Input samples ``[start, stop)`` (of the frame cropped to the kernel's
        border) copied into the transform; everything outside is zero.
    length
        Transform length: a multiple of the block factor with a fast quotient.
    out_start, out_stop
        Camera pixels ``[out_start, out_stop)`` this transform gives; the cells add
        nothing to the others.
    """

    start: int
    stop: int
    length: int
    out_start: int
    out_stop: int


def _fast_multiple(minimum: int, factor: int, real: bool) -> int:
    return factor * sp_fft.next_fast_len(-(-minimum // factor), real=real)


def axis_window(
    support: tuple[int, int],
    size: int,
    kernel: int,
    factor: int,
    full: int,
    *,
    real: bool = False,
) -> AxisWindow | None:
    """The shortest circular transform along one axis that is exact for the camera pixels.

    Parameters
    ----------
    support
        ``[a0, a1)``: the input is zero outside these samples.
    size
        Input samples along the axis; the valid convolution has ``size - kernel + 1``
        samples (a multiple of ``factor``), block-averaged to ``(size - kernel + 1) /
        factor`` camera pixels.
    kernel
        Kernel length along the axis.
    factor
        Block-average factor (render pixels per camera pixel).
    full
        The transform length of the whole frame (used when it is not longer).
    real
        The axis of the real-input transform (the last): lengths as
        :func:`~napari_symbac.optics.backends.resample_fft_shape` picks them there.

    Returns
    -------
    AxisWindow or None
        ``None`` when the support reaches no camera pixel. Camera pixel ``p`` takes
        the valid outputs ``j = p f .. p f + f - 1``, which read inputs ``j .. j +
        kernel - 1``: the pixels from ``J0 = f floor((a0 - kernel + 1) / f)`` (at
        least 0) to ``J1 = f ceil(a1 / f)`` (at most the valid size) can see the
        support. With the input copied from ``J0``, a circular transform of length
        ``N`` adds the periodic copies at ``+-N``; they stay out of the inputs
        ``[J0, J1 + kernel - 1)`` of those pixels when ``N >= a1 - J0`` and ``N >=
        J1 + kernel - 1 - a0``.
    """
    a0, a1 = max(int(support[0]), 0), min(int(support[1]), size)
    valid = size - kernel + 1
    j0 = factor * (max(a0 - kernel + 1, 0) // factor)
    j1 = min(valid, factor * -(-a1 // factor))
    if a1 <= a0 or j1 <= j0:
        return None
    need = max(a1 - j0, j1 + kernel - 1 - a0, kernel + factor - 1)
    length = _fast_multiple(need, factor, real)
    if length >= full:
        return AxisWindow(0, size, full, 0, valid // factor)
    return AxisWindow(j0, a1, length, j0 // factor, j1 // factor)


@dataclass(frozen=True)
class StaticLayers:
    """The open and device fractions of a drawn scene, hashed once, with their extent.

    Attributes
    ----------
    open, device
        Read-only float32 images of the scene's shape: ``media = open - cells``.
    fingerprint
        Content hash of both (cache key of their convolved images).
    extent
        ``(r0, r1, c0, c1)``: ``open`` is zero outside rows ``[r0, r1)`` and columns
        ``[c0, c1)``, and so are the cells.
    """

    open: np.ndarray
    device: np.ndarray
    fingerprint: str
    extent: tuple[int, int, int, int]


#: Static layers seen last, by the identity of their (read-only, kept alive) arrays;
#: few, as a field's layers are frame-sized (draw_scene's own caches hold them too).
_LAYERS: OrderedDict[tuple[int, int], StaticLayers] = OrderedDict()
_MAX_LAYERS = 2
_LOCK = threading.Lock()


def static_layers(scene: object) -> StaticLayers | None:
    """The :class:`StaticLayers` of ``scene``, or ``None`` where ``media = open - cells``
    is not known to hold.

    :func:`~napari_symbac.scene.draw_scene` records the open fraction on the scenes
    it draws; every frame of one geometry shares the same read-only open and device
    arrays, so their hash and extent are computed once. ``replace_cells`` /
    ``replace_media`` copies (texture, debris, per-cell brightness) and scenes built
    otherwise do not carry it.
    """
    open_ = getattr(scene, "__dict__", {}).get("_open_fraction")
    if open_ is None:
        return None
    device = scene.device  # type: ignore[attr-defined]
    key = (id(open_), id(device))
    with _LOCK:
        layers = _LAYERS.get(key)
        if layers is not None and layers.open is open_ and layers.device is device:
            _LAYERS.move_to_end(key)
            return layers
    from napari_symbac.scene._draw import _fingerprint

    rows = np.flatnonzero(open_.any(axis=1))
    cols = np.flatnonzero(open_.any(axis=0))
    if rows.size:
        extent = (int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1)
    else:
        extent = (0, 0, 0, 0)
    layers = StaticLayers(
        open_, device, _fingerprint(open_) + _fingerprint(device), extent
    )
    if open_.flags.writeable or device.flags.writeable:
        return layers  # could change: never remembered
    with _LOCK:
        _LAYERS[key] = layers
        while len(_LAYERS) > _MAX_LAYERS:
            _LAYERS.popitem(last=False)
    return layers
