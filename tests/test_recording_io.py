"""Reading real recordings and their pixel size."""

from __future__ import annotations

import numpy as np
import pytest
import tifffile

from napari_symbac.io import napari_get_reader, read_recording


def test_imagej_pixel_size(tmp_path):
    path = tmp_path / "stack.tif"
    data = np.arange(3 * 16 * 16, dtype=np.uint16).reshape(3, 16, 16)
    tifffile.imwrite(
        path, data, imagej=True, resolution=(1 / 0.08, 1 / 0.08), metadata={"unit": "um"}
    )
    recording = read_recording(path)
    assert recording.pixel_size_um == pytest.approx(0.08, rel=1e-4)
    assert recording.name == "stack"
    np.testing.assert_array_equal(recording.data, data)


def test_ome_pixel_size_in_nm(tmp_path):
    path = tmp_path / "field.ome.tif"
    tifffile.imwrite(
        path,
        np.zeros((16, 16), np.uint16),
        metadata={"PhysicalSizeX": 65.0, "PhysicalSizeXUnit": "nm"},
    )
    assert read_recording(path).pixel_size_um == pytest.approx(0.065)


def test_plain_tiff_has_no_pixel_size(tmp_path):
    path = tmp_path / "plain.tiff"
    tifffile.imwrite(path, np.zeros((16, 16), np.float32))
    assert read_recording(path).pixel_size_um is None


def test_reader_contract(tmp_path):
    path = tmp_path / "a.tif"
    tifffile.imwrite(
        path, np.ones((8, 8), np.uint16), imagej=True, resolution=(10, 10), metadata={"unit": "um"}
    )
    reader = napari_get_reader(str(path))
    ((_data, meta, kind),) = reader(str(path))
    assert kind == "image"
    assert meta["scale"] == pytest.approx((0.1, 0.1))
    assert napari_get_reader(str(tmp_path / "a.png")) is None


def test_bad_files_are_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        read_recording(tmp_path / "nope.tif")
    broken = tmp_path / "broken.tif"
    broken.write_bytes(b"not a tiff at all")
    with pytest.raises(ValueError, match="not a readable TIFF"):
        read_recording(broken)
    text = tmp_path / "notes.txt"
    text.write_text("x")
    with pytest.raises(ValueError, match="is not a TIFF file"):
        read_recording(text)


@pytest.mark.parametrize(
    ("method", "modality"), [("Phase", "phase"), ("Fluorescence", "fluorescence")]
)
def test_ome_contrast_method_gives_modality(tmp_path, method, modality):
    path = tmp_path / "x.ome.tif"
    tifffile.imwrite(
        path,
        np.zeros((16, 16), np.uint16),
        metadata={"axes": "YX", "Channel": {"Name": "c", "ContrastMethod": method}},
    )
    assert read_recording(path).modality == modality
    assert read_recording(tmp_path / "x.ome.tif").pixel_size_um is None
