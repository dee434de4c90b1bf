"""Batched rendering on a PyTorch device: scene components in, camera counts out.

A batch of frames goes to the device once (what each frame adds to the image, at
render sampling), stays there through every stage of the
:class:`~napari_symbac.optics.forward.ForwardModel` and comes back once, as the
finished uint16 camera images:

1. ``psf`` + ``resample`` (eq. 15 and the area average to camera pixels), as
   :meth:`~napari_symbac.optics.forward.ForwardModel.render_clean` with ``cache=False``
   computes them on the CPU: for drawn scenes of one geometry the open and device
   layers' image is made once (:mod:`~napari_symbac.optics.static`) and only the
   cells, over the columns and rows they can reach, go to the device; other scenes
   are composed on the host (eq. 3, float32, the CPU path's arithmetic) and go as one
   plane (two with separate phase amplitudes, whose ring image is subtracted). Each
   plane is transformed once and multiplied by the spectrum of the kernel convolved
   with the ``upsample x upsample`` mean filter; the block average is folded into
   alias sums of that spectrum, exactly as
   :meth:`~napari_symbac.optics.backends.ScipyBackend.convolve_resample` does on the
   CPU (same transform sizes, same kernel spectrum).
   ``depth`` (eq. 16, fluorescence with ``RenderSettings.depth_layers = N > 0``): the
   cells go as ``N`` slab planes, ``depth_profile[j] * cells`` in float32 (the CPU
   path's slabs bit for bit), each multiplied by its slab kernel's spectrum times
   ``I_c`` (the CPU path weights the summed slab image by ``float32(I_c)``), the
   products summed before one inverse; media and device stay on the 2-D kernel, as
   one composed plane, or on the static path in the static image, where the cells'
   window adds ``-I_m`` times the cells through the 2-D kernel (``media = open -
   cells``; an envelope stain is a copy without the open fraction and is composed).
   The CPU path composes depth scenes always, its slabs through the same fused block
   average (:meth:`~napari_symbac.optics.forward.ForwardModel.convolve_depth`); the
   two agree within float32 rounding (3-5e-7 of the range on trench and field
   batches). Measured once, before the CPU path's slabs were fused (which made its
   slab step 1.1-1.6x faster; not re-measured since), torch's CPU, one thread, against
   the scipy path frame by frame (20 trench frames of 258 x 46 px, 5 slabs, noise
   included, median of 3 interleaved rounds, 2-core machine shared at load 1.3-1.9):
   torch:cpu took 0.32x scipy's time (volume stain, static path) and 0.35x (envelope
   stain, composed). On one NVIDIA H200 (2026-12-04, 1000 trench frames,
   ``benchmarks/bench_gpu_modalities.py``): torch:cuda 34.9x scipy's frames/s (volume)
   and 27.7x (envelope), within 4-5.4e-7 of the range of ``render_clean``.
2. ``camera`` (eq. 17): shot noise ``Poisson(S / s)`` electrons, read noise ``N(0,
   sigma_d^2)`` electrons, gain ``s``, baseline, rounding and clipping to the bit depth
   (or the ``gaussian`` / ``none`` noise models), drawn on the device. As on the CPU
   (:func:`~napari_symbac.optics.camera.apply_camera_noise`), shot + read noise is one
   Gaussian of the same mean and variance wherever its skewness is at most
   :data:`~napari_symbac.optics.camera.GAUSSIAN_SKEWNESS_MAX`, an exact Poisson draw
   elsewhere.

The renderer reads the model's :attr:`~napari_symbac.optics.forward.ForwardModel.stages`
and kernels, so the two paths cannot drift apart. Extra stages on the recorded image
(``Stage.recorded``: the clip of a camera or of a background subtraction that ``fit``
writes for a recording clipped at 0) are applied to the finished uint16 frames on the
host, as the CPU path applies them; a stage it cannot run (the partially coherent
``phase_image``, any other extra stage found by fitting or diagnosis) is refused with a
:class:`ValueError` naming it.

Noise stream: each frame's noise comes from its own :class:`torch.Generator`, seeded
with one 63-bit integer drawn for that frame from the numpy ``Generator`` passed in,
so a frame's noise does not depend on the batch it is rendered in; the numbers differ
from the CPU path's (numpy's Poisson and normal samplers), and between torch's CPU and
CUDA generators, with the same distribution. The same call with the same seed gives
the same images on the same device bit for bit (the default batch size depends on the
frame size and the kind of device only). Another batch size can move a count by 1
where the clean value lies at a rounding boundary: FFT libraries round a batch of
transforms differently by its size (MKL on a 16-core host, cuFFT). Noise-free images
equal the CPU path's within float32 rounding (``tests/optics/test_batched.py``).
"""

from __future__ import annotations

import itertools
import os
from collections.abc import Iterable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np

from napari_symbac.optics.backends import resample_fft_shape, resample_kernel_spectrum
from napari_symbac.optics.camera import GAUSSIAN_SKEWNESS_MAX, exact_poisson_range
from napari_symbac.optics.forward import ForwardModel
from napari_symbac.optics.static import static_layers

__all__ = [
    "BACKENDS",
    "BatchedRenderer",
    "check_device_stages",
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
DEVICE_STAGES = ("depth", "psf", "resample", "intensity", "camera")
#: Name of depth slab ``j``'s input plane in :attr:`_Layout.planes`: ``depth_profile[j]
#: * cells``, float32 as :meth:`~napari_symbac.optics.forward.ForwardModel._depth_cells`
#: forms it.
_SLAB = "slab:"
#: Working memory per batch the default batch size aims at: 32 MiB on the CPU (a frame
#: or a few: larger batches fall out of the caches and ran slower), on a GPU 3 GiB or an
#: eighth of its memory, whichever is less (the device's size, not the memory free at
#: the time, so that the same call renders the same images); at most 1024 frames.
_BATCH_BYTES_CPU = 32 * 2**20
_BATCH_BYTES_GPU = 3 * 2**30
_MAX_BATCH_FRAMES = 1024
#: Host buffers smaller than this are filled by one thread.
_PARALLEL_FILL_BYTES = 4 * 2**20


@dataclass(frozen=True)
class _Layout:
    """How a batch of scenes goes through the device.

    Attributes
    ----------
    source
        ``(rows, cols)`` of each scene's arrays that the host copies.
    planes
        Per input plane, the ``(component, weight)`` pairs the host sums (eq. 3): the
        composed image (and with separate phase amplitudes the phase image), or the
        cells alone when the scenes share static layers (:mod:`~napari_symbac.optics.static`).
        Depth-resolved (eq. 16) the composed image is media and device only, and each
        slab ``j`` of the cells is a plane of its own, ``(("slab:j", 1.0),)``.
    kernels
        Per plane, the ``(weight, kernel)`` pairs whose fused spectra it is multiplied by.
    transform
        Size of the (circular) transform of each plane.
    out_shape
        Camera pixels the transform gives.
    out
        Where they land in the camera image (static layers), ``None``: they are it.
    static
        The camera image of the static layers (open and device convolved once), or
        ``None``.
    """

    source: tuple[slice, slice]
    planes: tuple[tuple[tuple[str, float], ...], ...]
    kernels: tuple[tuple[tuple[float, np.ndarray], ...], ...]
    transform: tuple[int, int]
    out_shape: tuple[int, int]
    out: tuple[slice, slice] | None
    static: np.ndarray | None


def _torch():
    try:
        import torch
    except ImportError as err:
        raise ValueError(
            "the torch backend needs PyTorch: pip install 'napari-symbac[gpu]' (see "
            "docs/benchmarks.md for the CUDA wheels), or use --backend scipy"
        ) from err
    return torch


def check_device_stages(model: ForwardModel) -> None:
    """Refuse a model with a stage the batched renderer cannot run (module notes).

    Raises
    ------
    ValueError
        Naming the stage and the fix (the scipy backend). Called before anything is
        written: an export refused later left a manifest that recorded the torch backend,
        so the scipy run the message asks for was refused in turn.
    """
    for stage in model.stages:
        if stage.name not in DEVICE_STAGES and not stage.recorded:
            raise ValueError(
                f"the forward model's {stage.name!r} stage cannot run on the torch device "
                "(the batched path runs depth, psf, resample, intensity and camera, and "
                "stages on the recorded image such as clipping): render with --backend "
                "scipy"
            )


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
        check_device_stages(model)
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
        self._statics: dict[int, tuple[np.ndarray, Any]] = {}
        self._budget: int | None = None
        self._pool: ThreadPoolExecutor | None = None

    # ------------------------------------------------------------------ stages
    def _stage(self, name: str) -> dict[str, Any]:
        return next(s.parameters for s in self.model.stages if s.name == name)

    def _spectrum(
        self, kernels: tuple[tuple[float, np.ndarray], ...], factor: int, shape, keep: int = 4
    ):
        """``sum w_k spectrum(kernel_k)`` of the fused convolution + block average, on the
        device (computed once per kernels, weights and size; the last ``keep``, at least
        4, are kept: a depth-resolved layout has one per slab)."""
        key = (factor, shape, *((w, k.shape, k.tobytes()) for w, k in kernels))
        spectrum = self._spectra.get(key)
        if spectrum is None:
            host = sum(
                np.float64(w) * resample_kernel_spectrum(k, factor, shape).astype(np.complex128)
                for w, k in kernels
            )
            spectrum = self.torch.from_numpy(np.asarray(host, np.complex64)).to(self.device)
            while len(self._spectra) >= max(4, keep):
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

    def _layout(self, scenes: Sequence[Any]) -> _Layout:
        """How ``scenes`` go through the device (see :class:`_Layout`); checks the scenes.

        Scenes that share static layers take the static path when there are several
        (its image costs two transforms of the frame on the CPU, once per geometry);
        a single frame of a geometry this model has not rendered yet is composed, as
        :meth:`~napari_symbac.optics.forward.ForwardModel.render_clean` decides.
        Depth-resolved scenes (eq. 16) take either path too (the CPU path composes them
        always): static, the cells' 2-D plane carries ``-I_m`` (the static image holds
        ``I_m O``) and each slab ``I_c`` through its own kernel, over the cells' window.
        """
        model, first = self.model, scenes[0]
        depth = model.depth_layers
        for scene in scenes:
            model._check_scene(scene)
            if (scene.cells.shape, scene.upsample, scene.pixel_size_um) != (
                first.cells.shape,
                first.upsample,
                first.pixel_size_um,
            ):
                raise ValueError(
                    f"a batch needs scenes of one size and sampling: {scene.cells.shape} and "
                    f"{first.cells.shape}; render scenes of each size in their own batch"
                )
            if depth:
                model._depth_profile(scene)  # raises, naming the fix, where there is none
                if scene.depth_um != first.depth_um:
                    raise ValueError(
                        f"a depth-resolved batch needs scenes of one depth: {scene.depth_um} "
                        f"and {first.depth_um} um; render scenes of each depth in their own "
                        "batch"
                    )
        layers = static_layers(first)
        if layers is not None and all(
            (other := static_layers(scene)) is not None
            and other.fingerprint == layers.fingerprint
            and scene.border_px == first.border_px
            for scene in scenes
        ):
            plan = model._static_plan(first, always=len(scenes) > 1, depth_cells=bool(depth))
            if plan is not None and depth:
                # (I_c - I_m) C of the 2-D path, split: - I_m C on the 2-D kernel, I_c C
                # slab by slab on the slabs' kernels
                r = model.render_settings
                minus_media = np.float32(-r.media_intensity)
                planes, plane_kernels = self._slab_planes(first)
                if minus_media != 0:
                    kernel = model.kernel(first.pixel_size_um)
                    planes.insert(0, (("cells", 1.0),))
                    plane_kernels.insert(0, ((float(minus_media), kernel),))
                return _Layout(
                    source=plan.cells or (slice(0, 0), slice(0, 0)),
                    planes=tuple(planes) if plan.cells else (),
                    kernels=tuple(plane_kernels),
                    transform=plan.transform_shape,
                    out_shape=plan.out_shape,
                    out=plan.out,
                    static=plan.static,
                )
            if plan is not None:
                kernels = tuple((float(w), k) for w, k in plan.cell_kernels)
                return _Layout(
                    source=plan.cells or (slice(0, 0), slice(0, 0)),
                    planes=((("cells", 1.0),),) if plan.cells and kernels else (),
                    kernels=(kernels,),
                    transform=plan.transform_shape,
                    out_shape=plan.out_shape,
                    out=plan.out,
                    static=plan.static,
                )
        return self._composed_layout(first)

    def _slab_planes(
        self, first: Any
    ) -> tuple[list[tuple[tuple[str, float], ...]], list[tuple[tuple[float, np.ndarray], ...]]]:
        """The depth slabs' planes (eq. 16): ``depth_profile[j] * cells`` through slab
        ``j``'s kernel, weighted by ``I_c`` after the convolution as the CPU path's
        ``np.float32(I_c) * _depth_cells`` (here in the kernel's spectrum)."""
        model = self.model
        weight = float(np.float32(model.render_settings.cell_intensity))
        kernels = model.depth_kernels(first.depth_um, first.pixel_size_um)
        planes = [((f"{_SLAB}{j}", 1.0),) for j in range(len(kernels))]
        return planes, [((weight, kernel),) for kernel in kernels]

    def _composed_layout(self, first: Any) -> _Layout:
        """The layout of scenes composed on the host (eq. 3): one plane, two with
        separate phase amplitudes, over the frame cropped to the PSF's reach;
        depth-resolved (eq. 16) media and device composed as one plane and the cells'
        slabs one plane each, as :meth:`~napari_symbac.optics.forward.ForwardModel.render_clean`
        composes them."""
        model = self.model
        r = model.render_settings
        px = first.pixel_size_um
        kernel = model.kernel(px)
        trim = first.border_px - r.psf_radius_px
        rows, cols = (n - 2 * trim for n in first.cells.shape)
        factor = first.upsample
        composed = (
            ("cells", r.cell_intensity),
            ("media", r.media_intensity),
            ("device", r.device_intensity),
        )
        planes: list[tuple[tuple[str, float], ...]] = [composed]
        plane_kernels: list[tuple[tuple[float, np.ndarray], ...]] = [((1.0, kernel),)]
        if model.depth_layers:  # media and device composed, the cells slab by slab
            planes, plane_kernels = self._slab_planes(first)
            planes.insert(0, composed[1:])
            plane_kernels.insert(0, ((1.0, kernel),))
        if model.separate_phase:  # separate phase amplitudes: minus the ring image
            p_cell, p_device = model.ring_amplitudes()
            planes.append((("cells", p_cell), ("device", p_device)))
            plane_kernels.append(((-1.0, model.ring_kernel(px)),))
        valid = ((rows - kernel.shape[0] + 1) // factor, (cols - kernel.shape[1] + 1) // factor)
        return _Layout(
            source=(slice(trim, trim + rows), slice(trim, trim + cols)),
            planes=tuple(planes),
            kernels=tuple(plane_kernels),
            transform=resample_fft_shape(rows, cols, factor),
            out_shape=valid,
            out=None,
            static=None,
        )

    def _upload(self, scenes: Sequence[Any], layout: _Layout, slot: int):
        """The input planes of every scene (``layout.planes`` over ``layout.source``):
        ``(N, P, Y, X)`` float32 on the device.

        Each plane is the weighted sum of eq. 3 in float32, in the order of the CPU path
        (bit for bit its composed image), or the cells alone (static layers), or a
        depth slab ``profile[j] * cells`` (bit for bit the CPU path's slab). One
        transfer per batch, from a host buffer kept per ``slot`` (two slots alternate,
        so filling the next batch overlaps the device's work on this one).
        """
        rows, cols = layout.source
        height, width = rows.stop - rows.start, cols.stop - cols.start
        n, n_planes = len(scenes), len(layout.planes)
        buffer = self._pinned(("in", slot), (n, n_planes, height, width), self.torch.float32)
        host = buffer.numpy()
        slabs = any(name.startswith(_SLAB) for (name, _), *_ in layout.planes)
        profiles = [self.model._depth_profile(scene) for scene in scenes] if slabs else []

        def fill(task: tuple[int, int, int, int]) -> None:
            i0, i1, r0, r1 = task
            window = (slice(rows.start + r0, rows.start + r1), cols)
            for i in range(i0, i1):
                for p, ((name, weight), *rest) in enumerate(layout.planes):
                    out = host[i, p, r0:r1]
                    if name.startswith(_SLAB):  # profile[j] * cells (weight 1, alone)
                        j = int(name[len(_SLAB) :])
                        np.multiply(profiles[i][j][window], scenes[i].cells[window], out=out)
                        continue
                    source = getattr(scenes[i], name)[window]
                    if weight == 1.0 and not rest:
                        out[...] = source
                        continue
                    np.multiply(np.float32(weight), source, out=out)
                    for other, w in rest:
                        out += np.float32(w) * getattr(scenes[i], other)[window]

        # The copies release the GIL: one thread per core (at most 8) fills its share,
        # whole frames when there are many, bands of rows of each frame when there are
        # few (the host side of a GPU batch is memory-bound).
        workers = min(8, os.cpu_count() or 1)
        if host.nbytes < _PARALLEL_FILL_BYTES or workers == 1:
            fill((0, n, 0, height))
        else:
            if self._pool is None:
                self._pool = ThreadPoolExecutor(workers)
            tasks = 4 * workers
            if n >= tasks:
                edges = np.linspace(0, n, tasks + 1).astype(int)
                jobs = [(a, b, 0, height) for a, b in itertools.pairwise(edges) if b > a]
            else:
                bands = np.linspace(0, height, min(height, -(-tasks // n)) + 1).astype(int)
                jobs = [
                    (i, i + 1, a, b)
                    for i in range(n)
                    for a, b in itertools.pairwise(bands)
                    if b > a
                ]
            list(self._pool.map(fill, jobs))
        if self.device == "cpu":
            return buffer
        return buffer.to(self.device, non_blocking=True)

    def _static_image(self, static: np.ndarray):
        """The camera image of the static layers on the device (kept per array)."""
        key = id(static)
        held = self._statics.get(key)
        if held is None or held[0] is not static:
            held = (static, self.torch.from_numpy(np.array(static)).to(self.device))
            if len(self._statics) >= 2:
                self._statics.pop(next(iter(self._statics)))
            self._statics[key] = held
        return held[1]

    def _clean(self, scenes: Sequence[Any], slot: int = 0):
        """``psf``, ``resample`` and ``intensity`` stages on the device: ``(N, Y', X')`` float32."""
        torch = self.torch
        layout = self._layout(scenes)
        n, factor = len(scenes), scenes[0].upsample
        part = None
        if layout.planes:
            stack = self._upload(scenes, layout, slot)
            spectrum = None
            for p, kernels in enumerate(layout.kernels):
                product = torch.fft.rfft2(stack[:, p], s=layout.transform)
                product *= self._spectrum(
                    kernels, factor, layout.transform, keep=len(layout.kernels)
                )
                spectrum = product if spectrum is None else spectrum.add_(product)
                del product
            del stack
            # decimate the rows (alias sum of the complex row frequencies), then the columns
            m1 = layout.transform[0] // factor
            folded = spectrum.reshape(n, factor, m1, -1).sum(dim=1)
            del spectrum
            folded = torch.fft.ifft(folded, dim=1)
            full = torch.fft.irfft(folded[:, : layout.out_shape[0]], n=layout.transform[1], dim=-1)
            part = full[:, :, : layout.out_shape[1] * factor : factor]
        if layout.static is None:
            return part.contiguous()
        image = self._static_image(layout.static).expand(n, *layout.static.shape).clone()
        if part is not None:
            image[(slice(None), *layout.out)] += part
        return image

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
        """Frames of ``scene``'s size per device batch (``batch_frames`` when given).

        A function of the frame's size and the device only (never of the memory free at
        the time), so that a rendering is repeatable bit for bit: the transforms'
        rounding can depend on how many frames they batch. Sized for the composed
        path (the static path's window needs less).
        """
        if self.batch_frames is not None:
            return self.batch_frames
        if self._budget is None:
            self._budget = _BATCH_BYTES_CPU
            if self.device != "cpu":
                total = self.torch.cuda.get_device_properties(self.device).total_memory
                self._budget = min(_BATCH_BYTES_GPU, total // 8)
        self.model._check_scene(scene)
        layout = self._composed_layout(scene)
        # input planes, spectrum and temporaries, each about a transform's size
        per_frame = 4 * layout.transform[0] * layout.transform[1] * (len(layout.planes) + 3)
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
        images = self._run(scenes, seeds)
        # the extra stages on the recorded image (clipping by the camera or a background
        # subtraction), frame by frame on the host as the CPU path applies them
        for stage in (stage for stage in self.model.stages if stage.recorded):
            for i, image in enumerate(images):
                images[i] = np.asarray(stage.apply(image, None), dtype=images.dtype)
        return images


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
    size = 0
    for scene in scenes:
        if not pending:  # a batch's size, once per batch
            size = renderer.frames_per_batch(scene)
        pending.append(scene)
        if len(pending) == size:
            yield from zip(pending, renderer.render(pending, rng))
            pending = []
    if pending:
        yield from zip(pending, renderer.render(pending, rng))
