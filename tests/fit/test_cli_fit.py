"""`napari-symbac fit`: fitted settings reusable by render/export, cells, residual, figure."""

from __future__ import annotations

import json

import imageio.v3 as iio
import numpy as np
import pytest
import tifffile

from napari_symbac.cli import main
from napari_symbac.fit import scene_classes
from napari_symbac.settings import PipelineSettings, load_settings, save_settings


def test_fit_command_writes_settings_cells_residual_and_figure(tmp_path, truth, capsys):
    image = tmp_path / "real.tif"
    labels = tmp_path / "labels.tif"
    tifffile.imwrite(image, truth.image)
    tifffile.imwrite(labels, scene_classes(truth.scene).astype(np.uint8))
    microscope = save_settings(truth.microscope, tmp_path / "microscope.yaml")
    out = tmp_path / "fit"
    code = main(
        [
            "fit",
            str(image),
            "--labels",
            str(labels),
            "--microscope",
            str(microscope),
            "--out",
            str(out),
        ]
    )
    assert code == 0
    assert "pixel chi2" in capsys.readouterr().out
    settings = load_settings(out / "settings.yaml", PipelineSettings)
    assert settings.render.media_intensity == pytest.approx(2600, rel=0.03)
    assert settings.simulation.trench.width_um == pytest.approx(1.5, abs=0.03)
    table = json.loads((out / "cells.json").read_text())
    assert len(table["cells"]["ids"]) == 3
    assert {"pixel", "eq20"} <= set(table["terms"])
    residual = tifffile.imread(out / "residual.tif")
    assert residual.shape == truth.image.shape
    figure = iio.imread(out / "before_after.png")
    assert figure.shape[0] == truth.image.shape[0]
    assert figure.shape[2] == 3
    assert figure.shape[1] == 4 * truth.image.shape[1] + 9


def test_fit_command_rejects_an_rgb_image(tmp_path, truth, capsys):
    image = tmp_path / "rgb.tif"
    tifffile.imwrite(image, np.repeat(truth.image[..., None], 3, axis=-1))
    microscope = save_settings(truth.microscope, tmp_path / "microscope.yaml")
    code = main(["fit", str(image), "--microscope", str(microscope), "--out", str(tmp_path / "o")])
    assert code == 2
    assert "RGB" in capsys.readouterr().err
