"""Reproductions of the supplement's benchmarks (section 1, Fig. S1.3 and S1.4).

These functions render single synthetic cells with perfect ground truth and measure
how a traditional method misjudges their width: the inter-peak distance of a
membrane dye (Fig. S1.3) and Otsu thresholding of phase contrast (Fig. S1.4).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from napari_symbac.optics.backends import get_backend
from napari_symbac.optics.psf import born_wolf_psf_3d, jinc, phase_contrast_psf, radius_grid_um
from napari_symbac.settings import CONDENSERS, Condenser, Microscope, RenderSettings

__all__ = [
    "MembraneWidthResult",
    "gaussian_psf_3d",
    "membrane_dye_width",
    "otsu_width",
    "spherocylinder_hull_volume",
    "symbac_like_phase_kernel",
]


def gaussian_psf_3d(
    radius_px: int,
    pixel_size_um: float,
    z_um: np.ndarray,
    wavelength_um: float,
    numerical_aperture: float,
    refractive_index: float,
) -> np.ndarray:
    """3-D Gaussian approximation of the widefield PSF (Zhang et al. 2007), per plane sum 1.

    Lateral s.d. ``0.21 lambda / NA``; axial s.d. ``0.66 lambda n / NA^2`` sets how
    fast the lateral width grows out of focus (``sigma(z)^2 = sigma_xy^2 (1 +
    (z / sigma_z)^2)``, so each plane still conserves power, as a widefield
    objective does).
    """
    sigma_xy = 0.21 * wavelength_um / numerical_aperture
    sigma_z = 0.66 * wavelength_um * refractive_index / numerical_aperture**2
    coords = np.arange(-radius_px, radius_px + 1) * pixel_size_um
    r2 = coords[None, :] ** 2 + coords[:, None] ** 2
    planes = []
    for z in np.atleast_1d(z_um):
        s2 = sigma_xy**2 * (1 + (z / sigma_z) ** 2)
        plane = np.exp(-r2 / (2 * s2))
        planes.append(plane / plane.sum())
    return np.asarray(planes, np.float32)


def spherocylinder_hull_volume(
    width_um: float,
    length_um: float,
    pixel_size_um: float,
    z_step_um: float,
    border_px: int,
    shell_um: float = 0.04,
) -> tuple[np.ndarray, np.ndarray]:
    """Hollow spherocylinder hull (a membrane) lying in the focal plane, axis along y.

    Voxels whose 3-D distance to the axis segment lies in ``[r - shell, r]`` hold 1
    (supplement Fig. S1.2), 0 elsewhere; the cell's centre-line is at ``z = 0``.

    Returns
    -------
    volume, z_um
        ``(Z, Y, X)`` float32 volume with a border of ``border_px`` pixels and the
        plane positions.
    """
    r = width_um / 2
    half = length_um / 2 - r
    nz = math.ceil(r / z_step_um)
    z = np.arange(-nz, nz + 1) * z_step_um
    ny = math.ceil(length_um / 2 / pixel_size_um) + 1 + border_px
    nx = math.ceil(r / pixel_size_um) + 1 + border_px
    y = np.arange(-ny, ny + 1) * pixel_size_um
    x = np.arange(-nx, nx + 1) * pixel_size_um
    dy = np.abs(y) - np.clip(np.abs(y), 0, half)
    d = np.sqrt(z[:, None, None] ** 2 + dy[None, :, None] ** 2 + x[None, None, :] ** 2)
    shell = min(shell_um, r)
    volume = ((d <= r) & (d >= r - shell)).astype(np.float32)
    return volume, z


def _two_peaks(profile: np.ndarray, pixel_size_um: float) -> float:
    """Distance between the highest maxima left and right of the centre (0 if merged)."""
    c = profile.size // 2
    left = int(np.argmax(profile[: c + 1]))
    right = c + int(np.argmax(profile[c:]))
    if left == c or right == c:
        return 0.0
    # Sub-pixel refinement by a parabola through each peak.
    pos = []
    for i in (left, right):
        y0, y1, y2 = profile[i - 1], profile[i], profile[i + 1]
        denom = y0 - 2 * y1 + y2
        pos.append(i + (0.5 * (y0 - y2) / denom if denom != 0 else 0.0))
    return (pos[1] - pos[0]) * pixel_size_um


@dataclass(frozen=True)
class MembraneWidthResult:
    """Width from the inter-peak distance of a membrane-dye profile (Fig. S1.3)."""

    true_width_um: float
    measured_width_um: float

    @property
    def relative_error(self) -> float:
        """``(true - measured) / true``: 1 means the two peaks merged."""
        return (self.true_width_um - self.measured_width_um) / self.true_width_um


def membrane_dye_width(
    width_um: float,
    microscope: Microscope,
    psf: str = "born-wolf",
    length_um: float = 3.0,
    pixel_size_um: float = 0.02,
    z_step_um: float = 0.02,
    radius_px: int = 40,
    shell_um: float = 0.04,
) -> MembraneWidthResult:
    """Image a membrane-stained cell in 3-D (eq. 16) and measure its inter-peak width.

    The hollow hull of :func:`spherocylinder_hull_volume` is convolved plane by plane
    with a 3-D PSF and summed over z (eq. 16); the width is read as the distance
    between the two intensity maxima across the minor axis at mid-length.

    Parameters
    ----------
    psf
        ``"born-wolf"`` (:func:`~napari_symbac.optics.psf.born_wolf_psf_3d`) or
        ``"gaussian"`` (:func:`gaussian_psf_3d`).
    """
    volume, z = spherocylinder_hull_volume(
        width_um, length_um, pixel_size_um, z_step_um, radius_px, shell_um
    )
    args = (
        radius_px,
        pixel_size_um,
        z,
        microscope.wavelength_um,
        microscope.numerical_aperture,
        microscope.refractive_index,
    )
    if psf == "born-wolf":
        kernel = born_wolf_psf_3d(*args)
    elif psf == "gaussian":
        kernel = gaussian_psf_3d(*args)
    else:
        raise ValueError(f"psf must be 'born-wolf' or 'gaussian', got {psf!r}")
    image = get_backend("scipy").convolve_valid(volume, kernel, sum_planes=True)
    profile = image[image.shape[0] // 2]
    return MembraneWidthResult(width_um, _two_peaks(profile.astype(np.float64), pixel_size_um))


def symbac_like_phase_kernel(
    radius_px: int,
    pixel_size_um: float,
    wavelength_um: float,
    numerical_aperture: float,
    condenser: str | Condenser,
    apodisation_sigma_um: float,
) -> np.ndarray:
    """Near-zero-DC phase kernel with SyMBac's normalisation, for comparison only.

    Eq. 7 taken literally, as an *amplitude* difference of two Airy terms,
    ``jinc(omega) - a^2 jinc(a omega)`` with ``a = ((R - W) / R)^2`` (the scaling of
    the SyMBac implementation), scaled to a peak of 1, divided by its own sum and
    apodised (eq. 11-12). Both Airy terms have the same integral, so their
    difference is a band-pass filter (an annulus in frequency space): the sum it is
    divided by nearly cancels, and the kernel passes almost no DC. It is returned
    with the sign that makes cells (lower eq. 3 intensity) dark, i.e. SyMBac's
    negative kernel applied to its OPL image, where cells are high. Not used by the
    renderer (:func:`~napari_symbac.optics.psf.phase_contrast_psf` has DC gain 1).
    """
    cond = condenser if isinstance(condenser, Condenser) else CONDENSERS[condenser]
    r = radius_grid_um(radius_px, pixel_size_um)
    omega = 2 * math.pi * numerical_aperture * r / wavelength_um
    a = ((cond.ring_radius_mm - cond.ring_width_mm) / cond.ring_radius_mm) ** 2
    k = jinc(omega) - a**2 * jinc(a * omega)
    k = k / k.max()
    k = k / k.sum()
    k = k * np.exp(-(r**2) / (2 * apodisation_sigma_um**2))
    return k.astype(np.float32)


def otsu_width(
    width_um: float,
    microscope: Microscope,
    render: RenderSettings,
    length_um: float = 3.0,
    n_shifts: int = 8,
    depth_um: float = 1.5,
    kernel: str = "model",
    profile: str = "rounded",
) -> float:
    """Width of a single phase-contrast cell segmented by Otsu's method (Fig. S1.4).

    A cell in media of optical depth ``depth_um`` (no device) is rendered at camera sampling
    without noise, thresholded with :func:`skimage.filters.threshold_otsu` over the
    whole frame (cell plus about 1.5 um of media on every side), and its width read
    as the mask's width at mid-length (the number of pixels across the middle five
    rows of the dark object on the cell's axis, holes filled, times the pixel size).
    The result is the mean over ``n_shifts`` sub-pixel positions of the cell across
    the pixel grid, so it is not quantised to whole camera pixels.

    Parameters
    ----------
    kernel
        ``"model"``: the renderer's kernel
        (:func:`~napari_symbac.optics.psf.phase_contrast_psf`, DC gain 1);
        ``"symbac"``: :func:`symbac_like_phase_kernel` (near-zero DC) with the
        same apodisation.
    profile
        ``"rounded"``: cell material proportional to the chord of the 3-D
        spherocylinder (eq. OPL2, as rendered); ``"flat"``: a flat-topped cell of
        the same peak thickness (a binary mask), for comparison.
    """
    if kernel not in ("model", "symbac"):
        raise ValueError(f"kernel must be 'model' or 'symbac', got {kernel!r}")
    if profile not in ("rounded", "flat"):
        raise ValueError(f"profile must be 'rounded' or 'flat', got {profile!r}")
    widths = [
        _otsu_width_once(
            width_um, microscope, render, length_um, k / n_shifts, depth_um, kernel, profile
        )
        for k in range(n_shifts)
    ]
    return float(np.mean(widths))


def _otsu_width_once(
    width_um: float,
    microscope: Microscope,
    render: RenderSettings,
    length_um: float,
    shift_px: float,
    depth_um: float,
    kernel_model: str = "model",
    profile: str = "rounded",
) -> float:
    from scipy.ndimage import binary_fill_holes
    from skimage.filters import threshold_otsu
    from skimage.measure import label

    u = render.upsample
    px = microscope.pixel_size_um / u
    radius = render.psf_radius_px
    cam = math.ceil((length_um + 3.0) / microscope.pixel_size_um)
    n = cam * u + 2 * radius
    coords = (np.arange(n) - n / 2 + 0.5) * px
    xx, yy = np.meshgrid(coords - shift_px * microscope.pixel_size_um, coords)
    r = width_um / 2
    half = length_um / 2 - r
    d = np.hypot(xx, np.abs(yy) - np.clip(np.abs(yy), 0, half))
    if profile == "flat":
        cells = (d <= r) * (width_um / depth_um)
    else:
        cells = 2 * np.sqrt(np.maximum(r * r - d * d, 0)) / depth_um
    opl = render.cell_intensity * cells + render.media_intensity * (1 - cells)
    if kernel_model == "symbac":
        kernel = symbac_like_phase_kernel(
            radius,
            px,
            microscope.wavelength_um,
            microscope.numerical_aperture,
            microscope.condenser,
            render.apodisation_sigma_um,
        )
    else:
        kernel = phase_contrast_psf(
            radius,
            px,
            microscope.wavelength_um,
            microscope.numerical_aperture,
            microscope.condenser,
            render.apodisation_sigma_um,
            render.ring_contrast,
            render.defocus_sigma_um,
            render.psf_offset,
        )
    image = get_backend("scipy").convolve_valid(opl[None].astype(np.float32), kernel)[0]
    image = image.reshape(cam, u, cam, u).mean(axis=(1, 3))
    mask = image < threshold_otsu(image)  # cells are dark in phase contrast
    lab = label(mask)
    c = cam // 2
    # Objects crossing the middle row inside the true cell; with an edge-detecting
    # (near-zero-DC) kernel the dark class can be a ring around a lighter centre,
    # so holes are filled before the width is read.
    half_px = int(r / microscope.pixel_size_um)
    ids = np.unique(lab[c, c - half_px : c + half_px + 1])
    ids = ids[ids > 0]
    if ids.size == 0:
        return 0.0
    cell = binary_fill_holes(np.isin(lab, ids))
    mid = cell[c - 2 : c + 3]
    return float(mid.sum(axis=1).mean() * microscope.pixel_size_um)
