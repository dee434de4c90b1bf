"""Eq. 2 intensities from rough labels, and the input checks in front of every fit."""

from __future__ import annotations

import numpy as np
import pytest
import tifffile

from napari_symbac.fit import CLASS_VALUES, as_image_stack, class_statistics


def _three_region_image(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    truth = {"device": 900.0, "media": 2600.0, "cell": 1400.0}
    image = np.full((64, 48), truth["device"])
    image[:, 12:36] = truth["media"]
    image[10:30, 16:32] = truth["cell"]
    image = image + rng.normal(0, 30, image.shape)
    labels = np.zeros(image.shape, np.uint8)
    labels[2:60:5, 2:8] = CLASS_VALUES["device"]  # sparse, rough strokes
    labels[40:60, 18:30:3] = CLASS_VALUES["media"]
    labels[15:25, 20:28] = CLASS_VALUES["cell"]
    return image, labels


def test_class_means_and_variances_from_sparse_labels():
    image, labels = _three_region_image(np.random.default_rng(0))
    stats = class_statistics(image, labels)
    assert stats["device"].mean == pytest.approx(900, abs=10)
    assert stats["media"].mean == pytest.approx(2600, abs=10)
    assert stats["cell"].mean == pytest.approx(1400, abs=10)
    for name in ("device", "media", "cell"):
        assert stats[name].variance == pytest.approx(30**2, rel=0.35)
        assert stats[name].n_pixels == np.count_nonzero(labels == CLASS_VALUES[name])


def test_time_series_with_2d_labels_and_integer_dtype():
    image, labels = _three_region_image(np.random.default_rng(1))
    stack = np.stack([image, image + 100]).astype(np.uint16)
    stats = class_statistics(stack, labels)
    assert stats["cell"].mean == pytest.approx(1450, abs=10)
    assert stats["cell"].n_pixels == 2 * np.count_nonzero(labels == CLASS_VALUES["cell"])


def test_agar_pad_without_device_class():
    image, labels = _three_region_image(np.random.default_rng(2))
    labels[labels == CLASS_VALUES["device"]] = 0
    stats = class_statistics(image, labels, required=("cell", "media"))
    assert set(stats) == {"cell", "media"}


@pytest.mark.parametrize(
    ("image", "match"),
    [
        (np.zeros((32, 32, 3)), "looks like an RGB"),
        (np.zeros((2, 3, 32, 32)), "must be 2D"),
        (np.full((32, 32), np.nan), "NaN or infinite"),
        (np.ones((32, 32)), "is constant"),
        (np.zeros((32, 32), bool), "dtype bool"),
        (np.ones((4, 4)), "too small"),
    ],
)
def test_bad_images_are_named(image, match):
    with pytest.raises(ValueError, match=match):
        as_image_stack(image)


def test_bad_labels_are_named():
    image, labels = _three_region_image(np.random.default_rng(3))
    with pytest.raises(ValueError, match="do not match the image"):
        class_statistics(image, labels[:10])
    with pytest.raises(ValueError, match=r"missing the class\(es\) device"):
        class_statistics(image, np.where(labels == CLASS_VALUES["device"], 0, labels))
    with pytest.raises(ValueError, match=r"unknown class value\(s\) \[7\]"):
        class_statistics(image, np.where(labels == 1, 7, labels))
    with pytest.raises(ValueError, match="integer class values"):
        class_statistics(image, labels + 0.5)


def test_real_trench_classes_are_ordered(real_data_dir):
    """On the real 100x trench: PDMS darkest, then cells, the trench's bright walls highest."""
    image = tifffile.imread(real_data_dir / "ecoli_100x_oil_exponential.tiff")
    labels = np.zeros(image.shape, np.uint8)
    labels[40:240, 0:4] = CLASS_VALUES["device"]  # PDMS left of the trench
    labels[40:240, 20:24] = CLASS_VALUES["cell"]  # cells fill the trench centre
    labels[40:240, 12:14] = CLASS_VALUES["media"]  # bright band along the trench wall
    stats = class_statistics(image, labels)
    assert stats["device"].mean < stats["cell"].mean < stats["media"].mean


@pytest.mark.parametrize("name", ["Sample000252", "Sample000193"])
def test_rough_class_means_of_a_phase_colony_match_its_masks(real_data_dir, name):
    """A phase field nobody painted: its background is the recording's away from the
    cells (a single threshold took the halo for it: 201 against 140 on Sample000252),
    and its cells darker than that."""
    from scipy.ndimage import binary_dilation

    from napari_symbac.fit.intensities import rough_class_means
    from napari_symbac.io import read_image

    folder = real_data_dir / "omnipose"
    image = np.asarray(read_image(folder / f"{name}.png").data, np.float64)
    masks = tifffile.imread(folder / f"{name}_cp_masks.tif")
    far = ~binary_dilation(masks > 0, iterations=8)
    rough = rough_class_means(image, "phase", field=True)
    assert abs(rough["media"] - image[far].mean()) < 0.05 * image[far].mean()
    assert rough["cell"] < 0.8 * rough["media"]


def test_rough_class_means_of_a_fluorescence_field_and_a_trench(real_data_dir):
    from napari_symbac.fit.intensities import rough_class_means

    field = tifffile.imread(
        real_data_dir / "colicoords" / "test_data" / "ds1" / "fluorescence" / "00001.tif"
    ).astype(np.float64)
    mask = tifffile.imread(
        real_data_dir / "colicoords/test_data/ds1/binary/00001_Probabilities_filtered.tif"
    ) > 0
    rough = rough_class_means(field, "fluorescence", field=True)
    assert rough["cell"] > 5 * rough["media"]  # bright cells on a dark background
    assert abs(rough["media"] - np.median(field[~mask])) < 0.2 * np.median(field[~mask])
    trench = tifffile.imread(real_data_dir / "ecoli_100x_oil_exponential.tiff")
    assert trench.ndim == 2
    rough = rough_class_means(trench.astype(np.float64), "phase", field=False)
    assert rough["cell"] < 0.5 * rough["media"]  # dark cells and PDMS, bright media


def test_rough_class_means_of_bright_field_and_flat_images():
    from napari_symbac.fit.intensities import rough_class_means

    image = np.full((32, 32), 500.0)
    assert rough_class_means(image, "phase", field=True) == {"media": 500.0}
    image[8:12, 8:20] = 480.0
    assert rough_class_means(image, "brightfield", field=True) == {"media": 500.0}
    with pytest.raises(ValueError, match="no finite pixel"):
        rough_class_means(np.full((8, 8), np.nan), "phase", field=True)
