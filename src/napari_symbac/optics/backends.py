"""Convolution backends: scipy FFT on the CPU (default), CuPy or PyTorch when asked for.

Every backend computes the same thing, the *valid* part of a linear convolution
(eq. 15, and the sum over planes of eq. 16), in single precision. Optional
libraries are imported only when their backend is requested.
"""

from __future__ import annotations

import hashlib
from typing import Protocol

import numpy as np
from scipy import fft as sp_fft

__all__ = ["ConvolutionBackend", "available_backends", "get_backend"]


class ConvolutionBackend(Protocol):
    """What the forward model needs from a convolution backend."""

    name: str

    def convolve_valid(
        self, images: np.ndarray, kernel: np.ndarray, *, sum_planes: bool = False
    ) -> np.ndarray:
        """Valid part of ``images[i] * kernel[i]`` (or one shared 2-D kernel).

        ``images`` is ``(N, Y, X)``, ``kernel`` ``(ky, kx)`` or ``(N, ky, kx)``; the
        result is ``(N, Y - ky + 1, X - kx + 1)`` float32, or its sum over ``N`` when
        ``sum_planes`` (eq. 16).
        """


def _check(images: np.ndarray, kernel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    images = np.asarray(images, dtype=np.float32)
    kernel = np.asarray(kernel, dtype=np.float32)
    if images.ndim != 3:
        raise ValueError(f"images must be (N, Y, X), got shape {images.shape}")
    if kernel.ndim == 2:
        kernel = kernel[None]
    if kernel.ndim != 3 or kernel.shape[0] not in (1, images.shape[0]):
        raise ValueError(f"kernel shape {kernel.shape} does not fit images {images.shape}")
    if kernel.shape[1] > images.shape[1] or kernel.shape[2] > images.shape[2]:
        raise ValueError(f"kernel {kernel.shape[1:]} is larger than the images {images.shape[1:]}")
    return images, kernel


def _fft_shape(images: np.ndarray) -> tuple[int, int]:
    return (
        sp_fft.next_fast_len(images.shape[1], real=True),
        sp_fft.next_fast_len(images.shape[2], real=True),
    )


class ScipyBackend:
    """CPU convolution with :mod:`scipy.fft` (single precision, all cores).

    The Fourier transforms of the last few kernels are kept, so rendering many
    frames with one PSF transforms the kernel once.
    """

    name = "scipy"

    def __init__(self) -> None:
        self._kernel_ffts: dict[tuple, np.ndarray] = {}

    def _kernel_fft(self, kernel: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        key = (hashlib.blake2b(kernel.tobytes(), digest_size=16).hexdigest(), kernel.shape, shape)
        cached = self._kernel_ffts.get(key)
        if cached is None:
            cached = sp_fft.rfft2(kernel, s=shape, workers=-1)
            if len(self._kernel_ffts) >= 8:
                self._kernel_ffts.pop(next(iter(self._kernel_ffts)))
            self._kernel_ffts[key] = cached
        return cached

    def convolve_valid(
        self, images: np.ndarray, kernel: np.ndarray, *, sum_planes: bool = False
    ) -> np.ndarray:
        images, kernel = _check(images, kernel)
        shape = _fft_shape(images)
        ky, kx = kernel.shape[1:]
        fi = sp_fft.rfft2(images, s=shape, workers=-1)
        fk = self._kernel_fft(kernel, shape)
        product = fi * fk
        if sum_planes:
            product = product.sum(axis=0, keepdims=True)
        full = sp_fft.irfft2(product, s=shape, workers=-1)
        out = full[:, ky - 1 : images.shape[1], kx - 1 : images.shape[2]]
        out = np.ascontiguousarray(out, dtype=np.float32)
        return out[0] if sum_planes else out


class TorchBackend:
    """PyTorch FFT convolution on ``device`` (``"cpu"``, ``"cuda"``, ...)."""

    def __init__(self, device: str = "cpu") -> None:
        try:
            import torch
        except ImportError as err:  # pragma: no cover - depends on the environment
            raise ValueError(
                "the torch backend needs PyTorch: pip install 'napari-symbac[torch]'"
            ) from err
        self._torch = torch
        self.device = device
        self.name = f"torch:{device}"

    def convolve_valid(
        self, images: np.ndarray, kernel: np.ndarray, *, sum_planes: bool = False
    ) -> np.ndarray:
        torch = self._torch
        images, kernel = _check(images, kernel)
        shape = _fft_shape(images)
        ky, kx = kernel.shape[1:]
        ti = torch.from_numpy(np.array(images, copy=True)).to(self.device)
        tk = torch.from_numpy(np.array(kernel, copy=True)).to(self.device)
        product = torch.fft.rfft2(ti, s=shape) * torch.fft.rfft2(tk, s=shape)
        if sum_planes:
            product = product.sum(dim=0, keepdim=True)
        full = torch.fft.irfft2(product, s=shape)
        out = full[:, ky - 1 : images.shape[1], kx - 1 : images.shape[2]]
        out = np.ascontiguousarray(out.cpu().numpy(), dtype=np.float32)
        return out[0] if sum_planes else out


class CupyBackend:
    """CuPy FFT convolution on the current CUDA device."""

    name = "cupy"

    def __init__(self) -> None:
        try:
            import cupy
        except ImportError as err:  # pragma: no cover - depends on the environment
            raise ValueError(
                "the cupy backend needs CuPy: pip install 'napari-symbac[gpu]'"
            ) from err
        self._cp = cupy

    def convolve_valid(
        self, images: np.ndarray, kernel: np.ndarray, *, sum_planes: bool = False
    ) -> np.ndarray:  # pragma: no cover - needs a GPU
        cp = self._cp
        images, kernel = _check(images, kernel)
        shape = _fft_shape(images)
        ky, kx = kernel.shape[1:]
        product = cp.fft.rfft2(cp.asarray(images), s=shape) * cp.fft.rfft2(
            cp.asarray(kernel), s=shape
        )
        if sum_planes:
            product = product.sum(axis=0, keepdims=True)
        full = cp.fft.irfft2(product, s=shape)
        out = cp.asnumpy(full[:, ky - 1 : images.shape[1], kx - 1 : images.shape[2]])
        out = np.ascontiguousarray(out, dtype=np.float32)
        return out[0] if sum_planes else out


def get_backend(name: str | ConvolutionBackend = "scipy") -> ConvolutionBackend:
    """Return a backend by name: ``"scipy"``, ``"torch"`` / ``"torch:cuda"``, ``"cupy"``.

    A backend object is returned unchanged. Optional libraries are imported here,
    lazily; a missing one gives a ``ValueError`` saying what to install.
    """
    if not isinstance(name, str):
        return name
    if name == "scipy":
        return ScipyBackend()
    if name == "torch" or name.startswith("torch:"):
        return TorchBackend(name.partition(":")[2] or "cpu")
    if name == "cupy":
        return CupyBackend()
    raise ValueError(f"unknown convolution backend {name!r}: use 'scipy', 'torch' or 'cupy'")


def available_backends() -> list[str]:
    """Names of the backends importable here (scipy always)."""
    import importlib.util

    names = ["scipy"]
    if importlib.util.find_spec("torch") is not None:
        names.append("torch")
    if importlib.util.find_spec("cupy") is not None:
        names.append("cupy")
    return names
