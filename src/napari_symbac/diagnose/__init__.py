"""Find where a rendered image and a real recording differ, and why.

Model-free checks of the recording come first: :func:`check_image`.
"""

from napari_symbac.diagnose.checks import (
    ImageChecks,
    NoiseFit,
    check_image,
    estimate_noise_sd,
    fit_poisson_gaussian,
)

__all__ = ["ImageChecks", "NoiseFit", "check_image", "estimate_noise_sd", "fit_poisson_gaussian"]
