"""The supplement's section-1 benchmarks (Fig. S1.3 and S1.4), with tolerances."""

from __future__ import annotations

import numpy as np
import pytest

from napari_symbac.optics.validation import membrane_dye_width, otsu_width
from napari_symbac.settings import Microscope, RenderSettings

#: The optics of the supplement's Fig. S4.2 (lambda 0.75 um, NA 0.97, n = 1).
S42 = Microscope(wavelength_um=0.75, numerical_aperture=0.97, refractive_index=1.0)


@pytest.mark.parametrize("psf", ["born-wolf", "gaussian"])
def test_membrane_dye_underestimates_width(psf):
    """Fig. S1.3: close to 80 % error at 0.6 um, ~30 % at 1 um, falling with width."""
    widths = (0.6, 1.0, 1.4)
    errors = [membrane_dye_width(w, S42, psf).relative_error for w in widths]
    assert 0.7 <= errors[0] <= 0.95
    assert 0.25 <= errors[1] <= 0.40
    assert 0.12 <= errors[2] <= 0.25
    assert errors[0] > errors[1] > errors[2]
    # A sharper (100x oil) objective errs less, but still underestimates.
    sharp = membrane_dye_width(1.0, Microscope(), psf).relative_error
    assert 0.08 < sharp < errors[1]


def test_otsu_offset():
    """Fig. S1.4: Otsu underestimates phase-contrast widths by a bounded offset."""
    mic, rs = Microscope(), RenderSettings(ring_contrast=1.0)
    widths = np.array([0.6, 1.0, 1.4])
    offsets = widths - np.array([otsu_width(w, mic, rs, n_shifts=4) for w in widths])
    assert (offsets > 0.04).all()
    assert (offsets < 0.3).all()
    assert np.ptp(offsets) < 0.15
    relative = offsets / widths
    assert relative[0] >= relative[-1] - 0.02
