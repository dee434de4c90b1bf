"""The catalogue of effects that diagnosis can name, model and fit (one module each)."""

from napari_symbac.diagnose.effects.background_texture import BackgroundTexture
from napari_symbac.diagnose.effects.base import Effect
from napari_symbac.diagnose.effects.camera_noise import CameraNoise
from napari_symbac.diagnose.effects.cell_curvature import CellCurvature
from napari_symbac.diagnose.effects.cell_intensity_variability import CellIntensityVariability
from napari_symbac.diagnose.effects.defocus_gradient import DefocusGradient
from napari_symbac.diagnose.effects.envelope_stain import EnvelopeStain
from napari_symbac.diagnose.effects.fixed_pattern_noise import FixedPatternNoise
from napari_symbac.diagnose.effects.halo import Halo
from napari_symbac.diagnose.effects.photobleaching import Photobleaching
from napari_symbac.diagnose.effects.saturation import Saturation
from napari_symbac.diagnose.effects.stage_drift import StageDrift
from napari_symbac.diagnose.effects.stray_light import StrayLight
from napari_symbac.diagnose.effects.uneven_illumination import UnevenIllumination

#: Every effect class, by name.
CATALOGUE: dict[str, type[Effect]] = {
    cls.name: cls
    for cls in (
        UnevenIllumination,
        Halo,
        DefocusGradient,
        CameraNoise,
        Photobleaching,
        StageDrift,
        CellIntensityVariability,
        BackgroundTexture,
        CellCurvature,
        EnvelopeStain,
        StrayLight,
        FixedPatternNoise,
        Saturation,
    )
}

__all__ = ["CATALOGUE", "Effect", *(cls.__name__ for cls in CATALOGUE.values())]
