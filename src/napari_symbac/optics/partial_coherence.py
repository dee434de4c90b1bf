"""Phase contrast beyond the weak-phase approximation: annular partially coherent imaging.

The linear kernels of :mod:`napari_symbac.optics.psf` (eq. 7-14) treat the image as
a convolution of the sample, which is the first-order (weak-phase) expansion of
``exp(i phi)``. A cell ~1 um thick with ``n_cell - n_media ~ 0.05`` delays light by
``phi ~ 2 pi 0.05 / 0.55 ~ 0.6 rad``, and a colony adds such phases edge to edge: not
weak. This module forms the image the way the microscope does (Koehler
illumination from the condenser annulus, the phase plate in the objective's back
focal plane), the incoherent sum over source points ``s`` of the annulus of
coherent images:

``I(x) = < | IFT[ FT(t)(f) P(s + f) Q(s + f) ] (x) |^2 >_s / |q|^2``

with ``t = sqrt(B) exp(i phi)`` the sample's complex transmission (``B`` the
bright-field transmission of eq. 3 relative to the media, ``phi`` the phase of
eq. OPL1-3 relative to the media), ``P`` the pupil (radius ``NA / lambda``), ``Q``
the plate (``q = sqrt(T_plate) exp(-i theta)`` on the ring conjugate to the annulus,
1 elsewhere). Dividing by the empty field's value (``|q|^2`` for a sharp ring) makes
an empty field 1. Gaussian apodisation
of eq. 11-12 (the PSF times ``G(r, sigma)``) is a Gaussian blur of the pupil
functions, applied here as soft edges of the pupil and the ring. Defocus is the pupil
phase of free propagation, ``exp(i 2 pi z (sqrt(n^2 / lambda^2 - |k|^2) - n / lambda))``
at spatial frequency ``k`` (``z`` the focal plane's distance from the sample, ``n`` the
immersion index): unlike the Gaussian blur of eq. 14, which only smooths, it moves
light between a cell's rim and its centre, and its sign matters. In focus (``z = 0``)
and to first order in ``phi`` this is ``1 + (2 sin(theta) / |q|) phi conv h`` with ``h``
the transfer function of :func:`~napari_symbac.optics.psf.annulus_transfer_function` (tested).
"""

from __future__ import annotations

import functools
import math

import numpy as np
from scipy import fft, special

from napari_symbac.settings import CONDENSERS, Condenser

__all__ = ["annular_phase_image"]

#: Softness widths beyond the pupil's edge at which its soft edge is taken as 0.
_EDGE_REACH = 10.0


def _soft_inside(u: np.ndarray, edge: float, softness: float) -> np.ndarray:
    """1 inside ``u < edge``, 0 outside, with a Gaussian-integral edge of width ``softness``."""
    if softness <= 0:
        return (u <= edge).astype(np.float64)
    return 0.5 * special.erfc((u - edge) / (math.sqrt(2) * softness))


def annular_phase_image(
    transmission: np.ndarray,
    phase_rad: np.ndarray,
    pixel_size_um: float,
    wavelength_um: float,
    numerical_aperture: float,
    condenser: str | Condenser,
    plate_transmission: float,
    plate_phase_rad: float,
    apodisation_sigma_um: float,
    ring_width_scale: float = 1.0,
    n_source_points: int = 48,
    focus_offset_um: float = 0.0,
    refractive_index: float = 1.518,
) -> np.ndarray:
    """Partially coherent phase-contrast image of a thin sample (module notes).

    Parameters
    ----------
    transmission
        Bright-field intensity transmission ``B >= 0`` relative to the media (2-D).
    phase_rad
        Phase delay ``phi`` relative to the media, radians (same shape).
    pixel_size_um, wavelength_um, numerical_aperture
        Sampling and optics (eq. 8); the sampling must resolve the pupil:
        ``pixel_size_um <= lambda / (4 NA)`` for the image's band (``2 NA / lambda``).
    condenser
        Annulus radii (eq. 7); the plate's ring is centred on its image.
    plate_transmission
        Intensity transmission ``T_plate = |q|^2`` of the ring, in ``(0, 1]``.
    plate_phase_rad
        Phase advance ``theta`` of the ring; ``pi / 2``: positive (dark-medium) phase
        contrast, in which cells denser than the media look dark with a bright halo.
    apodisation_sigma_um
        ``sigma`` of eq. 11-12 (image-space Gaussian): soft pupil and ring edges of
        width ``1 / (2 pi sigma)`` in spatial frequency.
    ring_width_scale
        Plate ring width over the catalogue annulus width (>= 0.5).
    n_source_points
        Points of the annulus summed (angles x 2 radii).
    focus_offset_um
        Distance of the focal plane from the sample along the light's path, um:
        positive when the focus lies past the sample, towards the objective.
    refractive_index
        Index ``n`` of the medium the defocus is in (the immersion's), ``> NA``.

    Returns
    -------
    numpy.ndarray
        float64 image, 1 for an empty field, same shape as the inputs. The FFT is
        periodic: pad the sample (mirror-wise) by the halo's reach beforehand.
    """
    b = np.asarray(transmission, np.float64)
    phi = np.asarray(phase_rad, np.float64)
    if b.ndim != 2 or b.shape != phi.shape:
        raise ValueError(
            f"transmission {b.shape} and phase_rad {phi.shape} must be 2-D of one shape"
        )
    if not (np.all(np.isfinite(b)) and np.all(np.isfinite(phi)) and b.min() >= 0):
        raise ValueError("transmission must be finite and >= 0, phase_rad finite")
    if not (0 < plate_transmission <= 1):
        raise ValueError(f"plate_transmission must be in (0, 1], got {plate_transmission!r}")
    if not math.isfinite(plate_phase_rad):
        raise ValueError(f"plate_phase_rad must be finite, got {plate_phase_rad!r}")
    if not (math.isfinite(apodisation_sigma_um) and apodisation_sigma_um > 0):
        raise ValueError(f"apodisation_sigma_um must be positive, got {apodisation_sigma_um!r}")
    if not (math.isfinite(ring_width_scale) and ring_width_scale >= 0.5):
        raise ValueError(f"ring_width_scale must be >= 0.5, got {ring_width_scale!r}")
    if pixel_size_um > wavelength_um / (4 * numerical_aperture) * 1.0001:
        raise ValueError(
            f"pixel size {pixel_size_um} um does not sample the image band of NA "
            f"{numerical_aperture} at {wavelength_um} um (needs <= "
            f"{wavelength_um / (4 * numerical_aperture):.4f} um): render with a larger "
            "upsample"
        )
    if not math.isfinite(focus_offset_um):
        raise ValueError(f"focus_offset_um must be finite, got {focus_offset_um!r}")
    if not refractive_index > numerical_aperture:
        raise ValueError(
            f"refractive_index {refractive_index!r} must exceed the NA {numerical_aperture}"
        )
    if n_source_points < 8:
        raise ValueError(f"n_source_points must be at least 8, got {n_source_points!r}")
    cond = condenser if isinstance(condenser, Condenser) else CONDENSERS.get(condenser)
    if cond is None:
        raise ValueError(f"unknown condenser {condenser!r}; choose one of {', '.join(CONDENSERS)}")
    # transforms of a length with large prime factors are slow (971 rows: 3 times a
    # 972's): extended mirror-wise to the next fast lengths, the extension cut off after
    rows, cols = b.shape
    shape = (fft.next_fast_len(rows), fft.next_fast_len(cols))
    extend = ((0, shape[0] - rows), (0, shape[1] - cols))
    sample = np.pad(np.sqrt(b) * np.exp(1j * phi), extend, mode="symmetric")
    spectrum = fft.fft2(sample).ravel()
    pupils, empty = _source_pupils(
        shape,
        pixel_size_um,
        numerical_aperture / wavelength_um,
        cond,
        plate_transmission,
        plate_phase_rad,
        apodisation_sigma_um,
        ring_width_scale,
        n_source_points,
        focus_offset_um,
        refractive_index / wavelength_um,
    )
    image = np.zeros(shape)
    for inside, pupil in pupils:
        passed = np.zeros_like(spectrum)
        passed[inside] = spectrum[inside] * pupil
        image += np.abs(fft.ifft2(passed.reshape(shape), overwrite_x=True)) ** 2
    return image[:rows, :cols] / empty


@functools.lru_cache(maxsize=1)
def _source_pupils(
    shape: tuple[int, int],
    pixel_size_um: float,
    cutoff: float,
    cond: Condenser,
    plate_transmission: float,
    plate_phase_rad: float,
    apodisation_sigma_um: float,
    ring_width_scale: float,
    n_source_points: int,
    focus_offset_um: float,
    n_over_lambda: float,
) -> tuple[tuple[tuple[np.ndarray, np.ndarray], ...], float]:
    """Each source point's pupil times plate, ``P(s + f) Q(s + f)``, where it is not 0,
    and the empty field's intensity (the sum of the direct light's ``|P Q|^2``).

    The pupil is 0 beyond its soft edge (to ``erfc(10 / sqrt 2) ~ 1e-23``): kept only
    inside, a tenth to a fifth of the frequencies, as flat indices and values. The last
    optics are kept: every frame of a series is rendered through the same pupils (for a
    frame of 971 x 1096, 12 source points: 31 MB, and 0.6 s a frame becomes 0.35 s).
    """
    fy = np.fft.fftfreq(shape[0], pixel_size_um)[:, None] / cutoff
    fx = np.fft.fftfreq(shape[1], pixel_size_um)[None, :] / cutoff
    softness = 1.0 / (2 * math.pi * apodisation_sigma_um * cutoff)  # pupil units
    centre = 0.5 * (cond.outer_fraction + cond.inner_fraction)
    half = 0.5 * (cond.outer_fraction - cond.inner_fraction)
    ring_in, ring_out = centre - half * ring_width_scale, centre + half * ring_width_scale
    q = math.sqrt(plate_transmission) * complex(
        math.cos(plate_phase_rad), -math.sin(plate_phase_rad)
    )
    reach = 1.0 + _EDGE_REACH * softness
    n_angles = n_source_points // 2
    pupils = []
    empty = 0.0
    for radius in (centre - 0.5 * half, centre + 0.5 * half):
        for angle in np.arange(n_angles) * (2 * math.pi / n_angles):
            u = np.hypot(fx + radius * math.cos(angle), fy + radius * math.sin(angle)).ravel()
            inside = np.flatnonzero(u < reach).astype(np.int32)
            u = u[inside]
            pupil = _plate_pupil(u, q, ring_in, ring_out, softness)
            if focus_offset_um:
                pupil = pupil * _defocus_phase(u * cutoff, focus_offset_um, n_over_lambda)
            inside.flags.writeable = pupil.flags.writeable = False
            pupils.append((inside, pupil))
            # the direct light of this source point (f = 0) meets the plate at u = radius
            empty += abs(_plate_pupil(np.array(radius), q, ring_in, ring_out, softness)) ** 2
    return tuple(pupils), empty


def _defocus_phase(k: np.ndarray, z_um: float, n_over_lambda: float) -> np.ndarray:
    """Free propagation by ``z_um`` of the plane wave of spatial frequency ``|k|`` (1/um).

    The constant ``n / lambda`` is taken out (a phase common to the whole image); the
    evanescent part beyond ``n / lambda``, reached only by a soft pupil edge, gets none.
    """
    kz = np.sqrt(np.maximum(n_over_lambda**2 - k**2, 0.0))
    return np.exp(2j * math.pi * z_um * (kz - n_over_lambda))


def _plate_pupil(
    u: np.ndarray, q: complex, ring_in: float, ring_out: float, softness: float
) -> np.ndarray:
    """Pupil times plate at normalised pupil radius ``u``: ``P (1 + (q - 1) R)``."""
    ring = _soft_inside(u, ring_out, softness) - _soft_inside(u, ring_in, softness)
    return _soft_inside(u, 1.0, softness) * (1 + (q - 1) * ring)
