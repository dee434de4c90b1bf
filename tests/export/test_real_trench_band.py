"""The PDMS beside an exported trench is as bright as the recording's.

A network trained on exported trenches sees the device band at the image's left and
right sides in every image: darker than the recording's (reported as 5th percentiles of
346-499 ADU against 740), it learns another background. The documented path, `fit` on
the SyMBac trench then `export --config FIT/settings.yaml`, did not reproduce it
(docs/rendering.md, "The PDMS band of an exported trench"); this guards that path.
"""

from __future__ import annotations

import numpy as np
import pytest
import tifffile

from napari_symbac.cli import main
from napari_symbac.export import export_of
from napari_symbac.export.dataset import PipelineSource
from napari_symbac.settings import Microscope, PipelineSettings, load_settings, save_settings

#: Columns at each side of the 46 px frame that hold PDMS only (the fitted walls lie at
#: 10.6 and 32.5 px; the exported trench, centred, at 12.0 and 34.0 px).
BAND_COLUMNS = 10
N_ITEMS = 4


def _band(image: np.ndarray) -> np.ndarray:
    return np.concatenate([image[:, :BAND_COLUMNS].ravel(), image[:, -BAND_COLUMNS:].ravel()])


def test_exported_device_band_is_as_bright_as_the_real_trench(tmp_path, real_data_dir):
    path = real_data_dir / "ecoli_100x_oil_exponential.tiff"
    real = tifffile.imread(path).astype(np.float64)
    microscope = save_settings(Microscope(pixel_size_um=0.065), tmp_path / "microscope.yaml")
    out = tmp_path / "fit"
    args = ["fit", str(path), "--microscope", str(microscope), "--out", str(out)]
    assert main([*args, "--max-iterations", "4"]) == 0
    settings = load_settings(out / "settings.yaml", PipelineSettings)
    source = PipelineSource(export_of(settings, n_items=N_ITEMS))
    images = [item.image.astype(np.float64) for i in range(N_ITEMS) for item in source.make_unit(i)]
    assert all(image.shape == real.shape for image in images)
    exported = np.concatenate([_band(image) for image in images])
    # Measured (2026-12-01, this path with the full fit, 40 items): the band's 5th
    # percentile 729 ADU on average (536-952 per item: the export draws the device
    # intensity 0.85-1.15x) against the recording's 699, its median 935 against 992.
    # 4 items average that spread to ~4 % s.d.; 20 % is the bias plus ~4 s.d. and
    # fails the reported 346-499 ADU (30-50 % below). With 4 iterations: 714 and 921;
    # with the device drawn at 0.6x: 252 and 457, which fail.
    for q, tolerance in ((5, 0.20), (50, 0.15)):
        assert np.percentile(exported, q) == pytest.approx(
            np.percentile(_band(real), q), rel=tolerance
        ), f"device band, percentile {q}"
