"""The FFT floor every benchmark is divided by: one real FFT convolution of the frame."""

from __future__ import annotations

import numpy as np
from scipy import signal

from napari_symbac.bench.timing import fft_floor, fft_floor_s, trench_kernel


def test_fft_floor_is_the_convolution_of_the_frame_with_the_kernel():
    rng = np.random.default_rng(3)
    frame = rng.random((61, 47), dtype=np.float32)
    kernel = rng.random((11, 9), dtype=np.float32)
    out = fft_floor(frame, kernel)()
    assert out.dtype == np.float32
    # circular at fast lengths >= the frame: its valid part is the valid convolution
    valid = signal.fftconvolve(frame.astype(np.float64), kernel, mode="valid")
    rows, cols = valid.shape
    np.testing.assert_allclose(out[10 : 10 + rows, 8 : 8 + cols], valid, rtol=1e-4, atol=1e-3)


def test_fft_floor_s_times_the_trench_frame():
    kernel = trench_kernel()
    assert kernel.shape == (101, 101)
    assert fft_floor_s((868, 238), kernel, repeats=2) > 0
