"""Timing helpers and the FFT floor every row is measured against."""

from __future__ import annotations

import platform
import resource
import time
from collections.abc import Callable

import numpy as np

__all__ = ["fft_floor", "fft_floor_s", "median_s", "peak_rss_mib", "trench_kernel"]


def median_s(fn: Callable[[], object], repeats: int) -> float:
    """Median wall time of ``repeats`` calls of ``fn``, in seconds."""
    times = []
    for _ in range(max(1, repeats)):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def trench_kernel(upsample: int = 3, psf_radius_px: int = 50) -> np.ndarray:
    """The default phase-contrast PSF kernel at render resolution (the floor's kernel)."""
    from napari_symbac.optics import ForwardModel
    from napari_symbac.settings import Camera, Microscope, RenderSettings

    render = RenderSettings(upsample=upsample, psf_radius_px=psf_radius_px)
    return np.asarray(ForwardModel(Microscope(), render, Camera()).kernel(), np.float32)


def fft_floor(frame: np.ndarray, kernel: np.ndarray) -> Callable[[], np.ndarray]:
    """One plain FFT convolution of ``frame`` with ``kernel``: the project's FFT floor.

    ``irfft2(rfft2(frame) * K)`` in float32 at the fast transform lengths of the frame
    (``scipy.fft.next_fast_len``; circular, its valid part is the valid convolution),
    with the kernel's spectrum ``K`` computed once beforehand, one thread. Returns the
    call to time; it is the yardstick of every row of ``napari-symbac bench`` and of
    the scripts in ``benchmarks/`` (about 2.5 ms for the 868 x 238 render frame of the
    256 x 46 trench).
    """
    from scipy import fft as sp_fft

    frame = np.asarray(frame, np.float32)
    shape = tuple(sp_fft.next_fast_len(n, real=True) for n in frame.shape)
    spectrum = sp_fft.rfft2(np.asarray(kernel, np.float32), s=shape)
    return lambda: sp_fft.irfft2(sp_fft.rfft2(frame, s=shape) * spectrum, s=shape)


def fft_floor_s(
    shape: tuple[int, int], kernel: np.ndarray | None = None, repeats: int = 5
) -> float:
    """Seconds of :func:`fft_floor` on a ``shape`` frame (wall time).

    The median of ``repeats`` calls after a warm-up, measured in the same run as the
    row it divides so that the ratios travel between machines and loads. ``kernel``
    defaults to :func:`trench_kernel` (the cost does not depend on its values: it is
    padded to the frame's transform lengths).
    """
    frame = np.random.default_rng(0).random(tuple(shape), dtype=np.float32)
    floor = fft_floor(frame, trench_kernel() if kernel is None else kernel)
    floor()
    return median_s(floor, repeats)


def peak_rss_mib() -> float:
    """Peak resident memory of this process so far, MiB.

    On Linux ``VmHWM`` of ``/proc/self/status``: unlike ``ru_maxrss``, which a process
    started by ``subprocess`` inherits from the parent it was forked from, it belongs to
    this program alone.
    """
    try:
        with open("/proc/self/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024
    except (OSError, ValueError, IndexError):
        pass
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return rss / 2**20 if platform.system() == "Darwin" else rss / 1024
