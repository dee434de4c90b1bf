"""napari's *File -> Open* with this plugin's reader: which TIFFs become labels layers.

docs/gui.md promises that a TIFF of instance masks opened so becomes a labels layer (the
*cell masks* of Auto-fit). Found as a user: the ColiCoords masks of the real data set
(``binary.tif``, ``binary/00001_Probabilities_filtered.tif``) opened as grey images, so
Auto-fit's *cell masks* could not take them and the *Real image* dock offered them as
recordings; only ``*_masks.tif`` and folders named labels/masks were recognised.
"""

from __future__ import annotations

import numpy as np
import pytest
import tifffile

from napari_symbac.io import napari_get_reader


def _kind(path) -> str:
    ((_data, _meta, kind),) = napari_get_reader(str(path))(str(path))
    return kind


@pytest.mark.parametrize(
    "name",
    [
        "binary.tif",
        "binary/00001_Probabilities_filtered.tif",
        "cell_mask.tif",
        "field 3_labels.tiff",
        "field-3-seg.tif",
        "masks/field.tif",
        "mask/field.tif",
        "segmentation/field.tif",
        "Sample000033_cp_masks.tif",
    ],
)
def test_masks_named_as_masks_open_as_labels(tmp_path, name):
    path = tmp_path / name
    path.parent.mkdir(parents=True, exist_ok=True)
    masks = np.zeros((16, 12), np.uint16)
    masks[2:6, 3:8], masks[9:14, 2:9] = 1, 2
    tifffile.imwrite(path, masks)
    assert _kind(path) == "labels"


@pytest.mark.parametrize(
    "name", ["field.tif", "binary_search.tif", "masking_test.tif", "labelled/field.tif"]
)
def test_recordings_open_as_images(tmp_path, name):
    path = tmp_path / name
    path.parent.mkdir(parents=True, exist_ok=True)
    tifffile.imwrite(path, np.arange(16 * 12, dtype=np.uint16).reshape(16, 12))
    assert _kind(path) == "image"


def test_a_float_image_named_as_masks_stays_an_image(tmp_path):
    path = tmp_path / "cell_mask.tif"
    tifffile.imwrite(path, np.linspace(0, 1, 16 * 12, dtype=np.float32).reshape(16, 12))
    assert _kind(path) == "image"


def test_the_colicoords_masks_open_as_labels(real_data_dir):
    coli = real_data_dir / "colicoords"
    masks = (
        coli / "01" / "binary.tif",
        coli / "test_data" / "ds3" / "binary.tif",
        coli / "test_data" / "ds1" / "binary" / "00001_Probabilities_filtered.tif",
    )
    for path in masks:
        assert _kind(path) == "labels", path
    for path in (coli / "01" / "fluorescence.tif", coli / "test_data" / "ds3" / "flu.tif"):
        assert _kind(path) == "image", path
