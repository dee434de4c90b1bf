"""Point spread functions (supplement section 4, eq. 6-14, and section 5).

Conventions
-----------
Kernels are square float32 arrays of side ``2 * radius_px + 1`` sampled at the
render-resolution pixel size, centred on the middle pixel (eq. 9-10).

Argument of the Bessel functions. Eq. 6 and 8 of the supplement write
``omega = 2 pi NA r / (n lambda)``. The diffraction-limited Airy pattern of an
objective of numerical aperture NA at *vacuum* wavelength ``lambda`` is
``omega = 2 pi NA r / lambda`` (first zero at ``0.61 lambda / NA``), whatever the
immersion medium: NA already contains ``n``. The two agree for the supplement's
``n = 1`` example (Fig. S4.2); we use the physically correct form, so an oil
objective's Airy disk is not shrunk by a further factor 1.518.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import special

from napari_symbac.settings import CONDENSERS, Condenser

__all__ = [
    "RING_MODELS",
    "airy_psf",
    "annulus_transfer_function",
    "apodise",
    "born_wolf_psf_3d",
    "brightfield_kernels",
    "defocus",
    "gaussian_kernel",
    "jinc",
    "phase_contrast_kernels",
    "phase_contrast_parts",
    "phase_contrast_psf",
    "radius_grid_um",
]


def _check_radius(radius_px: int) -> None:
    if not isinstance(radius_px, (int, np.integer)) or radius_px < 1:
        raise ValueError(f"radius_px must be an integer >= 1, got {radius_px!r}")


def _check_positive(**values: float) -> None:
    for name, value in values.items():
        if not (
            isinstance(value, (int, float, np.floating)) and math.isfinite(value) and value > 0
        ):
            raise ValueError(f"{name} must be a positive finite number, got {value!r}")


def radius_grid_um(radius_px: int, pixel_size_um: float) -> np.ndarray:
    """Distance of every kernel pixel to the centre, in um (eq. 9)."""
    _check_radius(radius_px)
    _check_positive(pixel_size_um=pixel_size_um)
    coords = np.arange(-radius_px, radius_px + 1, dtype=np.float64) * pixel_size_um
    return np.hypot(coords[None, :], coords[:, None])


def jinc(x: np.ndarray) -> np.ndarray:
    """``2 J1(x) / x`` with its limit 1 at ``x = 0`` (amplitude PSF of a disk pupil)."""
    x = np.asarray(x, dtype=np.float64)
    out = np.ones_like(x)
    nz = x != 0
    out[nz] = 2 * special.j1(x[nz]) / x[nz]
    return out


def airy_psf(
    radius_px: int, pixel_size_um: float, wavelength_um: float, numerical_aperture: float
) -> np.ndarray:
    """Fluorescence (incoherent) PSF, the Airy pattern of eq. 6, normalised to sum 1.

    ``PSF(r) = [2 J1(omega) / omega]^2`` with ``omega = 2 pi NA r / lambda`` (vacuum
    wavelength; see the module notes for the supplement's extra ``n``). Its first
    zero is at ``r = 0.61 lambda / NA``.
    """
    _check_positive(wavelength_um=wavelength_um, numerical_aperture=numerical_aperture)
    r = radius_grid_um(radius_px, pixel_size_um)
    psf = jinc(2 * math.pi * numerical_aperture * r / wavelength_um) ** 2
    return (psf / psf.sum()).astype(np.float32)


def gaussian_kernel(radius_px: int, pixel_size_um: float, sigma_um: float) -> np.ndarray:
    """Normalised 2-D Gaussian ``G(R, sigma)`` of eq. 11 (sum 1)."""
    _check_positive(sigma_um=sigma_um)
    r = radius_grid_um(radius_px, pixel_size_um)
    g = np.exp(-(r**2) / (2 * sigma_um**2))
    return (g / g.sum()).astype(np.float32)


def apodise(kernel: np.ndarray, pixel_size_um: float, sigma_um: float) -> np.ndarray:
    """Gaussian apodisation, eq. 11-12: ``PSF * exp(-r^2 / (2 sigma^2))`` (Hadamard product)."""
    kernel = np.asarray(kernel)
    if kernel.ndim != 2 or kernel.shape[0] != kernel.shape[1] or kernel.shape[0] % 2 != 1:
        raise ValueError(f"kernel must be square with an odd side, got shape {kernel.shape}")
    _check_positive(sigma_um=sigma_um)
    r = radius_grid_um(kernel.shape[0] // 2, pixel_size_um)
    return (kernel * np.exp(-(r**2) / (2 * sigma_um**2))).astype(np.float32)


def defocus(kernel: np.ndarray, pixel_size_um: float, sigma_um: float) -> np.ndarray:
    """Defocus, eq. 14: the kernel convolved with a Gaussian of s.d. ``sigma_um``.

    The result keeps the kernel's size and its sum (the part of the blur that would
    fall outside the kernel's radius is renormalised back). ``sigma_um = 0`` returns
    the kernel unchanged.
    """
    kernel = np.asarray(kernel, dtype=np.float64)
    if not (math.isfinite(sigma_um) and sigma_um >= 0):
        raise ValueError(f"defocus sigma_um must be zero or positive, got {sigma_um!r}")
    if sigma_um == 0:
        return kernel.astype(np.float32)
    from scipy.ndimage import gaussian_filter

    total = kernel.sum()
    out = gaussian_filter(kernel, sigma_um / pixel_size_um, mode="constant", truncate=4.0)
    if total != 0 and out.sum() != 0:
        out *= total / out.sum()
    return out.astype(np.float32)


def brightfield_kernels(
    radius_px: int,
    pixel_size_um: float,
    wavelength_um: float,
    numerical_aperture: float,
    *,
    defocus_sigma_um: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Bright-field kernels ``(k, laplacian(k))`` (float32): ``k`` sums to 1, the second
    to 0.

    ``k`` is the Airy pattern (eq. 6) blurred by eq. 14's defocus: a sample's absorption
    is imaged through it, as in fluorescence, under a condenser that fills the
    objective's aperture. A transparent sample in focus shows no contrast in bright
    field; out of focus by ``z`` its phase ``phi`` shows as the transport-of-intensity
    equation gives, ``I(z) = I_0 (1 - z lambda / (2 pi n) laplacian(phi))`` (``n`` the
    immersion index): a cell, a lens, gathers light into its centre on one side of
    focus and spreads it to its rim on the other. The image of the cells' phase map is
    ``laplacian(k)`` convolved with it, weighted by ``I_0 kappa``, ``kappa = z lambda
    phi / (2 pi n)`` (``RenderSettings.defocus_contrast_um2``, ``phi`` a full-depth
    column's phase). The discrete Laplacian (5 points, at the render pixel, per um^2)
    is made to sum to 0 exactly (a part ``k`` times its sum removed: ~1e-5 of it, the
    kernel's edge), so an empty field keeps its level.
    """
    from scipy.ndimage import laplace

    kernel = np.asarray(
        defocus(
            airy_psf(radius_px, pixel_size_um, wavelength_um, numerical_aperture),
            pixel_size_um,
            defocus_sigma_um,
        ),
        np.float64,
    )
    kernel /= kernel.sum()
    curvature = laplace(kernel, mode="constant") / pixel_size_um**2
    curvature -= curvature.sum() * kernel
    return kernel.astype(np.float32), curvature.astype(np.float32)


def _condenser(condenser: str | Condenser) -> Condenser:
    if isinstance(condenser, Condenser):
        return condenser
    if condenser not in CONDENSERS:
        raise ValueError(f"unknown condenser {condenser!r}; choose one of {', '.join(CONDENSERS)}")
    return CONDENSERS[condenser]


#: Shapes of the ring part of the phase kernel (``RenderSettings.ring_model``).
RING_MODELS = ("airy", "annulus")


def annulus_transfer_function(
    size_px: int,
    pixel_size_um: float,
    wavelength_um: float,
    numerical_aperture: float,
    condenser: str | Condenser,
    ring_width_scale: float = 1.0,
    n_source_points: int = 64,
) -> np.ndarray:
    """Weak-phase transfer function of annular illumination through a phase plate.

    Partially coherent (Koehler) imaging with the condenser annulus as source: a
    source point ``s`` on the annulus sends its direct (undiffracted) light through
    the conjugate phase ring of the plate, which multiplies it by ``a exp(i theta)``
    (amplitude transmission ``a``, phase shift ``theta``). A weak phase object
    ``exp(i phi) ~ 1 + i phi`` diffracts light of spatial frequency ``f`` to the pupil
    point ``s + f``. To first order in ``phi`` the image of that source point is
    ``|a|^2 + 2 a sin(theta) [phi conv h_s]``, where ``h_s`` passes ``f`` fully when
    ``s + f`` lies inside the pupil but outside the ring (the diffracted wave is not
    shifted), and not at all when it falls in the ring (direct and diffracted waves
    shifted alike: no contrast) or outside the pupil; the odd part from
    ``theta != pi/2`` cancels over the symmetric annulus. Summing over the source
    points (the incoherent sum of eq. 7's annulus) gives

    ``H(f) = < P(s + f) [1 - R(s + f)] >_s``

    with ``P`` the pupil (radius ``NA / lambda``) and ``R`` the plate ring. ``H(0) = 0``
    (no contrast for a uniform phase: the shade-off of large objects) and ``H -> 1``
    at frequencies beyond the ring's width (the detail): the halo and the
    shade-off are the frequencies between. The overall gain ``2 sin(theta) / a``
    multiplies the ring part of the kernel (``RenderSettings.ring_contrast`` or the
    ``*_phase_adu`` amplitudes), so it does not appear here.

    Parameters
    ----------
    size_px
        Side of the (square, odd) frequency grid, the kernel's side.
    pixel_size_um, wavelength_um, numerical_aperture
        Render pixel size, vacuum wavelength, objective NA (eq. 8).
    condenser
        The annulus radii ``R - W`` and ``R`` (eq. 7) as fractions of the pupil.
    ring_width_scale
        Width of the plate's ring over the condenser's catalogue annulus width
        (>= 0.5: the ring must hold the direct light of the source points, which sit
        at a quarter of the annulus width either side of its centre line); the ring
        stays centred on the annulus.
    n_source_points
        Source points on the annulus (angles x 2 radii).

    Returns
    -------
    numpy.ndarray
        ``H`` on the unshifted FFT frequency grid (``numpy.fft.fftfreq`` order), in
        ``[0, 1]``.
    """
    _check_positive(
        pixel_size_um=pixel_size_um,
        wavelength_um=wavelength_um,
        numerical_aperture=numerical_aperture,
    )
    if not (math.isfinite(ring_width_scale) and ring_width_scale >= 0.5):
        raise ValueError(
            f"ring_width_scale must be >= 0.5 (the ring must hold the direct light of the "
            f"annulus' source points), got {ring_width_scale!r}"
        )
    if n_source_points < 8:
        raise ValueError(f"n_source_points must be at least 8, got {n_source_points!r}")
    cond = _condenser(condenser)
    rho_o, rho_i = cond.outer_fraction, cond.inner_fraction
    centre, half = 0.5 * (rho_o + rho_i), 0.5 * (rho_o - rho_i)
    plate_i, plate_o = centre - half * ring_width_scale, centre + half * ring_width_scale
    cutoff = numerical_aperture / wavelength_um
    freq = np.fft.fftfreq(size_px, pixel_size_um) / cutoff
    fx, fy = np.meshgrid(freq, freq)
    n_angles = n_source_points // 2
    radii = centre + half * np.array([-0.5, 0.5])
    transfer = np.zeros((size_px, size_px))
    for radius in radii:
        for angle in np.arange(n_angles) * (2 * math.pi / n_angles):
            u = np.hypot(fx + radius * math.cos(angle), fy + radius * math.sin(angle))
            transfer += (u <= 1) & ((u < plate_i) | (u > plate_o))
    return transfer / (n_angles * radii.size)


def phase_contrast_parts(
    radius_px: int,
    pixel_size_um: float,
    wavelength_um: float,
    numerical_aperture: float,
    condenser: str | Condenser,
    apodisation_sigma_um: float,
    ring_model: str = "airy",
    ring_width_scale: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Bright-field and ring parts of the phase-contrast kernel (eq. 7-8, 11-12).

    Returns
    -------
    k_bf
        Apodised Airy pattern ``jinc(omega)^2 G(r, sigma_1)``, normalised to sum 1:
        the diffraction-limited bright-field image of the sample.
    k_ring
        Zero-sum ring part. ``ring_model="airy"`` (the shape used before the
        ``annulus`` model existed): ``k_bf - P_ring`` with ``P_ring`` the intensity
        pattern of the obscured Airy of eq. 7, ``[rho_o^2 jinc(rho_o omega) -
        rho_i^2 jinc(rho_i omega)]^2 G(r, sigma_1)``, normalised by its own sum.
        ``ring_model="annulus"``: the inverse transform of the partially coherent
        weak-phase transfer function :func:`annulus_transfer_function`, apodised with
        ``G(r, sigma_1)`` (eq. 11-12) and made zero-sum; its transfer function is ~1
        at high frequencies, so its weight is the phase-plate gain itself. Either way
        ``k_ring`` is "detail minus surround": it moves light from the neighbourhood
        of dark objects into a halo and makes the interiors of large objects lighter
        (shade-off), and ring width, radius and apodisation change *where* the halo
        light goes, never *how much*: that is the ring part's weight alone.
        (SyMBac divides the amplitude difference by its own sum, which nearly
        cancels, so shape parameters there act as hidden contrast knobs.)
    """
    _check_positive(
        wavelength_um=wavelength_um,
        numerical_aperture=numerical_aperture,
        apodisation_sigma_um=apodisation_sigma_um,
    )
    if ring_model not in RING_MODELS:
        raise ValueError(f"unknown ring_model {ring_model!r}; choose one of {RING_MODELS}")
    cond = _condenser(condenser)
    r = radius_grid_um(radius_px, pixel_size_um)
    omega = 2 * math.pi * numerical_aperture * r / wavelength_um  # eq. 8 (vacuum lambda)
    g = np.exp(-(r**2) / (2 * apodisation_sigma_um**2))  # eq. 11
    k_bf = jinc(omega) ** 2 * g
    k_bf /= k_bf.sum()
    if ring_model == "airy":
        rho_o, rho_i = cond.outer_fraction, cond.inner_fraction
        ring = (rho_o**2 * jinc(rho_o * omega) - rho_i**2 * jinc(rho_i * omega)) ** 2 * g  # eq. 7
        k_ring = k_bf - ring / ring.sum()
    else:
        size = 2 * radius_px + 1
        transfer = annulus_transfer_function(
            size, pixel_size_um, wavelength_um, numerical_aperture, cond, ring_width_scale
        )
        k_ring = np.fft.fftshift(np.real(np.fft.ifft2(transfer))) * g
        k_ring -= g * (k_ring.sum() / g.sum())  # zero sum, the tails still apodised
    return k_bf.astype(np.float32), k_ring.astype(np.float32)


def phase_contrast_psf(
    radius_px: int,
    pixel_size_um: float,
    wavelength_um: float,
    numerical_aperture: float,
    condenser: str | Condenser,
    apodisation_sigma_um: float,
    ring_contrast: float,
    defocus_sigma_um: float = 0.0,
    offset: float = 0.0,
    min_apodisation_sigma_um: float | None = None,
    ring_model: str = "airy",
    ring_width_scale: float = 1.0,
) -> np.ndarray:
    """Phase-contrast kernel ``h = k_bf + gamma k_ring + offset term`` (eq. 7-14, 13.2).

    Parameters
    ----------
    radius_px, pixel_size_um
        Kernel radius and render pixel size.
    wavelength_um, numerical_aperture
        Vacuum wavelength and objective NA (eq. 8).
    condenser
        Name in :data:`~napari_symbac.settings.CONDENSERS` or a
        :class:`~napari_symbac.settings.Condenser` (the ``R``, ``W`` of eq. 7).
    apodisation_sigma_um
        ``sigma_1`` of eq. 11-12.
    ring_contrast
        ``gamma``, the weight of the ring part. The sign is chosen so that in the
        intensity domain of eq. 3 (cells darker than media, as in negative phase
        contrast) ``gamma > 0`` puts a *bright* halo around cells and trench walls.
    defocus_sigma_um
        ``sigma_2`` of eq. 14 (0 = in focus).
    offset
        Halo and shade-off of section 13.2: a weight ``o`` moved from the
        bright-field part to a *negative* uniform disk over the kernel's radius,
        ``h -= o (U - k_bf)`` with ``U`` the disk normalised to sum 1. That adds a
        constant (``-o / N`` per pixel) inside the radius while the kernel's sum
        stays 1: long-range halos around dark objects and lighter interiors of
        large ones (shade-off) for ``o > 0``.
    min_apodisation_sigma_um
        Lower bound of eq. 13; when given, a smaller ``apodisation_sigma_um`` is a
        ``ValueError``.
    ring_model, ring_width_scale
        Shape of the ring part, see :func:`phase_contrast_parts`.

    Returns
    -------
    numpy.ndarray
        float32 kernel whose sum is exactly 1, so flat regions keep their intensity.
    """
    _check_apodisation(apodisation_sigma_um, min_apodisation_sigma_um)
    if not math.isfinite(ring_contrast):
        raise ValueError(f"ring_contrast must be finite, got {ring_contrast!r}")
    k_bf, k_ring = _dc_and_ring(
        radius_px,
        pixel_size_um,
        wavelength_um,
        numerical_aperture,
        condenser,
        apodisation_sigma_um,
        offset,
        ring_model,
        ring_width_scale,
    )
    h = k_bf + ring_contrast * k_ring
    h = defocus(h, pixel_size_um, defocus_sigma_um).astype(np.float64)
    return (h / h.sum()).astype(np.float32)


def phase_contrast_kernels(
    radius_px: int,
    pixel_size_um: float,
    wavelength_um: float,
    numerical_aperture: float,
    condenser: str | Condenser,
    apodisation_sigma_um: float,
    defocus_sigma_um: float = 0.0,
    offset: float = 0.0,
    min_apodisation_sigma_um: float | None = None,
    ring_model: str = "annulus",
    ring_width_scale: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """The two parts of the phase kernel, kept apart: ``(h_dc, h_ring)``.

    ``h_dc`` is the bright-field part with the offset term (sum 1) and ``h_ring`` the
    zero-sum ring part (:func:`phase_contrast_parts`), both with the defocus of
    eq. 14. The forward model weights them with separate amplitudes when the phase
    signal of the sample is set apart from its bright-field (absorption) contrast
    (``RenderSettings.cell_phase_adu``): the image is ``sum_k I_k X_k conv h_dc -
    sum_k P_k X_k conv h_ring``, all amplitudes linear, so none of them is
    hidden in a ratio. ``phase_contrast_psf`` is ``h_dc + gamma h_ring``.
    """
    _check_apodisation(apodisation_sigma_um, min_apodisation_sigma_um)
    k_bf, k_ring = _dc_and_ring(
        radius_px,
        pixel_size_um,
        wavelength_um,
        numerical_aperture,
        condenser,
        apodisation_sigma_um,
        offset,
        ring_model,
        ring_width_scale,
    )
    dc = defocus(k_bf, pixel_size_um, defocus_sigma_um).astype(np.float64)
    ring = k_ring
    if defocus_sigma_um > 0:
        from scipy.ndimage import gaussian_filter

        ring = gaussian_filter(k_ring, defocus_sigma_um / pixel_size_um, mode="constant")
        ring -= ring.mean()
    return (dc / dc.sum()).astype(np.float32), ring.astype(np.float32)


def _check_apodisation(apodisation_sigma_um: float, min_apodisation_sigma_um: float | None) -> None:
    if min_apodisation_sigma_um is not None and apodisation_sigma_um < min_apodisation_sigma_um:
        raise ValueError(
            f"apodisation_sigma_um={apodisation_sigma_um} is below the diffraction bound of "
            f"eq. 13 ({min_apodisation_sigma_um:.3f} um): the phase PSF cannot be narrower "
            f"than the Airy disk"
        )


def _dc_and_ring(
    radius_px: int,
    pixel_size_um: float,
    wavelength_um: float,
    numerical_aperture: float,
    condenser: str | Condenser,
    apodisation_sigma_um: float,
    offset: float,
    ring_model: str,
    ring_width_scale: float,
) -> tuple[np.ndarray, np.ndarray]:
    """float64 ``(k_bf - offset (U - k_bf), k_ring)`` before defocus."""
    if not math.isfinite(offset):
        raise ValueError(f"offset must be finite, got {offset!r}")
    k_bf, k_ring = phase_contrast_parts(
        radius_px,
        pixel_size_um,
        wavelength_um,
        numerical_aperture,
        condenser,
        apodisation_sigma_um,
        ring_model,
        ring_width_scale,
    )
    dc = k_bf.astype(np.float64)
    if offset:
        disk = (radius_grid_um(radius_px, 1.0) <= radius_px).astype(np.float64)
        dc = dc - offset * (disk / disk.sum() - dc)
    return dc, k_ring.astype(np.float64)


def born_wolf_psf_3d(
    radius_px: int,
    pixel_size_um: float,
    z_um: np.ndarray,
    wavelength_um: float,
    numerical_aperture: float,
    refractive_index: float,
    n_quadrature: int = 96,
) -> np.ndarray:
    """3-D widefield fluorescence PSF from the scalar Debye (Born-Wolf) integral.

    ``h(r, z) = | int_0^1 J0(k NA r rho) exp(i k z sqrt(n^2 - NA^2 rho^2)) rho drho |^2``
    with ``k = 2 pi / lambda`` (vacuum). At ``z = 0`` it is the Airy pattern of
    eq. 6. It is the documented stand-in for the Gibson-Lanni model the supplement
    uses in section 5 (no coverslip/immersion mismatch terms): the sample is assumed
    index-matched, which is what the sum-over-z comparison of eq. 16 needs.

    Parameters
    ----------
    z_um
        Defocus of each plane (0 = focal plane).
    n_quadrature
        Gauss-Legendre nodes for the pupil integral.

    Returns
    -------
    numpy.ndarray
        ``(len(z_um), 2 radius + 1, 2 radius + 1)`` float32; every plane sums to 1
        (a widefield objective collects the same power from every plane).
    """
    _check_positive(
        wavelength_um=wavelength_um,
        numerical_aperture=numerical_aperture,
        refractive_index=refractive_index,
    )
    if numerical_aperture > refractive_index:
        raise ValueError("numerical_aperture cannot exceed refractive_index")
    z = np.atleast_1d(np.asarray(z_um, dtype=np.float64))
    if z.ndim != 1 or not np.all(np.isfinite(z)):
        raise ValueError("z_um must be a finite 1-D array of plane positions")
    r2d = radius_grid_um(radius_px, pixel_size_um)
    r1d = np.linspace(0.0, r2d.max() + pixel_size_um, 4 * radius_px * 2 + 8)
    nodes, weights = np.polynomial.legendre.leggauss(n_quadrature)
    rho = 0.5 * (nodes + 1)
    w = 0.5 * weights * rho
    k = 2 * math.pi / wavelength_um
    bessel = special.j0(k * numerical_aperture * np.outer(r1d, rho))  # (Nr, Nq)
    axial = np.sqrt(refractive_index**2 - (numerical_aperture * rho) ** 2)
    out = np.empty((z.size, *r2d.shape), np.float32)
    for i, zi in enumerate(z):
        amplitude = bessel @ (w * np.exp(1j * k * zi * axial))
        profile = np.abs(amplitude) ** 2
        plane = np.interp(r2d, r1d, profile)
        out[i] = plane / plane.sum()
    return out
