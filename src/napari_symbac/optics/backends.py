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

__all__ = [
    "ConvolutionBackend",
    "available_backends",
    "get_backend",
    "resample_fft_shape",
    "resample_kernel_spectrum",
]


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


def resample_fft_shape(height: int, width: int, factor: int) -> tuple[int, int]:
    """Transform size of the fused convolution + block average of ``(height, width)`` images.

    Multiples of ``factor`` (for the alias sums of the decimation) whose quotient is a
    fast length; every backend with a fused path uses it, so they transform alike.
    """
    m1 = sp_fft.next_fast_len(-(-height // factor))
    m2 = sp_fft.next_fast_len(-(-width // factor), real=True)
    return (m1 * factor, m2 * factor)


def resample_kernel_spectrum(kernel: np.ndarray, factor: int, shape: tuple[int, int]) -> np.ndarray:
    """Spectrum of ``kernel`` convolved with the ``factor x factor`` mean filter (complex64).

    The kernel is rolled so that the samples the block average needs land on
    multiples of ``factor`` (see :meth:`ScipyBackend.convolve_resample`), and the ``1 /
    factor**2`` of the block mean and the ``1 / factor`` of each decimation's alias sum
    are folded in, so the spectral product needs no further scaling. Computed in
    float64 and rounded once, so every backend multiplies by the same numbers.
    """
    k64 = np.asarray(kernel, np.float64)
    ky, kx = k64.shape
    # kernel (*) box: the box sum of the kernel at every offset, divided by factor^2
    boxed = np.zeros((ky + factor - 1, kx + factor - 1), np.float64)
    for dy in range(factor):
        for dx in range(factor):
            boxed[dy : dy + ky, dx : dx + kx] += k64
    boxed /= factor * factor
    # placed at the origin of a zero array of ``shape`` and rolled back by ``shift``
    shift = (ky + factor - 2, kx + factor - 2)
    rows = (np.arange(boxed.shape[0]) - shift[0]) % shape[0]
    cols = (np.arange(boxed.shape[1]) - shift[1]) % shape[1]
    padded = np.zeros(shape, np.float64)
    padded[np.ix_(rows, cols)] = boxed
    return (sp_fft.rfft2(padded) / factor).astype(np.complex64)


#: Bounds of :class:`ScipyBackend`'s kernel-spectrum cache (oldest dropped first). A
#: scene fit asks for one spectrum per kernel and transform size: its renders' frame
#: and each size of its cell patches (:meth:`ScipyBackend.convolve_resample_circular`);
#: its fitted optics change the kernel at nearly every render, so what must stay is one
#: Jacobian's patch sizes under one kernel. Measured (fits' requests replayed): the real
#: SyMBac trench (256 x 46) up to 23 spectra per kernel, a 256 x 256 field of 36 cells 29,
#: a 512 x 512 field of 100 cells 49 (keeping 8, that fit would compute 2296 spectra
#: instead of 563), which computes no more than 563 once 116 MiB are kept (frame spectra
#: of 11.4 MB, patches' up to 190 kB). Hence 128 spectra and 192 MiB; but never fewer
#: than the last 8 (the bound before), whatever their size: a 2048 x 2048 frame rendered
#: 3x finer has a 150 MB spectrum.
_MAX_SPECTRA = 128
_MAX_SPECTRA_BYTES = 192 << 20
_KEEP_SPECTRA = 8


class ScipyBackend:
    """CPU convolution with :mod:`scipy.fft` (single precision, all cores).

    The Fourier transforms of the last kernels and transform sizes are kept, so
    rendering many frames with one PSF transforms the kernel once, and a scene fit's
    cell patches (:meth:`convolve_resample_circular`) reuse the spectrum of their size.
    """

    name = "scipy"

    def __init__(self) -> None:
        self._kernel_ffts: dict[tuple, np.ndarray] = {}
        self._last_kernel: tuple[np.ndarray, tuple, str] | None = None

    def _cached(self, key: tuple, make) -> np.ndarray:
        cached = self._kernel_ffts.get(key)
        if cached is None:
            cached = make()
            store = self._kernel_ffts
            size = cached.nbytes + sum(spectrum.nbytes for spectrum in store.values())
            while len(store) >= _KEEP_SPECTRA and (
                len(store) >= _MAX_SPECTRA or size > _MAX_SPECTRA_BYTES
            ):
                size -= store.pop(next(iter(store))).nbytes  # the oldest first
            store[key] = cached
        return cached

    def _kernel_fft(self, kernel: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        key = (hashlib.blake2b(kernel.tobytes(), digest_size=16).hexdigest(), kernel.shape, shape)
        return self._cached(key, lambda: sp_fft.rfft2(kernel, s=shape))

    def convolve_valid(
        self, images: np.ndarray, kernel: np.ndarray, *, sum_planes: bool = False
    ) -> np.ndarray:
        images, kernel = _check(images, kernel)
        shape = _fft_shape(images)
        ky, kx = kernel.shape[1:]
        fi = sp_fft.rfft2(images, s=shape)
        fk = self._kernel_fft(kernel, shape)
        product = fi * fk
        if sum_planes:
            product = product.sum(axis=0, keepdims=True)
        full = sp_fft.irfft2(product, s=shape)
        out = full[:, ky - 1 : images.shape[1], kx - 1 : images.shape[2]]
        out = np.ascontiguousarray(out, dtype=np.float32)
        return out[0] if sum_planes else out

    # ------------------------------------------------------ convolve + resample
    def _kernel_digest(self, kernel: np.ndarray) -> str:
        """Content hash of ``kernel``, remembered for the last read-only kernel seen.

        The forward model passes the same read-only, cached kernel array for every
        frame; hashing its 40 kB each time cost about as much as the spectral
        products. The reference kept here holds that memory alive, so the same
        address, shape and strides of a read-only array mean the same content.
        """
        signature = (
            kernel.__array_interface__["data"][0],
            kernel.shape,
            kernel.strides,
            kernel.dtype.str,
        )
        last = self._last_kernel
        if last is not None and last[1] == signature:
            return last[2]
        digest = hashlib.blake2b(kernel.tobytes(), digest_size=16).hexdigest()
        self._last_kernel = None if kernel.flags.writeable else (kernel, signature, digest)
        return digest

    def _resample_kernel_fft(
        self, kernel: np.ndarray, factor: int, shape: tuple[int, int]
    ) -> np.ndarray:
        """Spectrum of ``kernel`` convolved with the ``factor x factor`` mean filter.

        The kernel is rolled so that the samples the block average needs land on
        multiples of ``factor`` (see :meth:`convolve_resample`), and the ``1 /
        factor**2`` of the block mean and the ``1 / factor`` of each decimation's
        alias sum are folded in, so the spectral product needs no further scaling.
        """
        key = (self._kernel_digest(kernel), kernel.shape, shape, "resample", factor)
        return self._cached(key, lambda: resample_kernel_spectrum(kernel, factor, shape))

    def convolve_resample(
        self,
        images: np.ndarray,
        kernel: np.ndarray,
        factor: int,
        *,
        weights: np.ndarray | None = None,
    ) -> np.ndarray:
        """Valid convolution followed by the ``factor x factor`` block average.

        Equals ``block_average(convolve_valid(images, kernel), factor)`` (float
        rounding aside) but costs one forward transform per image and an inverse
        transform ``factor**2`` times smaller: the block mean is folded into the
        kernel's (cached) spectrum and the decimation into an aliasing sum of the
        product spectrum. With ``weights`` (one per image) the images are first
        combined into one, ``sum_i weights[i] images[i]`` (by linearity the same as
        weighting the convolved images), and a single ``(Y', X')`` image is returned.

        ``images`` is ``(N, Y, X)`` with ``Y - ky + 1`` and ``X - kx + 1``
        multiples of ``factor``; the result is ``(N, (Y - ky + 1) // factor,
        (X - kx + 1) // factor)`` float32.
        """
        images, kernel = _check(images, kernel)
        if kernel.shape[0] != 1:
            raise ValueError("convolve_resample takes one 2-D kernel")
        kernel = kernel[0]
        factor = int(factor)
        ky, kx = kernel.shape
        n, height, width = images.shape
        rows, cols = height - ky + 1, width - kx + 1
        if factor < 1 or rows % factor or cols % factor:
            raise ValueError(
                f"the valid convolution ({rows}, {cols}) is not a multiple of {factor}"
            )
        if weights is not None:
            weights = np.asarray(weights, np.float32)
            if weights.shape != (n,):
                raise ValueError(f"weights {weights.shape} do not fit images {images.shape}")
            combined = weights[0] * images[0]
            for weight, image in zip(weights[1:], images[1:]):
                combined += weight * image
            images = combined[None]
        shape = resample_fft_shape(height, width, factor)
        out = self._fused(images, kernel, factor, shape, (rows // factor, cols // factor))
        return out[0] if weights is not None else out

    def convolve_resample_circular(
        self,
        image: np.ndarray,
        kernel: np.ndarray,
        factor: int,
        shape: tuple[int, int],
        out_shape: tuple[int, int],
    ) -> np.ndarray:
        """The fused convolution + block average as a *circular* convolution of ``shape``.

        The image is zero-padded to ``shape`` and transformed once at that size; the
        inverse runs ``factor**2`` times smaller, at camera resolution (the block mean
        is folded into the kernel's cached spectrum, the decimation into an aliasing
        sum of the product spectrum). Camera pixel ``(p, q)`` of the result is the
        block average of the valid outputs ``(p f .. p f + f - 1, q f .. q f + f - 1)``
        of the periodic extension of the padded image. That equals the linear result
        wherever the periodic copies of the image do not reach those outputs' inputs:
        the caller chooses ``shape`` (see :func:`~napari_symbac.optics.static.axis_window`),
        which may be smaller than the valid convolution of ``image`` would need, or
        than ``image`` plus the kernel. With ``kernel - 1`` zero rows and columns
        before an image, ``shape`` at least its size gives its *full* convolution
        (the scene fit's cell patches).

        Parameters
        ----------
        image
            ``(Y, X)`` image, or ``(N, Y, X)`` images transformed together; at most
            ``shape``.
        kernel
            ``(ky, kx)`` kernel; ``ky + factor - 1`` and ``kx + factor - 1`` at most
            ``shape``.
        factor
            Side of the camera pixel in image pixels (the block average's).
        shape
            Transform size: multiples of ``factor`` with fast quotients
            (:func:`resample_fft_shape` gives such sizes).
        out_shape
            Camera pixels kept from the top-left; ``out_shape * factor`` at most
            ``shape``.

        Returns
        -------
        numpy.ndarray
            ``out_shape`` (or ``(N,) + out_shape``) float32.
        """
        image = np.asarray(image, dtype=np.float32)
        kernel = np.asarray(kernel, dtype=np.float32)
        factor = int(factor)
        if image.ndim not in (2, 3) or kernel.ndim != 2:
            raise ValueError(
                f"image must be 2-D or 3-D and kernel 2-D, got shapes {image.shape} and "
                f"{kernel.shape}"
            )
        shape = (int(shape[0]), int(shape[1]))
        out_shape = (int(out_shape[0]), int(out_shape[1]))
        for axis in (0, 1):
            if factor < 1 or shape[axis] % factor:
                raise ValueError(f"transform shape {shape} is not a multiple of {factor}")
            size = image.shape[axis - 2]
            if size > shape[axis] or kernel.shape[axis] + factor - 1 > shape[axis]:
                raise ValueError(
                    f"image {image.shape} or kernel {kernel.shape} (+ the {factor} x "
                    f"{factor} block) does not fit the transform shape {shape}"
                )
            if not 0 < out_shape[axis] * factor <= shape[axis]:
                raise ValueError(f"out_shape {out_shape} does not fit the transform {shape}")
        if image.ndim == 2:
            return self._fused(image[None], kernel, factor, shape, out_shape)[0]
        return self._fused(image, kernel, factor, shape, out_shape)

    def convolve_resample_sum(
        self, images: np.ndarray, kernels: np.ndarray, factor: int
    ) -> np.ndarray:
        """``sum_j`` of ``images[j]`` convolved (valid) with ``kernels[j]``, block-averaged
        ``factor x factor``: the slabs of eq. 16 through their PSFs.

        Equals ``block_average(convolve_valid(images, kernels, sum_planes=True), factor)``
        (float rounding aside) as :meth:`convolve_resample` equals its unfused form: one
        forward transform per slab, the slabs' spectral products summed, one inverse
        ``factor**2`` times smaller. ``images`` ``(N, Y, X)``, ``kernels`` ``(N, ky,
        kx)``; the result is ``((Y - ky + 1) // factor, (X - kx + 1) // factor)`` float32.
        """
        images, kernels = _check(images, kernels)
        factor = int(factor)
        n, height, width = images.shape
        ky, kx = kernels.shape[1:]
        rows, cols = height - ky + 1, width - kx + 1
        if factor < 1 or rows % factor or cols % factor:
            raise ValueError(
                f"the valid convolution ({rows}, {cols}) is not a multiple of {factor}"
            )
        shape = resample_fft_shape(height, width, factor)
        spectrum = None
        for image, kernel in zip(images, np.broadcast_to(kernels, (n, ky, kx))):
            product = sp_fft.rfft2(image, s=shape)
            product *= self._resample_kernel_fft(kernel, factor, shape)
            spectrum = product if spectrum is None else np.add(spectrum, product, out=spectrum)
        return self._decimate(spectrum[None], factor, shape, (rows // factor, cols // factor))[0]

    def _fused(
        self,
        images: np.ndarray,
        kernel: np.ndarray,
        factor: int,
        shape: tuple[int, int],
        out_shape: tuple[int, int],
    ) -> np.ndarray:
        """``(N, Y, X)`` float32 images -> ``(N,) + out_shape``: transforms of ``shape``."""
        spectrum = sp_fft.rfft2(images, s=shape)
        spectrum *= self._resample_kernel_fft(kernel, factor, shape)
        return self._decimate(spectrum, factor, shape, out_shape)

    @staticmethod
    def _decimate(
        spectrum: np.ndarray, factor: int, shape: tuple[int, int], out_shape: tuple[int, int]
    ) -> np.ndarray:
        """The product spectra ``(N, shape[0], shape[1] // 2 + 1)`` -> the block-averaged
        images ``(N,) + out_shape`` float32 (the kernel's spectrum carries the scale)."""
        m1 = shape[0] // factor
        # Decimate the rows: sum the aliases of the (full, complex) row frequencies.
        folded = spectrum.reshape(spectrum.shape[0], factor, m1, -1).sum(axis=1)
        folded = sp_fft.ifft(folded, axis=1, overwrite_x=True)
        # Decimate the columns: back to real rows at full width, keep every factor-th
        # sample (the kernel's spectrum carries the normalisation).
        full = sp_fft.irfft(folded[:, : out_shape[0]], n=shape[1], axis=-1, overwrite_x=True)
        return np.ascontiguousarray(full[:, :, : out_shape[1] * factor : factor], dtype=np.float32)


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
                "the cupy backend needs CuPy: pip install 'napari-symbac[gpu-cuda12]' "
                "(or [gpu-cuda13] for a CUDA 13 driver)"
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
