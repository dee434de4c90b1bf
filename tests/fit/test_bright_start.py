"""Fluorescent cells each cut at half their own peak: dim cells beside bright ones."""

from __future__ import annotations

import numpy as np
import pytest
import tifffile
from scipy import ndimage

from napari_symbac.fit import fit_scene
from napari_symbac.fit.bright_start import bright_instances, touching_cells
from napari_symbac.fit.camera_estimate import censored_pixels
from napari_symbac.fit.start import start_scene
from napari_symbac.settings import Microscope, RenderSettings

PX = 0.08


def _axis_distance(shape, centre, length_px, width_px, angle):
    """Each pixel's distance (px) from a rod's axis segment."""
    rows, cols = np.indices(shape)
    dy, dx = rows - centre[0], cols - centre[1]
    along = dx * np.sin(angle) + dy * np.cos(angle)
    across = dx * np.cos(angle) - dy * np.sin(angle)
    half = (length_px - width_px) / 2
    return np.hypot(np.clip(np.abs(along) - half, 0, None), across)


def _rod(shape, centre, length_px, width_px, angle):
    return (_axis_distance(shape, centre, length_px, width_px, angle) <= width_px / 2).astype(float)


def test_a_dim_cell_beside_a_bright_one_is_found_and_a_spot_is_not():
    rng = np.random.default_rng(3)
    shape = (120, 120)
    bright = _rod(shape, (40, 40), 30, 12, 0.3)
    dim = _rod(shape, (40, 72), 28, 12, -0.2)  # 6 px from the bright one, 8x dimmer
    spot = np.zeros(shape)
    spot[95, 90] = 1.0
    clean = 2000 * bright + 250 * dim + 3000 * ndimage.gaussian_filter(spot, 1.2) * 9
    clean = ndimage.gaussian_filter(clean, 1.5) + 100
    image = clean + rng.normal(0, 20, shape)
    labels = bright_instances(image, PX)
    assert labels.max() == 2
    found = {int(labels[40, 40]), int(labels[40, 72])}
    assert found == {1, 2}
    assert labels[93:98, 88:93].max() == 0  # the spot is smaller than a cell
    # one Otsu threshold on the same image misses the dim cell
    from skimage.filters import threshold_otsu

    smooth = ndimage.gaussian_filter(image, 1.0)
    assert not (smooth > threshold_otsu(smooth))[40, 72]


@pytest.fixture(scope="module")
def field_2(real_data_dir):
    folder = real_data_dir / "colicoords" / "test_data" / "ds1"
    image = tifffile.imread(folder / "fluorescence" / "00002.tif").astype(float)
    mask = tifffile.imread(folder / "binary" / "00002_Probabilities_filtered.tif")
    return image, ndimage.label(mask > 0)[0]


def _on_mask(cells, labels):
    rows = np.clip((cells.y_um / PX).astype(int), 0, labels.shape[0] - 1)
    cols = np.clip((cells.x_um / PX).astype(int), 0, labels.shape[1] - 1)
    return labels[rows, cols]


def test_colicoords_field_2_start_has_all_seven_cells(field_2):
    """ds1 fluorescence field 2: its 7 masked cells span 180-1140 ADU; Otsu found 5."""
    image, labels = field_2
    assert labels.max() == 7
    microscope = Microscope(pixel_size_um=PX, modality="fluorescence")
    cells = start_scene(image, microscope, geometry="open", valid=~censored_pixels(image))[0]
    assert sorted(_on_mask(cells, labels).tolist()) == [1, 2, 3, 4, 5, 6, 7]


@pytest.mark.slow
def test_colicoords_field_2_fit_keeps_the_dim_cells(field_2):
    """A crop of field 2: two dim cells (280-300 ADU), a bright one (1140 ADU) and a
    bright spot the mask leaves out. The fit keeps the three cells and adds no spot."""
    image, labels = field_2
    crop = (slice(100, 240), slice(80, 320))
    microscope = Microscope(pixel_size_um=PX, modality="fluorescence")
    fit = fit_scene(image[crop], microscope, RenderSettings(), None, geometry="open")
    assert sorted(_on_mask(fit.cells, labels[crop]).tolist()) == [2, 3, 4], fit.moves


def _chord(shape, centre, length_px, width_px, angle):
    """A rod's thickness (px) along the line of sight: its fluorescence."""
    distance = _axis_distance(shape, centre, length_px, width_px, angle)
    return 2 * np.sqrt(np.clip((width_px / 2) ** 2 - distance**2, 0, None))


def test_touching_cells_cuts_a_blob_at_its_valleys_and_leaves_one_cell_whole():
    rng = np.random.default_rng(5)
    shape = (100, 100)
    # two daughters end to end (their poles touch at the septum) and a lone cell
    pair = _chord(shape, (30, 33), 26, 12, np.pi / 2) + _chord(shape, (30, 59), 26, 12, np.pi / 2)
    lone = _chord(shape, (75, 50), 30, 12, 0.4)
    clean = ndimage.gaussian_filter(150 * (pair + lone), 1.5) + 100
    image = clean + rng.normal(0, 15, shape)
    blobs = bright_instances(image, PX)
    assert blobs.max() == 2  # at the start's smoothing the pair is one blob
    parts = touching_cells(image, PX, blobs)
    assert parts.max() == 3  # the pair in two, the lone cell whole
    assert parts[30, 30] != parts[30, 62]
    assert min(parts[30, 30], parts[30, 62]) > 0
    assert np.unique(parts[blobs == blobs[30, 46]]).tolist() == sorted(
        {int(parts[30, 30]), int(parts[30, 62])}
    )
    assert np.unique(parts[blobs == blobs[75, 50]]).size == 1
    assert not parts[blobs == 0].any()


def test_a_crop_around_one_cell_is_refused_without_strokes_and_started_with_them(
    real_data_dir,
):
    """Found as a user: ColiCoords' single-cell crop (``01``, 57 x 61 px, one cell 40 x 17
    px) said "the start found no cells in the image (no region of 6 pixels or more)". The
    cell's glow is most of the crop, so the lower half of the crop is no background: the
    start now says how far its brightest region stands, and painted media strokes give
    it the background to measure the cell against."""
    from napari_symbac.fit.start import FaintStartError

    folder = real_data_dir / "colicoords" / "01"
    image = tifffile.imread(folder / "fluorescence.tif").astype(float)
    mask = tifffile.imread(folder / "binary.tif") > 0
    mic = Microscope(pixel_size_um=PX, modality="fluorescence", wavelength_um=0.53)
    with pytest.raises(FaintStartError, match="the brightest stands 21 times") as caught:
        start_scene(image, mic, geometry="open")
    assert str(caught.value).endswith("give the cells' instance masks or painted labels")
    strokes = np.zeros(image.shape, np.uint8)
    strokes[27:31, 15:45] = 1  # along the cell
    strokes[2:6, 2:20] = strokes[50:54, 40:58] = 2  # two corners of media
    cells, _, _, instances = start_scene(image, mic, geometry="open", labels=strokes)
    assert len(cells.x_um) == 1
    overlap = ((instances > 0) & mask).sum() / ((instances > 0) | mask).sum()
    assert overlap > 0.6
    # found as a user: the cell painted inside its mask and the media wherever 15 px off
    # it (the cell's glow reaches there) stood 30 background s.d. and was refused; a
    # region over painted cell is a cell from 5 s.d. (the cells painted nowhere: refused)
    painted = np.zeros(image.shape, np.uint8)
    painted[ndimage.binary_erosion(mask, iterations=3)] = 1
    painted[~ndimage.binary_dilation(mask, iterations=15)] = 2
    cells, _, _, instances = start_scene(image, mic, geometry="open", labels=painted)
    assert len(cells.x_um) == 1
    overlap = ((instances > 0) & mask).sum() / ((instances > 0) | mask).sum()
    assert overlap > 0.6
    media_only = np.where(painted == 2, 2, 0).astype(np.uint8)
    with pytest.raises(FaintStartError, match="no bright region stands 40 times"):
        start_scene(image, mic, geometry="open", labels=media_only)
