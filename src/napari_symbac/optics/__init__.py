"""Optics: PSFs (eq. 6-14), convolution backends, the forward model, camera (eq. 17-19).

The forward model's batched renderer on a torch device is :mod:`.batched` (torch is
imported only when it is used).

Also Fourier/histogram matching (section 6-7) and Perlin background texture (13.2).
"""

from napari_symbac.optics import (
    backends,
    batched,
    camera,
    matching,
    psf,
    texture,
)
from napari_symbac.optics.backends import available_backends, get_backend
from napari_symbac.optics.batched import BatchedRenderer, render_scenes, resolve_backend
from napari_symbac.optics.camera import (
    DarkCalibration,
    apply_camera_noise,
    apply_gaussian_noise,
    calibrate_camera,
)
from napari_symbac.optics.forward import COMPONENTS, ForwardModel, Stage, block_average
from napari_symbac.optics.matching import match_fourier_spectrum, match_histogram
from napari_symbac.optics.psf import (
    airy_psf,
    apodise,
    born_wolf_psf_3d,
    defocus,
    gaussian_kernel,
    phase_contrast_psf,
)
from napari_symbac.optics.texture import perlin_texture, random_perlin_texture, texture_stage

__all__ = [
    "COMPONENTS",
    "BatchedRenderer",
    "DarkCalibration",
    "ForwardModel",
    "Stage",
    "airy_psf",
    "apodise",
    "apply_camera_noise",
    "apply_gaussian_noise",
    "available_backends",
    "backends",
    "batched",
    "block_average",
    "born_wolf_psf_3d",
    "calibrate_camera",
    "camera",
    "defocus",
    "gaussian_kernel",
    "get_backend",
    "match_fourier_spectrum",
    "match_histogram",
    "matching",
    "perlin_texture",
    "phase_contrast_psf",
    "psf",
    "random_perlin_texture",
    "render_scenes",
    "resolve_backend",
    "texture",
    "texture_stage",
]
