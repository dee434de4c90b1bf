"""Masks and images agree on what is visible: the contrast-to-noise rule and its actions."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import tifffile
from skimage.draw import ellipse

from napari_symbac.export import ExportSettings, Visibility, contrast_to_noise, export_dataset
from napari_symbac.export.visibility import faint_cells, pixel_noise
from napari_symbac.settings import PipelineSettings, SimulationSettings

NOISE = 40.0


def _field(rng, cells: dict[int, float], shape=(80, 60)):
    """Background 2400 with cells at the given intensities, Gaussian noise of sd 40."""
    labels = np.zeros(shape, np.uint32)
    truth = np.full(shape, 2400.0)
    for k, (cell, level) in enumerate(cells.items()):
        rr, cc = ellipse(12 + 18 * k, 20, 7, 5, shape=shape)
        labels[rr, cc] = cell
        truth[rr, cc] = level
    return truth + rng.normal(0, NOISE, shape), labels


def test_pixel_noise_is_the_camera_noise():
    rng = np.random.default_rng(1)
    image, labels = _field(rng, {1: 800.0})
    # a slow illumination gradient does not count as noise
    image += np.linspace(0, 400, image.shape[1])[None, :]
    assert pixel_noise(image, labels == 0) == pytest.approx(NOISE, rel=0.1)


def test_cell_as_bright_as_the_medium_is_faint():
    rng = np.random.default_rng(2)
    image, labels = _field(rng, {1: 800.0, 2: 2410.0, 3: 2300.0})
    cnr = contrast_to_noise(image, labels)
    assert cnr[1] == pytest.approx(1600 / NOISE, rel=0.1)
    assert cnr[2] < 1  # 10 ADU against a noise of 40: invisible
    assert cnr[3] == pytest.approx(100 / NOISE, rel=0.3)
    assert faint_cells(cnr, 1.0) == [2]
    assert faint_cells(cnr, 3.0) == [2, 3]


def test_contrast_is_measured_against_the_medium_not_the_wall():
    """A long cell in a trench: most of its ring is dark wall, yet it matches the medium."""
    rng = np.random.default_rng(3)
    shape = (80, 40)
    medium = np.zeros(shape, bool)
    medium[:, 16:25] = True  # the trench, as wide as the cell
    labels = np.zeros(shape, np.uint32)
    rr, cc = ellipse(40, 20, 28, 5, shape=shape)
    labels[rr, cc] = 1
    truth = np.where(medium, 2400.0, 300.0)  # the cell is as bright as the medium
    image = truth + rng.normal(0, NOISE, shape)
    without = contrast_to_noise(image, labels)[1]
    with_medium = contrast_to_noise(image, labels, medium=medium)[1]
    assert with_medium < 1 < without


def test_settings_validation():
    with pytest.raises(ValueError, match="min_contrast_to_noise must be a number >= 0"):
        Visibility(min_contrast_to_noise=-1)
    with pytest.raises(ValueError, match="'flag', 'drop' or 'keep'"):
        Visibility(action="hide")
    with pytest.raises(ValueError, match="use 'flag' for kind='timeseries'"):
        ExportSettings(kind="timeseries", visibility=Visibility(action="drop"))


def _faint_settings(action: str) -> ExportSettings:
    pipeline = PipelineSettings(simulation=SimulationSettings(n_frames=40))
    pipeline = dataclasses.replace(
        pipeline, render=dataclasses.replace(pipeline.render, cell_brightness_cv=0.8)
    )
    return ExportSettings(
        n_items=6,
        formats=["tiff"],
        first_frame=30,
        val_fraction=0,
        pipeline=pipeline,
        visibility=Visibility(min_contrast_to_noise=1.0, action=action),  # type: ignore[arg-type]
    )


@pytest.fixture(scope="module")
def flagged_and_dropped(tmp_path_factory):
    root = tmp_path_factory.mktemp("visibility")
    for action in ("flag", "drop"):
        export_dataset(_faint_settings(action), root / action, workers=1)
    return root


def _entries(folder):
    return json.loads((folder / "manifest.json").read_text())["items"]


def test_flag_lists_faint_cells_and_keeps_masks(flagged_and_dropped):
    entries = _entries(flagged_and_dropped / "flag")
    faint = [c for e in entries for c in e["faint_cells"]]
    assert faint, "cell_brightness_cv=0.8 makes some cells as bright as the medium"
    for entry in entries:
        cnr = entry["contrast_to_noise"]
        assert set(cnr) == {str(row[0]) for row in entry["objects"]}
        assert entry["faint_cells"] == sorted(int(c) for c, v in cnr.items() if v < 1.0)
        labels = tifffile.imread(flagged_and_dropped / "flag" / entry["files"]["tiff"][1])
        assert set(entry["faint_cells"]) <= set(np.unique(labels).tolist())


def test_drop_removes_exactly_the_faint_cells(flagged_and_dropped):
    flag, drop = flagged_and_dropped / "flag", flagged_and_dropped / "drop"
    for flagged, dropped in zip(_entries(flag), _entries(drop)):
        image_f = tifffile.imread(flag / flagged["files"]["tiff"][0])
        image_d = tifffile.imread(drop / dropped["files"]["tiff"][0])
        np.testing.assert_array_equal(image_f, image_d)  # the image is the same
        labels_f = tifffile.imread(flag / flagged["files"]["tiff"][1])
        labels_d = tifffile.imread(drop / dropped["files"]["tiff"][1])
        expected = np.where(np.isin(labels_f, flagged["faint_cells"]), 0, labels_f)
        np.testing.assert_array_equal(labels_d, expected)
        semantic_d = tifffile.imread(drop / dropped["files"]["tiff"][2])
        assert not semantic_d[np.isin(labels_f, flagged["faint_cells"])].any()
        # every cell left in the mask is one the image shows
        kept = [str(c) for c in np.unique(labels_d) if c]
        assert all(flagged["contrast_to_noise"][c] >= 1.0 for c in kept)
        assert dropped["faint_cells"] == flagged["faint_cells"]


def test_keep_measures_nothing(tmp_path):
    settings = dataclasses.replace(_faint_settings("flag"), n_items=1)
    settings = dataclasses.replace(settings, visibility=Visibility(action="keep"))
    export_dataset(settings, tmp_path, workers=1)
    [entry] = _entries(tmp_path)
    assert "faint_cells" not in entry


@pytest.mark.parametrize("sd", [0.3, 0.45, 0.8, 1.5])
def test_noise_of_a_grey_level_or_two_is_measured(sd):
    """An 8-bit recording's camera: noise below a grey level, most neighbours equal.
    The MAD alone gave 0 at 0.45 ADU, so every cell's CNR was infinite and none was faint."""
    rng = np.random.default_rng(4)
    labels = np.zeros((120, 120), np.uint32)
    truth = np.full(labels.shape, 120.0)
    for k, level in enumerate((60.0, 120.2)):  # a dark cell, and one as bright as the medium
        rr, cc = ellipse(30 + 60 * k, 60, 12, 6, shape=labels.shape)
        labels[rr, cc] = k + 1
        truth[rr, cc] = level
    truth += np.linspace(0, 6, 120)[None, :]  # a slow shading is not noise
    image = np.rint(truth + rng.normal(0, sd, truth.shape))
    noise = pixel_noise(image, labels == 0)
    assert noise == pytest.approx(np.sqrt(sd**2 + 1 / 12), rel=0.15)
    cnr = contrast_to_noise(image, labels)
    assert np.isfinite(cnr[1])
    assert cnr[1] > 20
    assert faint_cells(cnr, 1.0) == [2]
