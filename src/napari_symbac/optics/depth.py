"""The depth-resolved fluorescence image (eq. 16): each slab of the stain through the PSF
defocused by its distance from the focal plane.

``S = sum_z PSF_z conv OPL_z``: the slabs of :func:`~napari_symbac.scene.stain_layers`
(a scene's :attr:`~napari_symbac.scene.Scene.depth_profile` times its cells image), each
convolved with the scalar Debye PSF
(:func:`~napari_symbac.optics.psf.born_wolf_psf_3d`, index-matched) at the slab
middle's height less ``RenderSettings.focus_offset_um``, with the Gaussian defocus of
eq. 14 on top, then summed and area-averaged to camera pixels.
"""

from __future__ import annotations

import numpy as np

from napari_symbac.optics.psf import born_wolf_psf_3d, defocus
from napari_symbac.settings import Microscope, RenderSettings

__all__ = ["depth_kernels"]


def depth_kernels(
    microscope: Microscope, render: RenderSettings, depth_um: float, pixel_size_um: float
) -> np.ndarray:
    """The PSF of every slab of ``render.depth_layers`` through ``depth_um`` (eq. 16).

    ``(depth_layers, 2 R + 1, 2 R + 1)`` float32 (``R = render.psf_radius_px``), each
    plane the Born-Wolf PSF at height ``z_k - focus_offset_um`` (``z_k`` the slab's
    middle from the cells' mid-plane,
    :func:`~napari_symbac.scene.depth_layer_centres_um`) convolved with the Gaussian of
    ``defocus_sigma_um`` (eq. 14), normalised to sum 1: every slab's light reaches the
    camera whole, only spread. ``depth_layers = 0`` is an error (there are no slabs).
    """
    from napari_symbac.scene import depth_layer_centres_um

    if render.depth_layers < 1:
        raise ValueError("depth kernels need RenderSettings.depth_layers >= 1")
    z = depth_layer_centres_um(depth_um, render.depth_layers) - render.focus_offset_um
    planes = born_wolf_psf_3d(
        render.psf_radius_px,
        pixel_size_um,
        z,
        microscope.wavelength_um,
        microscope.numerical_aperture,
        microscope.refractive_index,
    )
    out = np.empty_like(planes)
    for k, plane in enumerate(planes):
        blurred = defocus(plane, pixel_size_um, render.defocus_sigma_um).astype(np.float64)
        out[k] = blurred / blurred.sum()
    out.setflags(write=False)
    return out
