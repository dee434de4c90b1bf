"""Timing helpers and the FFT floor every row is measured against."""

from __future__ import annotations

import platform
import resource
import time
from collections.abc import Callable

import numpy as np

__all__ = ["fft_floor_s", "median_s", "peak_rss_mib", "trench_kernel"]


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


def fft_floor_s(shape: tuple[int, int], kernel: np.ndarray, repeats: int = 5) -> float:
    """Seconds of one plain FFT convolution of a ``shape`` frame with ``kernel``.

    ``scipy.signal.fftconvolve(frame, kernel, mode="valid")``, float32, the median of
    ``repeats`` calls after a warm-up: the yardstick every row is divided by, measured
    in the same run so that the ratios travel between machines and loads.
    """
    from scipy import signal

    frame = np.random.default_rng(0).random(shape, dtype=np.float32)
    signal.fftconvolve(frame, kernel, mode="valid")
    return median_s(lambda: signal.fftconvolve(frame, kernel, mode="valid"), repeats)


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
