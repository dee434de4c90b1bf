"""Find where a rendered image and a real recording differ, and why (issue 11).

Model-free checks of the recording come first (:func:`check_image`). Then, from a
base fit (fitted scenes and forward-model settings), :func:`diagnose` pools the
standardised residual into discrepancy statistics, ranks the effects of the catalogue
(:data:`~napari_symbac.diagnose.effects.CATALOGUE`) by efficient score tests, fits the
best ones stepwise and accepts an effect only when it improves held-out pixels by more
than a parametric bootstrap says noise would.
"""

from napari_symbac.diagnose.checks import (
    ImageChecks,
    NoiseFit,
    check_image,
    estimate_noise_sd,
    fit_poisson_gaussian,
)
from napari_symbac.diagnose.config import DiagnoseConfig, load_microscope_file, parse_microscope
from napari_symbac.diagnose.effects import CATALOGUE
from napari_symbac.diagnose.model import BaseDesign, build_design
from napari_symbac.diagnose.run import Diagnosis, EffectResult, diagnose, diagnose_scenes
from napari_symbac.diagnose.stages import load_extra_stages, stage_for, updated_settings

__all__ = [
    "CATALOGUE",
    "BaseDesign",
    "DiagnoseConfig",
    "Diagnosis",
    "EffectResult",
    "ImageChecks",
    "NoiseFit",
    "build_design",
    "check_image",
    "diagnose",
    "diagnose_scenes",
    "estimate_noise_sd",
    "fit_poisson_gaussian",
    "load_extra_stages",
    "load_microscope_file",
    "parse_microscope",
    "stage_for",
    "updated_settings",
]
