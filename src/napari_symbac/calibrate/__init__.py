"""Calibrate the pipeline to a real recording and compare real and synthetic images.

* :func:`calibrate`: fit a recording (scene fit, or the masks' scene with the partially
  coherent phase model for dense colonies) and turn the fit into matched
  :class:`~napari_symbac.settings.PipelineSettings`;
* :func:`measure_field`: model-free sizes, brightness, noise and layout from masks;
* :func:`measure_debris`: the unlabelled blobs outside the masks (debris);
* :func:`measure_packing`: how tightly the colonies are packed (cell fraction, seams),
  :func:`cell_curvatures_px`; :func:`choose_gravity`: the compaction that matches it;
* :func:`compare_images`: real against synthetic (class medians, noise, radially
  averaged power spectrum), :func:`compare_with_dataset` against the first
  :data:`COMPARED_ITEMS` items of a matched dataset, and :func:`montage`, the
  side-by-side picture.
"""

from napari_symbac.calibrate.compaction import CompactionTrial, choose_gravity
from napari_symbac.calibrate.compare import Comparison, compare_images, montage, radial_power
from napari_symbac.calibrate.core import (
    COMPARED_ITEMS,
    Calibration,
    best_crop,
    calibrate,
    compare_with_dataset,
    export_settings,
    items_words,
    settings_from_fit,
)
from napari_symbac.calibrate.measure import (
    ColonyPacking,
    DebrisMeasurements,
    FieldMeasurements,
    cell_curvatures_px,
    instance_masks,
    measure_debris,
    measure_field,
    measure_packing,
)

__all__ = [
    "COMPARED_ITEMS",
    "Calibration",
    "ColonyPacking",
    "CompactionTrial",
    "Comparison",
    "DebrisMeasurements",
    "FieldMeasurements",
    "best_crop",
    "calibrate",
    "cell_curvatures_px",
    "choose_gravity",
    "compare_images",
    "compare_with_dataset",
    "export_settings",
    "instance_masks",
    "items_words",
    "measure_debris",
    "measure_field",
    "measure_packing",
    "montage",
    "radial_power",
    "settings_from_fit",
]
