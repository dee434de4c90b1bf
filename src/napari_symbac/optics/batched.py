"""Batched rendering on a PyTorch device: scene components in, camera counts out.

A batch of frames goes to the device once (the cells / media / device fractions of
every frame, at render sampling), stays there through every stage of the
:class:`~napari_symbac.optics.forward.ForwardModel` and comes back once, as the
finished uint16 camera images:

1. ``psf`` + ``resample`` (eq. 15 and the area average to camera pixels): the
   components are weighted by the ``intensity`` stage's amplitudes (eq. 3, linear, so
   weighting before convolving is the same image), transformed once per frame and
   multiplied by the spectrum of the kernel convolved with the ``upsample x upsample``
   mean filter; the block average is folded into alias sums of that spectrum, exactly
   as :meth:`~napari_symbac.optics.backends.ScipyBackend.convolve_resample` does on the
   CPU (same transform sizes, same kernel spectrum). With separate phase amplitudes the
   ring kernel's product is subtracted before the inverse transform.
2. ``camera`` (eq. 17): shot noise ``Poisson(S / s)`` electrons, read noise ``N(0,
   sigma_d^2)`` electrons, gain ``s``, baseline, rounding and clipping to the bit depth
   (or the ``gaussian`` / ``none`` noise models), drawn on the device. As on the CPU
   (:func:`~napari_symbac.optics.camera.apply_camera_noise`), shot + read noise is one
   Gaussian of the same mean and variance wherever its skewness is at most
   :data:`~napari_symbac.optics.camera.GAUSSIAN_SKEWNESS_MAX`, an exact Poisson draw
   elsewhere.

The renderer reads the model's :attr:`~napari_symbac.optics.forward.ForwardModel.stages`
and kernels, so the two paths cannot drift apart; a stage it cannot run on the device
(the partially coherent ``phase_image``, any extra stage found by fitting or diagnosis)
is refused with a :class:`ValueError` naming it.

Noise stream: each frame's noise comes from its own :class:`torch.Generator`, seeded
with one 63-bit integer drawn for that frame from the numpy ``Generator`` passed in.
The same seed gives the same images on the same device, whatever the batch size; the
numbers differ from the CPU path's (numpy's Poisson and normal samplers), and between
torch's CPU and CUDA generators, with the same distribution. Noise-free images equal
the CPU path's within float32 rounding (``tests/optics/test_batched.py``).
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

from napari_symbac.optics.backends import resample_fft_shape, resample_kernel_spectrum
from napari_symbac.optics.camera import GAUSSIAN_SKEWNESS_MAX, exact_poisson_range
from napari_symbac.optics.forward import ForwardModel

__all__ = [
    "BACKENDS",
    "BatchedRenderer",
    "render_scenes",
    "resolve_backend",
]

#: Render backends a user can choose (``--backend``): scipy on the CPU, frame by frame
#: (the reference); torch, batched on a torch device; cupy, frame by frame on a CUDA
#: device (convolution only).
BACKENDS = ("scipy", "torch", "cupy")
#: Devices of the torch backend (``--device``); ``auto`` is cuda when available.
DEVICES = ("auto", "cpu", "cuda")
#: Stages the batched renderer runs on the device.
DEVICE_STAGES = ("psf", "resample", "intensity", "camera")
#: Working memory per batch the default batch size aims at: 32 MiB on the CPU (a frame
#: or a few: larger batches fall out of the caches and ran slower), a quarter of the
#: free memory on a GPU; at most 1024 frames.
_BATCH_BYTES_CPU = 32 * 2**20
_MAX_BATCH_FRAMES = 1024
#: Frames per thread below which a batch is filled on the host by one thread.
_FRAMES_PER_FILL_THREAD = 4


def _torch():
    try:
        import torch
    except ImportError as err:
        raise ValueError(
            "the torch backend needs PyTorch: pip install 'napari-symbac[gpu]' (see "
            "docs/benchmarks.md for the CUDA wheels), or use --backend scipy"
        ) from err
    return torch


def resolve_backend(backend: str = "scipy", device: str | None = None) -> str:
    """The backend as a full name: ``"scipy"``, ``"cupy"``, ``"torch:cpu"`` or ``"torch:cuda"``.

    Parameters
    ----------
    backend
        ``"scipy"``, ``"cupy"``, ``"torch"`` or ``"torch:DEVICE"``.
    device
        For torch: ``"auto"`` / ``None`` (cuda when available, else cpu), ``"cpu"`` or
        ``"cuda"`` (``"cuda:1"`` for another GPU). Overrides a device in ``backend``.

    Raises
    ------
    ValueError
        An unknown backend or device, a device given for a backend other than torch,
        torch missing, or cuda asked for where torch sees no GPU.
    """
    name, _, named_device = str(backend).partition(":")
    if name not in BACKENDS:
        raise ValueError(
            f"unknown render backend {backend!r}: use one of {', '.join(BACKENDS)}"
        )
    device = device or named_device or None
    if name != "torch":
        if device not in (None, "auto"):
            raise ValueError(
                f"--device {device} applies to the torch backend only; use --backend torch "
                f"or leave --device out"
            )
        return name
    torch = _torch()
    if device in (None, "auto"):
        return "torch:cuda" if torch.cuda.is_available() else "torch:cpu"
    if device != "cpu" and not device.startswith("cuda"):
        raise ValueError(f"unknown torch device {device!r}: use one of {', '.join(DEVICES)}")
    if device.startswith("cuda") and not torch.cuda.is_available():
        raise ValueError(
            f"device {device!r} asked for, but this torch ({torch.__version__}) sees no "
            "CUDA GPU: use --device cpu, or install a CUDA build of torch"
        )
    return f"torch:{device}"


class BatchedRenderer:
    """Render batches of scenes with ``model`` on a torch device.

    Parameters
    ----------
    model
        The forward model whose stages and settings are rendered (its convolution
        backend is not used).
    device
        ``"cpu"``, ``"cuda"``, ``"cuda:N"`` or ``"auto"`` / ``None`` (cuda when
        available).
    batch_frames
        Frames per device batch; by default as many as fit about 32 MiB (cpu) or a
        quarter of the GPU's free memory (at most 1024).

    Raises
    ------
    ValueError
        A stage of ``model`` that cannot run on the device (named in the message),
        torch missing or no GPU for ``device="cuda"``.

    Examples
    --------
    >>> renderer = BatchedRenderer(ForwardModel(Microscope(), RenderSettings()))  # doctest: +SKIP
    >>> images = renderer.render(scenes, np.random.default_rng(0))  # doctest: +SKIP
    """

    def __init__(
        self, model: ForwardModel, device: str | None = None, *, batch_frames: int | None = None
    ) -> None:
        if not isinstance(model, ForwardModel):
            raise ValueError(f"model must be a ForwardModel, got {type(model).__name__}")
        for stage in model.stages:
            if stage.name not in DEVICE_STAGES:
                raise ValueError(
                    f"the forward model's {stage.name!r} stage cannot run on the torch device "
                    "(the batched path runs psf, resample, intensity and camera only): "
                    "render with --backend scipy"
                )
        if batch_frames is not None and (
            isinstance(batch_frames, bool) or not isinstance(batch_frames, int) or batch_frames < 1
        ):
            raise ValueError(f"batch_frames must be an integer >= 1, got {batch_frames!r}")
        self.torch = _torch()
        self.device = resolve_backend("torch", device).partition(":")[2]
        self.model = model
        self.batch_frames = batch_frames
        self._spectra: dict[tuple, Any] = {}
        self._buffers: dict[tuple, Any] = {}
        self._budget: int | None = None
        self._pool: ThreadPoolExecutor | None = None

    # ------------------------------------------------------------------ stages
    def _stage(self, name: str) -> dict[str, Any]:
        return next(s.parameters for s in self.model.stages if s.name == name)

    def _spectrum(self, kernel: np.ndarray, factor: int, shape: tuple[int, int], tag: str):
        """The kernel's fused spectrum on the device (computed once per kernel and size)."""
        key = (tag, kernel.shape, factor, shape, kernel.tobytes())
        spectrum = self._spectra.get(key)
        if spectrum is None:
            host = resample_kernel_spectrum(kernel, factor, shape)
            spectrum = self.torch.from_numpy(host).to(self.device)
            if len(self._spectra) >= 4:
                self._spectra.pop(next(iter(self._spectra)))
            self._spectra[key] = spectrum
        return spectrum

    def _pinned(self, slot: tuple, shape: tuple[int, ...], dtype):
        """A host buffer of at least ``shape`` for ``slot``, kept (page-locked on a GPU)."""
        torch = self.torch
        size = int(np.prod(shape))
        buffer = self._buffers.get(slot)
        if buffer is None or buffer.numel() < size or buffer.dtype != dtype:
            buffer = torch.empty(size, dtype=dtype, pin_memory=self.device != "cpu")
            self._buffers[slot] = buffer
        return buffer[:size].view(shape)

    def _upload(self, scenes: Sequence[Any], slot: int):
        """Cells / media / device of every scene, cropped to the PSF's reach: ``(N, 3, Y, X)``.

        One transfer per batch, from a host buffer kept per ``slot`` (two slots
        alternate, so filling the next batch overlaps the device's work on this one).
        """
        first = scenes[0]
        for scene in scenes:
            self.model._check_scene(scene)
            if scene.cells.shape != first.cells.shape:
                raise ValueError(
                    f"a batch needs scenes of one size: {scene.cells.shape} and "
                    f"{first.cells.shape}; render scenes of each size in their own batch"
                )
        trim = first.border_px - self.model.render_settings.psf_radius_px
        crop = (slice(trim, -trim),) * 2 if trim else (slice(None),) * 2
        height, width = first.cells[crop].shape
        buffer = self._pinned(("in", slot), (len(scenes), 3, height, width), self.torch.float32)
        host = buffer.numpy()

        def fill(frames: range) -> None:
            for i in frames:
                host[i, 0] = scenes[i].cells[crop]
                host[i, 1] = scenes[i].media[crop]
                host[i, 2] = scenes[i].device[crop]

        # The copies release the GIL: on a batch of many frames, one thread per core
        # (at most 8) fills its share (the host side of a GPU batch is memory-bound).
        workers = min(8, os.cpu_count() or 1, len(scenes) // _FRAMES_PER_FILL_THREAD)
        if workers > 1:
            if self._pool is None:
                self._pool = ThreadPoolExecutor(min(8, os.cpu_count() or 1))
            shares = np.array_split(np.arange(len(scenes)), workers)
            list(self._pool.map(fill, [range(int(p[0]), int(p[-1]) + 1) for p in shares]))
        else:
            fill(range(len(scenes)))
        if self.device == "cpu":
            return buffer
        return buffer.to(self.device, non_blocking=True)

    def _clean(self, scenes: Sequence[Any], slot: int = 0):
        """``psf``, ``resample`` and ``intensity`` stages on the device: ``(N, Y', X')`` float32."""
        torch = self.torch
        model, first = self.model, scenes[0]
        factor = first.upsample
        px = first.pixel_size_um
        stack = self._upload(scenes, slot)
        n, _, height, width = stack.shape
        kernel = model.kernel(px)
        ky, kx = kernel.shape
        rows, cols = height - ky + 1, width - kx + 1
        shape = resample_fft_shape(height, width, factor)
        m1 = shape[0] // factor
        amplitudes = self._stage("intensity")
        weights = [
            np.float32(amplitudes[f"{name}_intensity"]) for name in ("cell", "media", "device")
        ]
        # eq. 3 at render sampling (float32; in place: no batch-sized temporaries)
        composed = torch.mul(stack[:, 0], float(weights[0]))
        composed.add_(stack[:, 1], alpha=float(weights[1]))
        composed.add_(stack[:, 2], alpha=float(weights[2]))
        spectrum = torch.fft.rfft2(composed, s=shape)
        del composed
        spectrum *= self._spectrum(kernel, factor, shape, "psf")
        if "cell_phase_adu" in amplitudes:  # separate phase amplitudes: minus the ring image
            phase = torch.mul(stack[:, 0], float(np.float32(amplitudes["cell_phase_adu"])))
            phase.add_(stack[:, 2], alpha=float(np.float32(amplitudes["device_phase_adu"])))
            ring = torch.fft.rfft2(phase, s=shape)
            del phase
            ring *= self._spectrum(model.ring_kernel(px), factor, shape, "ring")
            spectrum -= ring
            del ring
        del stack
        # decimate the rows (alias sum of the complex row frequencies), then the columns
        folded = spectrum.reshape(n, factor, m1, -1).sum(dim=1)
        del spectrum
        folded = torch.fft.ifft(folded, dim=1)
        full = torch.fft.irfft(folded[:, : rows // factor], n=shape[1], dim=-1)
        return full[:, :, :cols:factor].contiguous()

    def _camera(self, clean, seeds: np.ndarray):
        """The ``camera`` stage (eq. 17) on the device; returns uint16 on the device.

        Frame ``i``'s shot and read noise come from a generator seeded with
        ``seeds[i]``; everything else runs on the whole batch at once. The rule of
        :func:`~napari_symbac.optics.camera.apply_camera_noise`: one Gaussian of the
        exact mean and variance where the skewness of shot + read noise is at most
        :data:`~napari_symbac.optics.camera.GAUSSIAN_SKEWNESS_MAX`, an exact Poisson
        draw (plus read noise) elsewhere.
        """
        torch = self.torch
        cam = self._stage("camera")
        noise_model = cam["noise_model"]
        baseline = float(cam["baseline_adu"])
        if noise_model == "none":
            out = clean.add_(baseline)
        else:
            normal = torch.empty_like(clean)
            if noise_model == "camera":
                s = float(cam["sensitivity_adu_per_e"])
                dark_e = float(cam["dark_noise_e"])
                rates = torch.clamp(clean, min=0.0).div_(s)
                exact_range = exact_poisson_range(dark_e, GAUSSIAN_SKEWNESS_MAX)
                exact = None
                if exact_range is not None:
                    exact = (rates > exact_range[0]) & (rates < exact_range[1])
                    poisson_rates = torch.where(exact, rates, torch.zeros_like(rates))
                    electrons = torch.empty_like(clean)
            for i, seed in enumerate(seeds):
                generator = torch.Generator(device=self.device)
                generator.manual_seed(int(seed))
                if noise_model == "camera" and exact is not None:
                    electrons[i] = torch.poisson(poisson_rates[i], generator=generator)
                torch.randn(clean.shape[1:], generator=generator, out=normal[i])
            if noise_model == "camera":
                # s (A + B) + baseline: A + B ~ N(lambda, lambda + sigma_d^2) where that
                # is indistinguishable, else A ~ Poisson(lambda), B ~ N(0, sigma_d^2)
                spread = rates.add(dark_e * dark_e).sqrt_()
                if exact is None:
                    out = rates
                else:
                    spread = torch.where(exact, torch.full_like(spread, dark_e), spread)
                    out = torch.where(exact, electrons, rates)
                out.addcmul_(spread, normal).mul_(s).add_(baseline)
            else:
                out = normal.mul_(float(cam["gaussian_noise_sd_adu"])).add_(clean).add_(baseline)
        max_adu = float(2 ** int(cam["bit_depth"]) - 1)
        return out.round_().clamp_(0.0, max_adu).to(torch.uint16)

    # ------------------------------------------------------------------ public
    def frames_per_batch(self, scene: Any) -> int:
        """Frames of ``scene``'s size per device batch (``batch_frames`` when given)."""
        if self.batch_frames is not None:
            return self.batch_frames
        if self._budget is None:
            self._budget = _BATCH_BYTES_CPU
            if self.device != "cpu":
                free, _ = self.torch.cuda.mem_get_info(self.device)
                self._budget = max(_BATCH_BYTES_CPU, free // 4)
        per_frame = scene.cells.nbytes * 3 * 4  # components, spectra, temporaries
        return int(min(_MAX_BATCH_FRAMES, max(1, self._budget // per_frame)))

    def _batches(self, scenes: Sequence[Any]) -> Iterator[Sequence[Any]]:
        size = self.frames_per_batch(scenes[0])
        for start in range(0, len(scenes), size):
            yield scenes[start : start + size]

    def _run(self, scenes: Sequence[Any], seeds: np.ndarray | None) -> np.ndarray:
        """Every batch through the device; clean float32 (``seeds`` None) or uint16 counts.

        On a GPU the result of batch ``k`` is copied back asynchronously while batch
        ``k + 1`` is filled on the host; on the CPU everything runs in turn.
        """
        torch = self.torch
        first = scenes[0]
        out_dtype = np.float32 if seeds is None else np.uint16
        result = np.empty((len(scenes), *first.camera_shape), out_dtype)
        pending: tuple | None = None  # (event, host tensor, start, stop) of the last batch

        def collect(job: tuple) -> None:
            event, host, start, stop = job
            if event is not None:
                event.synchronize()
            result[start:stop] = host.numpy()

        start = 0
        with torch.inference_mode():
            for k, batch in enumerate(self._batches(scenes)):
                stop = start + len(batch)
                images = self._clean(batch, k % 2)
                if seeds is not None:
                    images = self._camera(images, seeds[start:stop])
                if self.device == "cpu":
                    job: tuple = (None, images, start, stop)
                else:
                    host = self._pinned(("out", k % 2), tuple(images.shape), images.dtype)
                    host.copy_(images, non_blocking=True)
                    event = torch.cuda.Event()
                    event.record(torch.cuda.current_stream(self.device))
                    job = (event, host, start, stop)
                if pending is not None:
                    collect(pending)
                pending = job
                start = stop
            if pending is not None:
                collect(pending)
        return result

    def render_clean(self, scenes: Sequence[Any]) -> np.ndarray:
        """Noise-free ``(N, Y, X)`` float32 images in ADU above the baseline (eq. 3, 15).

        The same images as :meth:`ForwardModel.render_clean` of each scene within
        float32 rounding; one float32 transfer back per batch.
        """
        scenes = list(scenes)
        if not scenes:
            raise ValueError("render_clean needs at least one scene")
        return self._run(scenes, None)

    def render(self, scenes: Sequence[Any], rng: np.random.Generator) -> np.ndarray:
        """Camera images ``(N, Y, X)`` uint16 of ``scenes``, noise drawn on the device.

        One 63-bit seed per frame is drawn from ``rng`` (in frame order) and seeds that
        frame's :class:`torch.Generator` (see the module notes); the finished uint16
        batch is the only transfer back.
        """
        if not isinstance(rng, np.random.Generator):
            raise ValueError("rng must be a numpy.random.Generator (np.random.default_rng(seed))")
        scenes = list(scenes)
        if not scenes:
            raise ValueError("render needs at least one scene")
        seeds = rng.integers(0, 2**63 - 1, size=len(scenes), dtype=np.int64)
        return self._run(scenes, seeds)


def render_scenes(
    model: ForwardModel,
    scenes: Iterable[Any],
    rng: np.random.Generator,
    *,
    backend: str = "scipy",
    batch_frames: int | None = None,
) -> Iterator[tuple[Any, np.ndarray]]:
    """Render ``scenes`` with ``model`` on ``backend``, yielding ``(scene, image)`` in order.

    Parameters
    ----------
    model
        The forward model (stages and settings).
    scenes
        Scenes of one size (a batch on torch; an iterable is consumed batch by batch).
    rng
        Noise generator: drawn frame by frame on scipy and cupy (bit for bit today's
        images), one seed per frame on torch (see the module notes).
    backend
        A name of :func:`resolve_backend`: ``"scipy"`` (reference, CPU), ``"cupy"``
        (convolution on the GPU, frame by frame), ``"torch:cpu"`` / ``"torch:cuda"`` /
        ``"torch"`` (batched, every stage on the device).
    batch_frames
        Frames per device batch on torch (default: :class:`BatchedRenderer`'s).
    """
    name = resolve_backend(backend)
    if name == "scipy":
        for scene in scenes:
            yield scene, model.render(scene, rng, cache=False)
        return
    if name == "cupy":
        gpu = ForwardModel(
            model.microscope,
            model.render_settings,
            model.camera,
            backend="cupy",
            extra_stages=model.extra_stages,
        )
        for scene in scenes:
            yield scene, gpu.render(scene, rng, cache=False)
        return
    renderer = BatchedRenderer(model, name.partition(":")[2], batch_frames=batch_frames)
    pending: list[Any] = []
    for scene in scenes:
        pending.append(scene)
        if len(pending) == renderer.frames_per_batch(pending[0]):
            yield from zip(pending, renderer.render(pending, rng))
            pending = []
    if pending:
        yield from zip(pending, renderer.render(pending, rng))
