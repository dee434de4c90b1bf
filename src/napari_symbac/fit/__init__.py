"""Fit the forward model to a real recording.

* :func:`class_statistics`: mean and variance of cells, media and device from rough
  painted labels (eq. 2 of the SyMBac supplement);
* :func:`objective_terms`: eq. 20 and better comparisons of a synthetic and a real
  image (class statistics, power spectrum, histogram, edge profile, pixels);
* :func:`fit_parameters`: intensities, apodisation, defocus, PSF offset (ring
  contrast, noise) fitted to a real image;
* :func:`fit_scene`: analysis by synthesis, cells and trench placed, sized and counted
  so the rendered image overlays the real one pixel for pixel, with the camera,
  censoring and standard errors (stages in ``start``, ``noise``, ``engine``, ``lm``,
  ``overlap``, ``moves``);
* :func:`fit_colony`: a dense phase-contrast colony from its instance masks, the
  partially coherent phase model fitted to them (``colony``); :func:`fit_colony_series`
  a time-lapse of one, the optics fitted on all frames jointly and the masks' cells tracked
  (``colony_series``);
* :func:`fit_series`: a ``(T, Y, X)`` series with the optics (and camera) shared by
  the frames and the cells per frame, linked into tracks and a lineage
  (:func:`link_cells`, :class:`LinkSettings`, :class:`Lineage`).
"""

from napari_symbac.fit.colony import ColonyFit, fit_colony
from napari_symbac.fit.colony_series import ColonySeriesFit, fit_colony_series
from napari_symbac.fit.fitted_settings import fitted_pipeline
from napari_symbac.fit.inputs import (
    CLASS_NAMES,
    CLASS_VALUES,
    as_image_stack,
    as_label_stack,
    as_single_image,
)
from napari_symbac.fit.intensities import ClassStatistics, class_statistics
from napari_symbac.fit.lineage import Lineage, LinkSettings, link_cells
from napari_symbac.fit.objectives import DEFAULT_TERMS, TERM_NAMES, objective_terms
from napari_symbac.fit.parameters import (
    DEFAULT_FIT,
    DEFAULT_FIT_STATISTICS,
    FitCancelled,
    FitResult,
    fit_parameters,
    parameter_bounds,
    scene_classes,
)
from napari_symbac.fit.scene_fit import (
    SceneFit,
    TrenchPlacement,
    fit_scene,
    otsu_cells,
)
from napari_symbac.fit.series import SeriesFit, fit_series

__all__ = [
    "CLASS_NAMES",
    "CLASS_VALUES",
    "DEFAULT_FIT",
    "DEFAULT_FIT_STATISTICS",
    "DEFAULT_TERMS",
    "TERM_NAMES",
    "ClassStatistics",
    "ColonyFit",
    "ColonySeriesFit",
    "FitCancelled",
    "FitResult",
    "Lineage",
    "LinkSettings",
    "SceneFit",
    "SeriesFit",
    "TrenchPlacement",
    "as_image_stack",
    "as_label_stack",
    "as_single_image",
    "class_statistics",
    "fit_colony",
    "fit_colony_series",
    "fit_parameters",
    "fit_scene",
    "fit_series",
    "fitted_pipeline",
    "link_cells",
    "objective_terms",
    "otsu_cells",
    "parameter_bounds",
    "scene_classes",
]
