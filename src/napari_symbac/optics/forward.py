"""The forward model: scene -> camera image as an ordered list of stages (eq. 3, 14-17).

Stages, in order:

1. ``psf`` (linear): the phase-contrast kernel of eq. 7-13 or the Airy pattern of
   eq. 6, with the defocus of eq. 14 folded in, convolved with each scene component
   (cells, media, device) separately (eq. 15), then area-averaged to camera pixels.
   When the render settings give the phase signal its own amplitudes
   (``RenderSettings.phase_separate``), the bright-field part ``h_dc`` and the
   zero-sum ring part ``h_ring`` are two kernels: cells, media and device go through
   ``h_dc`` and cells and device also through ``h_ring`` (``cells_phase``,
   ``device_phase``; the media's ring image is minus their sum, since the fractions
   add to 1 and ``h_ring`` sums to 0).
   Each convolved component is cached, keyed on the component's content and the
   kernel's parameters. The scipy backend fuses convolution and area average
   (``convolve_resample``); ``render(..., cache=False)`` composes eq. 3 first and
   convolves once (bulk rendering).
2. ``intensity`` (eq. 3): ``I_c C + I_m M + I_t D`` (``- P_c C_phase - P_t D_phase``
   with separate phase amplitudes); by linearity this equals the convolution of the
   composed image, so changing an intensity only recombines cached arrays.
3. any ``extra_stages`` (pointwise effects found by fitting / diagnosis).
4. ``camera`` (eq. 17): noise, baseline, rounding and clipping to the bit depth.

In fluorescence with ``RenderSettings.depth_layers > 0`` a ``depth`` stage comes
first: the cells' stain is imaged slab by slab through the depth (eq. 16;
:mod:`~napari_symbac.optics.depth`, the scene's
:attr:`~napari_symbac.scene.Scene.depth_profile`), each slab through the PSF defocused
by its distance from the focal plane, while media and device go through the ``psf``
stage's kernel.

With ``RenderSettings.phase_model = "partially_coherent"`` stages 1-2 are one
nonlinear stage, ``phase_image``: the sample's complex transmission imaged through
the condenser annulus and the phase plate
(:func:`~napari_symbac.optics.partial_coherence.annular_phase_image`), the defocus
of eq. 14 as a Gaussian blur of that image, the area average to camera pixels and
the media level. Nothing is cached per component there (the image is not linear
in the scene).
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from napari_symbac.optics.backends import ConvolutionBackend, get_backend, resample_fft_shape
from napari_symbac.optics.camera import apply_camera_noise, apply_gaussian_noise, quantise
from napari_symbac.optics.depth import depth_kernels
from napari_symbac.optics.partial_coherence import annular_phase_image
from napari_symbac.optics.psf import (
    airy_psf,
    brightfield_kernels,
    defocus,
    phase_contrast_kernels,
    phase_contrast_psf,
)
from napari_symbac.optics.static import axis_window, static_layers
from napari_symbac.settings import CONDENSERS, Camera, Microscope, RenderSettings

__all__ = ["COMPONENTS", "ForwardModel", "Stage", "block_average"]

COMPONENTS = ("cells", "media", "device")


def block_average(image: np.ndarray, factor: int) -> np.ndarray:
    """Resample to camera pixels: the mean of every ``factor x factor`` block (area average)."""
    image = np.asarray(image)
    if factor == 1:
        return image.astype(np.float32, copy=False)
    *lead, rows, cols = image.shape
    if rows % factor or cols % factor:
        raise ValueError(f"image shape {image.shape[-2:]} is not a multiple of {factor}")
    blocks = image.reshape(*lead, rows // factor, factor, cols // factor, factor)
    return blocks.mean(axis=(-3, -1), dtype=np.float32)


@dataclass(frozen=True)
class Stage:
    """One step of the forward model.

    Attributes
    ----------
    name
        Short name (``"psf"``, ``"intensity"``, ``"camera"``, ...).
    linear
        Linear in the scene: applied per component once and cached.
    parameters
        The parameters the stage depends on (for display and cache keys).
    apply
        For extra (non-built-in) stages: ``apply(image, scene) -> image`` on the
        clean camera-resolution float32 image.
    recorded
        For extra stages: ``apply`` acts on the recorded image after the camera (uint16
        ADU, baseline included), as clipping by the camera or a later processing step
        does, not on the clean image.
    """

    name: str
    linear: bool
    parameters: dict[str, Any] = field(default_factory=dict)
    apply: Callable[[np.ndarray, Any], np.ndarray] | None = None
    recorded: bool = False


class _Cache:
    """Least-recently-used store of convolved, camera-resolution components."""

    def __init__(self, max_items: int = 96) -> None:
        self.max_items = max_items
        self._items: OrderedDict[tuple, np.ndarray] = OrderedDict()
        self.hits = 0
        self.misses = 0

    def get(self, key: tuple) -> np.ndarray | None:
        value = self._items.get(key)
        if value is not None:
            self._items.move_to_end(key)
            self.hits += 1
        return value

    def has(self, key: tuple) -> bool:
        """Whether ``key`` is stored (neither a hit nor a miss)."""
        return key in self._items

    def put(self, key: tuple, value: np.ndarray) -> None:
        self.misses += 1
        value.setflags(write=False)
        self._items[key] = value
        self._items.move_to_end(key)
        while len(self._items) > self.max_items:
            self._items.popitem(last=False)

    def clear(self) -> None:
        self._items.clear()


@dataclass
class _StaticPlan:
    """What :meth:`ForwardModel._render_static` needs per geometry: the camera image of
    the static layers, where the cells are read and written, and their kernels."""

    render: RenderSettings
    microscope: Microscope
    static: np.ndarray
    cells: tuple[slice, slice] | None = None
    out: tuple[slice, slice] = (slice(0), slice(0))
    transform_shape: tuple[int, int] = (0, 0)
    out_shape: tuple[int, int] = (0, 0)
    cell_kernels: list[tuple[np.float32, np.ndarray]] = field(default_factory=list)


class ForwardModel:
    """Image formation from a :class:`~napari_symbac.scene.Scene` to camera counts.

    Parameters
    ----------
    microscope
        Objective, wavelength, condenser and modality (``"phase"``, ``"fluorescence"``
        or ``"brightfield"``).
    render
        Upsampling, PSF radius, intensities (eq. 3), apodisation (eq. 11-13),
        defocus (eq. 14), ring contrast, PSF offset and noise model.
    camera
        EMVA1288 camera of eq. 17.
    backend
        Convolution backend of this model, frame by frame: ``"scipy"`` (default),
        ``"torch"``, ``"torch:cuda"``, ``"cupy"`` or a backend object. Rendering many
        frames on a GPU is :class:`~napari_symbac.optics.batched.BatchedRenderer` (every
        stage on the device; ``--backend torch``).
    extra_stages
        Pointwise stages applied to the clean image before the camera, or (those marked
        ``recorded``) to the recorded image after it.

    Examples
    --------
    >>> model = ForwardModel(Microscope(), RenderSettings(), Camera())  # doctest: +SKIP
    >>> image = model.render(scene, np.random.default_rng(0))  # doctest: +SKIP
    """

    def __init__(
        self,
        microscope: Microscope,
        render: RenderSettings,
        camera: Camera | None = None,
        *,
        backend: str | ConvolutionBackend = "scipy",
        extra_stages: Sequence[Stage] = (),
        _cache: _Cache | None = None,
        _kernel_cache: dict | None = None,
    ) -> None:
        if not isinstance(microscope, Microscope):
            raise ValueError(f"microscope must be a Microscope, got {type(microscope).__name__}")
        if not isinstance(render, RenderSettings):
            raise ValueError(f"render must be RenderSettings, got {type(render).__name__}")
        camera = Camera() if camera is None else camera
        if microscope.modality == "phase" and (
            render.apodisation_sigma_um < microscope.min_apodisation_sigma_um
        ):
            raise ValueError(
                f"RenderSettings.apodisation_sigma_um={render.apodisation_sigma_um} is below "
                f"the diffraction bound of eq. 13 ({microscope.min_apodisation_sigma_um:.3f} um "
                f"for this microscope): raise it"
            )
        for stage in extra_stages:
            if stage.apply is None:
                raise ValueError(f"extra stage {stage.name!r} has no apply function")
        self.microscope = microscope
        self.render_settings = render
        self.camera = camera
        self.backend = get_backend(backend)
        self.extra_stages = tuple(extra_stages)
        self._cache = _cache if _cache is not None else _Cache()
        self._kernels: dict = _kernel_cache if _kernel_cache is not None else {}
        self._plans: dict[tuple, _StaticPlan] = {}
        self._seen: set[tuple] = set()

    # ------------------------------------------------------------------ stages
    @property
    def stages(self) -> tuple[Stage, ...]:
        """The ordered stages of this model (for display, saving and diagnosis)."""
        m, r = self.microscope, self.render_settings
        psf_params: dict[str, Any] = {
            "modality": m.modality,
            "wavelength_um": m.wavelength_um,
            "numerical_aperture": m.numerical_aperture,
            "psf_radius_px": r.psf_radius_px,
            "upsample": r.upsample,
            "defocus_sigma_um": r.defocus_sigma_um,
        }
        if m.modality == "phase":
            psf_params.update(
                condenser=m.condenser,
                apodisation_sigma_um=r.apodisation_sigma_um,
                ring_contrast=r.ring_contrast,
                psf_offset=r.psf_offset,
                ring_model=r.ring_model,
                phase_ring_width_scale=r.phase_ring_width_scale,
            )
        intensity_params = {
            "cell_intensity": r.cell_intensity,
            "media_intensity": r.media_intensity,
            "device_intensity": r.device_intensity,
        }
        if m.modality == "phase" and r.phase_separate:
            intensity_params.update(
                cell_phase_adu=r.phase_amplitudes()[0], device_phase_adu=r.phase_amplitudes()[1]
            )
        if m.modality == "brightfield":
            intensity_params["defocus_contrast_um2"] = r.defocus_contrast_um2
        if m.modality == "phase" and r.phase_model == "partially_coherent":
            return (
                Stage(
                    "phase_image",
                    False,
                    {
                        "wavelength_um": m.wavelength_um,
                        "numerical_aperture": m.numerical_aperture,
                        "condenser": m.condenser,
                        "upsample": r.upsample,
                        "cell_phase_rad": r.cell_phase_rad,
                        "device_phase_rad": r.device_phase_rad,
                        "plate_transmission": r.plate_transmission,
                        "plate_phase_rad": r.plate_phase_rad,
                        "phase_ring_width_scale": r.phase_ring_width_scale,
                        "apodisation_sigma_um": r.apodisation_sigma_um,
                        "defocus_sigma_um": r.defocus_sigma_um,
                        "focus_offset_um": r.focus_offset_um,
                        "source_points": r.source_points,
                        **intensity_params,
                    },
                ),
                *self._clean_stages,
                self._camera_stage(),
                *self._recorded_stages,
            )
        depth = ()
        if self.depth_layers:
            depth = (
                Stage(
                    "depth",
                    True,
                    {"depth_layers": r.depth_layers, "focus_offset_um": r.focus_offset_um},
                ),
            )
        return (
            *depth,
            Stage("psf", True, psf_params),
            Stage("resample", True, {"upsample": r.upsample}),
            Stage("intensity", False, intensity_params),
            *self._clean_stages,
            self._camera_stage(),
            *self._recorded_stages,
        )

    @property
    def _clean_stages(self) -> tuple[Stage, ...]:
        return tuple(stage for stage in self.extra_stages if not stage.recorded)

    @property
    def _recorded_stages(self) -> tuple[Stage, ...]:
        return tuple(stage for stage in self.extra_stages if stage.recorded)

    def _camera_stage(self) -> Stage:
        r = self.render_settings
        return Stage(
            "camera",
            False,
            {
                "noise_model": r.noise_model,
                **_camera_dict(self.camera),
                "gaussian_noise_sd_adu": r.gaussian_noise_sd_adu,
            },
        )

    @property
    def partially_coherent(self) -> bool:
        """Whether the phase image is formed by the partially coherent model."""
        return (
            self.microscope.modality == "phase"
            and self.render_settings.phase_model == "partially_coherent"
        )

    def halo_reach_um(self) -> float:
        """``lambda / (W NA)``: how far the phase plate's halo reaches (W: ring width / pupil)."""
        m, r = self.microscope, self.render_settings
        cond = CONDENSERS[m.condenser]
        width = (cond.outer_fraction - cond.inner_fraction) * r.phase_ring_width_scale
        return m.wavelength_um / (width * m.numerical_aperture)

    def phase_image(self, scene: Any) -> np.ndarray:
        """The ``phase_image`` stage: camera-resolution image, 1 = empty field (float64).

        Only for ``phase_model="partially_coherent"``; the scene's border, extended
        mirror-wise to :meth:`halo_reach_um` where it is narrower, pads the sample
        against the FFT's wrap-around.
        """
        if not self.partially_coherent:
            raise ValueError(
                "phase_image needs RenderSettings.phase_model='partially_coherent' and a "
                "phase microscope"
            )
        self._check_scene(scene)
        m, r = self.microscope, self.render_settings
        if r.media_intensity <= 0:
            raise ValueError(
                "the partially coherent model needs media_intensity > 0 (the level of the "
                "empty field)"
            )
        key = (
            "phase_image",
            scene.fingerprints["cells"],
            scene.fingerprints["device"],
            self._kernel_key(scene.pixel_size_um),
            r.cell_intensity / r.media_intensity,
            r.device_intensity / r.media_intensity,
            r.cell_phase_rad,
            r.device_phase_rad,
            r.plate_transmission,
            r.plate_phase_rad,
            r.source_points,
            r.focus_offset_um,
        )
        cached = self._cache.get(key)
        if cached is not None:
            return cached
        b = (
            r.cell_intensity * scene.cells.astype(np.float64)
            + r.media_intensity * scene.media
            + r.device_intensity * scene.device
        ) / r.media_intensity
        phi = r.cell_phase_rad * scene.cells.astype(np.float64)
        phi += r.device_phase_rad * scene.device
        # The halo reaches ~ lambda / (W NA) (W the ring's width as a fraction of the
        # pupil); where the scene's border is narrower, extend it mirror-wise so the
        # FFT's wrap-around does not fold the far side's halo in.
        extra = max(0, math.ceil(self.halo_reach_um() / scene.pixel_size_um) - scene.border_px)
        if extra:
            b = np.pad(b, extra, mode="symmetric")
            phi = np.pad(phi, extra, mode="symmetric")
        image = annular_phase_image(
            b,
            phi,
            scene.pixel_size_um,
            m.wavelength_um,
            m.numerical_aperture,
            m.condenser,
            r.plate_transmission,
            r.plate_phase_rad,
            r.apodisation_sigma_um,
            r.phase_ring_width_scale,
            r.source_points,
            r.focus_offset_um,
            m.refractive_index,
        )
        if r.defocus_sigma_um > 0:
            from scipy.ndimage import gaussian_filter

            image = gaussian_filter(image, r.defocus_sigma_um / scene.pixel_size_um)
        if extra:
            image = image[extra:-extra, extra:-extra]
        out = block_average(scene.interior(image), scene.upsample).astype(np.float64)
        self._cache.put(key, out)
        return out

    def with_render(self, render: RenderSettings) -> ForwardModel:
        """A model with new render settings sharing this one's caches.

        When only intensities or the noise model changed, rendering a scene that was
        rendered before recombines cached arrays: no convolution runs.
        """
        return ForwardModel(
            self.microscope,
            render,
            self.camera,
            backend=self.backend,
            extra_stages=self.extra_stages,
            _cache=self._cache,
            _kernel_cache=self._kernels,
        )

    def with_camera(self, camera: Camera) -> ForwardModel:
        """A model with another camera, sharing this one's caches."""
        return ForwardModel(
            self.microscope,
            self.render_settings,
            camera,
            backend=self.backend,
            extra_stages=self.extra_stages,
            _cache=self._cache,
            _kernel_cache=self._kernels,
        )

    def with_microscope(self, microscope: Microscope) -> ForwardModel:
        """A model with another microscope, sharing this one's caches."""
        return ForwardModel(
            microscope,
            self.render_settings,
            self.camera,
            backend=self.backend,
            extra_stages=self.extra_stages,
            _cache=self._cache,
            _kernel_cache=self._kernels,
        )

    @property
    def cache_info(self) -> dict[str, int]:
        """Hits and misses of the convolution cache (a miss is one convolution)."""
        return {
            "hits": self._cache.hits,
            "misses": self._cache.misses,
            "size": len(self._cache._items),
        }

    # ------------------------------------------------------------------ kernel
    def _kernel_key(self, pixel_size_um: float) -> tuple:
        m, r = self.microscope, self.render_settings
        key: tuple = (
            m.modality,
            m.wavelength_um,
            m.numerical_aperture,
            round(pixel_size_um, 12),
            r.psf_radius_px,
            r.defocus_sigma_um,
        )
        if m.modality == "phase":
            gamma = "separate" if r.phase_separate else r.ring_contrast
            key += (m.condenser, r.apodisation_sigma_um, gamma, r.psf_offset, r.ring_model)
            key += (r.phase_ring_width_scale,)
        return key

    @property
    def depth_layers(self) -> int:
        """Slabs of the depth-resolved cells image (eq. 16); 0: the 2-D projection (and
        always in phase contrast)."""
        if self.microscope.modality != "fluorescence":
            return 0
        return self.render_settings.depth_layers

    def depth_kernels(self, depth_um: float, pixel_size_um: float | None = None) -> np.ndarray:
        """The slabs' PSFs (:func:`~napari_symbac.optics.depth.depth_kernels`), cached."""
        m, r = self.microscope, self.render_settings
        px = m.pixel_size_um / r.upsample if pixel_size_um is None else pixel_size_um
        key = ("depth", *self._kernel_key(px), r.depth_layers, r.focus_offset_um, depth_um)
        kernels = self._kernels.get(key)
        if kernels is None:
            kernels = depth_kernels(m, r, depth_um, px)
            self._kernels[key] = kernels
        return kernels

    def _depth_profile(self, scene: Any) -> np.ndarray:
        """``scene``'s :attr:`~napari_symbac.scene.Scene.depth_profile` of
        ``depth_layers`` slabs; a scene without cells (no labels: debris alone) and no
        profile has its light at the cells' mid-plane. Raises, naming the fix, for a
        scene with cells and no profile of as many slabs."""
        from napari_symbac.scene._depth import midplane_share

        profile = scene.depth_profile
        if profile is None and not scene.labels.any():
            profile = np.broadcast_to(
                midplane_share(self.depth_layers)[:, None, None],
                (self.depth_layers, *scene.shape),
            )
        if profile is None or profile.shape[0] != self.depth_layers:
            raise ValueError(
                f"RenderSettings.depth_layers={self.depth_layers} images the cells slab by "
                "slab, but the scene has no depth profile of as many slabs: stain it with "
                "napari_symbac.pipeline.stain_cells (or scene.depth_stain)"
            )
        return profile

    def _depth_cells(self, scene: Any, trim: int) -> np.ndarray:
        """The cells image slab by slab through the slabs' PSFs, summed and area-averaged
        (eq. 16), not cached (profile: :meth:`_depth_profile`)."""
        profile = self._depth_profile(scene)
        crop = (slice(trim, -trim),) * 2 if trim else (slice(None),) * 2
        layers = profile[(slice(None), *crop)] * scene.cells[crop][None]
        kernels = self.depth_kernels(scene.depth_um, scene.pixel_size_um)
        return self.convolve_depth(layers, kernels, scene.upsample)

    def convolve_depth(self, layers: np.ndarray, kernels: np.ndarray, factor: int) -> np.ndarray:
        """Slab ``j`` of ``layers`` through ``kernels[j]`` (valid), summed and
        block-averaged ``factor x factor`` (eq. 16): the backend's fused form where it
        has one (``convolve_resample_sum``: the average folded into each slab's
        spectrum, one inverse transform at camera resolution), float32."""
        fused = getattr(self.backend, "convolve_resample_sum", None)
        if fused is not None:
            return fused(layers, kernels, factor)
        return block_average(self.backend.convolve_valid(layers, kernels, sum_planes=True), factor)

    @property
    def separate_phase(self) -> bool:
        """Whether the ring part is rendered with its own amplitudes (two kernels): phase
        contrast with ``*_phase_adu`` set, and always in bright field, whose second
        kernel is the lens term's ``laplacian(k)`` (:meth:`ring_amplitudes`)."""
        m = self.microscope
        return m.modality == "brightfield" or (
            m.modality == "phase" and self.render_settings.phase_separate
        )

    def ring_amplitudes(self) -> tuple[float, float]:
        """``(P_cell, P_device)``, the weights (ADU) of the cells and device through
        :meth:`ring_kernel`, subtracted from the image: the phase ring's
        (``RenderSettings.phase_amplitudes``), or in bright field the lens term of the
        cells' phase, ``kappa I_m`` (``defocus_contrast_um2`` times the media level,
        the light that falls on the sample; the transport-of-intensity equation of
        :func:`~napari_symbac.optics.psf.brightfield_kernels`). The PDMS's own lens
        term is not modelled (0)."""
        r = self.render_settings
        if self.microscope.modality == "brightfield":
            return (r.defocus_contrast_um2 * r.media_intensity, 0.0)
        return r.phase_amplitudes()

    def _kernel_pair(self, px: float) -> tuple[np.ndarray, np.ndarray]:
        key = ("pair", *self._kernel_key(px))
        pair = self._kernels.get(key)
        if pair is not None:
            return pair
        m, r = self.microscope, self.render_settings
        if m.modality == "brightfield":
            pair = brightfield_kernels(
                r.psf_radius_px,
                px,
                m.wavelength_um,
                m.numerical_aperture,
                defocus_sigma_um=r.defocus_sigma_um,
            )
        else:
            pair = phase_contrast_kernels(
                r.psf_radius_px,
                px,
                m.wavelength_um,
                m.numerical_aperture,
                m.condenser,
                r.apodisation_sigma_um,
                defocus_sigma_um=r.defocus_sigma_um,
                offset=r.psf_offset,
                min_apodisation_sigma_um=m.min_apodisation_sigma_um,
                ring_model=r.ring_model,
                ring_width_scale=r.phase_ring_width_scale,
            )
        for k in pair:
            k.setflags(write=False)
        self._kernels[key] = pair
        return pair

    def ring_kernel(self, pixel_size_um: float | None = None) -> np.ndarray:
        """The zero-sum ring kernel ``h_ring`` of a model with separate phase amplitudes
        (in bright field ``laplacian(k)``, the lens term's)."""
        if not self.separate_phase:
            raise ValueError(
                "the ring kernel is separate only with RenderSettings.cell_phase_adu or "
                "device_phase_adu set (phase modality) or in bright field; use kernel() "
                "otherwise"
            )
        m, r = self.microscope, self.render_settings
        px = m.pixel_size_um / r.upsample if pixel_size_um is None else pixel_size_um
        return self._kernel_pair(px)[1]

    def kernel(self, pixel_size_um: float | None = None) -> np.ndarray:
        """The 2-D kernel of the ``psf`` stage (defocus included), float32, sum 1.

        With separate phase amplitudes this is the bright-field part ``h_dc``; the
        ring part is :meth:`ring_kernel`.
        """
        m, r = self.microscope, self.render_settings
        px = m.pixel_size_um / r.upsample if pixel_size_um is None else pixel_size_um
        if self.separate_phase:
            return self._kernel_pair(px)[0]
        key = self._kernel_key(px)
        kernel = self._kernels.get(key)
        if kernel is None:
            if m.modality == "phase":
                kernel = phase_contrast_psf(
                    r.psf_radius_px,
                    px,
                    m.wavelength_um,
                    m.numerical_aperture,
                    m.condenser,
                    r.apodisation_sigma_um,
                    r.ring_contrast,
                    defocus_sigma_um=r.defocus_sigma_um,
                    offset=r.psf_offset,
                    min_apodisation_sigma_um=m.min_apodisation_sigma_um,
                    ring_model=r.ring_model,
                    ring_width_scale=r.phase_ring_width_scale,
                )
            else:
                kernel = airy_psf(r.psf_radius_px, px, m.wavelength_um, m.numerical_aperture)
                kernel = defocus(kernel, px, r.defocus_sigma_um)
                kernel = kernel / kernel.sum(dtype=np.float64)
            kernel = np.asarray(kernel, np.float32)
            kernel.setflags(write=False)
            self._kernels[key] = kernel
        return kernel

    # ------------------------------------------------------------------ render
    def _check_scene(self, scene: Any) -> None:
        r, m = self.render_settings, self.microscope
        if scene.upsample != r.upsample:
            raise ValueError(
                f"the scene was drawn with upsample={scene.upsample} but the render settings "
                f"say {r.upsample}: redraw the scene with these settings"
            )
        if scene.border_px < r.psf_radius_px:
            raise ValueError(
                f"the scene's border ({scene.border_px} px) is narrower than the PSF radius "
                f"({r.psf_radius_px} px): redraw the scene with these render settings"
            )
        expected = m.pixel_size_um / r.upsample
        if not math.isclose(scene.pixel_size_um, expected, rel_tol=1e-6):
            raise ValueError(
                f"the scene's pixel size ({scene.pixel_size_um} um) differs from this "
                f"microscope's render pixel ({expected} um)"
            )

    def _convolve_resample(
        self, stack: np.ndarray, kernel: np.ndarray, factor: int, weights: np.ndarray | None = None
    ) -> np.ndarray:
        """``psf`` + ``resample`` stages on ``(N, Y, X)`` images (optionally combined first)."""
        fused = getattr(self.backend, "convolve_resample", None)
        if fused is not None:
            return fused(stack, kernel, factor, weights=weights)
        if weights is not None:
            combined = np.float32(weights[0]) * stack[0]
            for weight, image in zip(weights[1:], stack[1:]):
                combined = combined + np.float32(weight) * image
            return block_average(self.backend.convolve_valid(combined[None], kernel), factor)[0]
        return block_average(self.backend.convolve_valid(stack, kernel), factor)

    def components(self, scene: Any) -> dict[str, np.ndarray]:
        """Convolved, camera-resolution cells / media / device images (cached, read-only).

        With separate phase amplitudes also ``cells_phase`` and ``device_phase``: cells
        and device through the ring kernel.
        """
        if self.partially_coherent:
            raise ValueError(
                "the partially coherent phase model is not a sum of convolved components: "
                "use phase_image() or render_clean()"
            )
        self._check_scene(scene)
        kkey = self._kernel_key(scene.pixel_size_um)
        kernel = self.kernel(scene.pixel_size_um)
        if self.depth_layers:
            from napari_symbac.scene._draw import _fingerprint

            out = self._convolved(scene, ("media", "device"), kernel, kkey)
            trim = scene.border_px - self.render_settings.psf_radius_px
            profile = scene.depth_profile
            if profile is None:
                self._depth_cells(scene, trim)  # raises, naming the fix, unless no cells
            r = self.render_settings
            shares = "mid-plane" if profile is None else _fingerprint(profile)
            key = (
                ("depth", scene.fingerprints["cells"], shares),
                (*kkey, r.depth_layers, r.focus_offset_um, scene.depth_um),
                trim,
            )
            cells = self._cache.get(key)
            if cells is None:
                cells = np.ascontiguousarray(self._depth_cells(scene, trim))
                self._cache.put(key, cells)
            return {"cells": cells, **out}
        out = self._convolved(scene, COMPONENTS, kernel, kkey)
        if self.separate_phase:
            ring = self._convolved(
                scene, ("cells", "device"), self.ring_kernel(scene.pixel_size_um), ("ring", *kkey)
            )
            out["cells_phase"], out["device_phase"] = ring["cells"], ring["device"]
        return out

    def _convolved(
        self, scene: Any, names: tuple[str, ...], kernel: np.ndarray, kkey: tuple
    ) -> dict[str, np.ndarray]:
        trim = scene.border_px - self.render_settings.psf_radius_px
        out: dict[str, np.ndarray] = {}
        missing: list[str] = []
        for name in names:
            key = (scene.fingerprints[name], kkey, trim)
            cached = self._cache.get(key)
            if cached is None:
                missing.append(name)
            else:
                out[name] = cached
        if missing:
            stack = np.stack([getattr(scene, name) for name in missing])
            if trim:
                stack = stack[:, trim:-trim, trim:-trim]
            small = self._convolve_resample(stack, kernel, scene.upsample)
            for name, image in zip(missing, small):
                image = np.ascontiguousarray(image)
                self._cache.put((scene.fingerprints[name], kkey, trim), image)
                out[name] = image
        return out

    def render_clean(self, scene: Any, *, cache: bool = True) -> np.ndarray:
        """Noise-free camera-resolution image in ADU above the baseline (eq. 3, 15), float32.

        With ``cache=True`` (the default, for interactive tuning) each component is
        convolved once and cached (:meth:`components`), so a later change of
        intensities only recombines arrays. With ``cache=False`` (bulk rendering,
        where every frame is new) the components are weighted first and the
        composed image is convolved once (eq. 3 and 15 are linear): one transform
        pair per frame instead of one per changed component, no cache traffic.
        Both give the same image up to float32 rounding. The partially coherent
        phase model has one path (:meth:`phase_image` times ``media_intensity``).
        """
        r = self.render_settings
        if self.partially_coherent:
            image = (r.media_intensity * self.phase_image(scene)).astype(np.float32)
        elif cache:
            comps = self.components(scene)
            image = (
                np.float32(r.cell_intensity) * comps["cells"]
                + np.float32(r.media_intensity) * comps["media"]
                + np.float32(r.device_intensity) * comps["device"]
            )
            if self.separate_phase:
                p_cell, p_device = self.ring_amplitudes()
                image -= np.float32(p_cell) * comps["cells_phase"]
                image -= np.float32(p_device) * comps["device_phase"]
        elif (plan := self._static_plan(scene)) is not None:
            image = self._render_static(scene, plan)
        else:
            self._check_scene(scene)
            kernel = self.kernel(scene.pixel_size_um)
            trim = scene.border_px - r.psf_radius_px
            crop = (slice(trim, -trim),) * 2 if trim else (slice(None),) * 2
            # eq. 3 at render resolution (no stacked copy of the three components),
            # then one convolution of the composed image.
            if self.depth_layers:
                composed = np.float32(r.media_intensity) * scene.media[crop]
                composed += np.float32(r.device_intensity) * scene.device[crop]
                image = self._convolve_resample(composed[None], kernel, scene.upsample)[0]
                image += np.float32(r.cell_intensity) * self._depth_cells(scene, trim)
            else:
                composed = np.float32(r.cell_intensity) * scene.cells[crop]
                composed += np.float32(r.media_intensity) * scene.media[crop]
                composed += np.float32(r.device_intensity) * scene.device[crop]
                image = self._convolve_resample(composed[None], kernel, scene.upsample)[0]
            if self.separate_phase:
                p_cell, p_device = self.ring_amplitudes()
                phase = np.float32(p_cell) * scene.cells[crop]
                phase += np.float32(p_device) * scene.device[crop]
                ring = self.ring_kernel(scene.pixel_size_um)
                image = image - self._convolve_resample(phase[None], ring, scene.upsample)[0]
        for stage in self._clean_stages:
            image = np.asarray(stage.apply(image, scene), dtype=np.float32)  # type: ignore[misc]
        return image.astype(np.float32, copy=False)

    def _render_static(self, scene: Any, plan: _StaticPlan) -> np.ndarray:
        """``render_clean(cache=False)`` of a drawn scene: static layers once, cells per frame.

        ``(I_c - I_m) conv(C) + I_m conv(O) + I_t conv(D)`` (:mod:`~napari_symbac.optics.static`;
        with separate phase amplitudes ``- P_c conv_ring(C) - P_t conv_ring(D)``): the
        open and device images are convolved once and cached, keyed on their content
        and the kernel; the cells go through a circular transform over the columns
        and rows they can occupy.
        """
        image = plan.static.copy()
        if plan.cells is None:
            return image  # no cell can reach the camera's field of view
        cells = scene.cells[plan.cells]
        for weight, kernel in plan.cell_kernels:
            part = self.backend.convolve_resample_circular(  # type: ignore[attr-defined]
                cells, kernel, scene.upsample, plan.transform_shape, plan.out_shape
            )
            part *= weight
            image[plan.out] += part
        return image

    def _static_plan(
        self, scene: Any, *, always: bool = False, depth_cells: bool = False
    ) -> _StaticPlan | None:
        """The static image and the cells' transform of ``scene``'s geometry, or ``None``
        where the composed path renders it.

        ``None`` for scenes without static layers (not from ``draw_scene``, or
        modified since), backends without the circular transform, the depth-resolved
        cells image (eq. 16), and (unless
        ``always``: a caller with many frames in hand) the first frame of a geometry
        this model renders unless its static layers are in the shared cache already:
        they cost two transforms of the frame, which pay from the second frame of a
        series on (a model that renders one frame, e.g. an export item with
        randomised settings, stays on the composed path). The plan is memoised per
        geometry with this model's settings.

        ``depth_cells``: the caller images the cells through the depth itself (the
        batched renderer, :mod:`~napari_symbac.optics.batched`), so a depth-resolved
        model gets a plan too; its static image (media and device on the 2-D kernel)
        and cells' window hold, its ``cell_kernels`` (the 2-D cells) do not.
        """
        self._check_scene(scene)
        if (self.depth_layers and not depth_cells) or not hasattr(
            self.backend, "convolve_resample_circular"
        ):
            return None
        layers = static_layers(scene)
        if layers is None:
            return None
        key = (
            layers.fingerprint,
            scene.shape,
            scene.border_px,
            scene.upsample,
            scene.pixel_size_um,
        )
        plan = self._plans.get(key)
        if (
            plan is not None
            and plan.render is self.render_settings
            and plan.microscope is self.microscope
        ):
            return plan
        r = self.render_settings
        px = scene.pixel_size_um
        kkey = self._kernel_key(px)
        u = scene.upsample
        trim = scene.border_px - r.psf_radius_px
        if not always and key not in self._seen and not self._cache.has(
            (("open", layers.fingerprint), ("static", *kkey), trim, u)
        ):
            if len(self._seen) >= 64:
                self._seen.clear()
            self._seen.add(key)
            return None
        kernel = self.kernel(px)
        static = self._convolved_static(layers, (("static", *kkey), kernel), trim, u)
        image = np.float32(r.media_intensity) * static["open"]
        image += np.float32(r.device_intensity) * static["device"]
        cell_kernels = [(np.float32(r.cell_intensity - r.media_intensity), kernel)]
        if self.separate_phase:
            p_cell, p_device = self.ring_amplitudes()
            ring_kernel = self.ring_kernel(px)
            ring = self._convolved_static(
                layers, (("static-ring", *kkey), ring_kernel), trim, u, ("device",)
            )
            image -= np.float32(p_device) * ring["device"]
            cell_kernels.append((np.float32(-p_cell), ring_kernel))
        image.setflags(write=False)
        height, width = (n - 2 * trim for n in scene.shape)
        full = resample_fft_shape(height, width, u)
        r0, r1, c0, c1 = layers.extent
        rows = axis_window((r0 - trim, r1 - trim), height, kernel.shape[0], u, full[0])
        cols = axis_window(
            (c0 - trim, c1 - trim), width, kernel.shape[1], u, full[1], real=True
        )
        plan = _StaticPlan(r, self.microscope, image)
        if rows is not None and cols is not None:
            plan.cells = (
                slice(trim + rows.start, trim + rows.stop),
                slice(trim + cols.start, trim + cols.stop),
            )
            plan.out = (slice(rows.out_start, rows.out_stop), slice(cols.out_start, cols.out_stop))
            plan.transform_shape = (rows.length, cols.length)
            plan.out_shape = (rows.out_stop - rows.out_start, cols.out_stop - cols.out_start)
            plan.cell_kernels = [(w, k) for w, k in cell_kernels if w != 0]
        if len(self._plans) >= 8:
            self._plans.clear()
        self._plans[key] = plan
        return plan

    def _convolved_static(
        self,
        layers: Any,
        kernel: tuple[tuple, np.ndarray],
        trim: int,
        upsample: int,
        names: tuple[str, ...] = ("open", "device"),
    ) -> dict[str, np.ndarray]:
        """The open / device images of ``layers`` through ``kernel`` = ``(key, array)``
        (``psf`` + ``resample``), cached on their content, the kernel and the trim."""
        kkey, array = kernel
        out = {}
        for name in names:
            key = ((name, layers.fingerprint), kkey, trim, upsample)
            cached = self._cache.get(key)
            if cached is None:
                image = getattr(layers, name)
                image = image[trim : image.shape[0] - trim, trim : image.shape[1] - trim]
                cached = np.ascontiguousarray(
                    self._convolve_resample(image[None], array, upsample)[0]
                )
                self._cache.put(key, cached)
            out[name] = cached
        return out

    def add_noise(self, clean: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The ``camera`` stage: noise of ``render.noise_model``, baseline, uint16 (eq. 17),
        then the extra stages that act on the recorded image (clipping)."""
        model = self.render_settings.noise_model
        if model == "camera":
            recorded = apply_camera_noise(clean, self.camera, rng)
        elif model == "gaussian":
            recorded = apply_gaussian_noise(
                clean, self.camera, self.render_settings.gaussian_noise_sd_adu, rng
            )
        else:
            recorded = quantise(
                np.asarray(clean, np.float64) + self.camera.baseline_adu, self.camera
            )
        for stage in self._recorded_stages:
            recorded = np.asarray(stage.apply(recorded, None), dtype=recorded.dtype)  # type: ignore[misc]
        return recorded

    def render(self, scene: Any, rng: np.random.Generator, *, cache: bool = True) -> np.ndarray:
        """Camera image (uint16) with the noise model of ``render.noise_model``.

        ``cache=False`` is the fast path for bulk rendering (see :meth:`render_clean`);
        it draws the same noise numbers in the same order.
        """
        if not isinstance(rng, np.random.Generator):
            raise ValueError("rng must be a numpy.random.Generator (np.random.default_rng(seed))")
        return self.add_noise(self.render_clean(scene, cache=cache), rng)

    def render_fluorescence_3d(
        self, volume: np.ndarray, psf_3d: np.ndarray, upsample: int | None = None
    ) -> np.ndarray:
        """Sum-over-z convolution of eq. 16, area-averaged to camera pixels (float32).

        Parameters
        ----------
        volume
            ``(Z, Y, X)`` emitter density per plane, at render resolution, with a
            border of at least the PSF radius on every side (it is cropped away).
        psf_3d
            ``(Z, ky, kx)`` PSF planes matching ``volume``'s planes, e.g. from
            :func:`~napari_symbac.optics.psf.born_wolf_psf_3d`.
        upsample
            Block size of the resampling; defaults to ``render.upsample``.
        """
        image = self.backend.convolve_valid(volume, psf_3d, sum_planes=True)
        factor = self.render_settings.upsample if upsample is None else upsample
        return block_average(image, factor)


def _camera_dict(camera: Camera) -> dict[str, Any]:
    return {
        "baseline_adu": camera.baseline_adu,
        "sensitivity_adu_per_e": camera.sensitivity_adu_per_e,
        "dark_noise_e": camera.dark_noise_e,
        "bit_depth": camera.bit_depth,
    }
