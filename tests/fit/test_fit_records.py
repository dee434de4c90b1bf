"""What ``napari-symbac fit`` writes of its cells: series.json's lineage and each cell's
mask label in cells.json."""

from __future__ import annotations

import numpy as np


def test_series_json_leaves_the_drift_empty_between_frames_that_share_no_cell():
    """Found as a user: ColiCoords ds3's unrelated fields, no cell linked across them,
    gave ``drift_um`` [0, 0] for every pair, read as a measured still stage."""
    from napari_symbac._cli_fit import _lineage_record
    from napari_symbac.fit.lineage import Lineage

    lineage = Lineage(
        track_ids=(np.array([1]), np.array([1]), np.array([2])),
        tracks=np.array([[1, 0, 1, 0], [2, 2, 2, 0]]),
        growth_per_frame=1.0,
        drift_um=np.array([[0.3, -0.1], [0.0, 0.0]]),
        link_costs=(np.array([0.5]), np.array([np.nan])),
    )
    record = _lineage_record(lineage, [4, 5, 6])
    assert record["drift_um"] == [[0.3, -0.1], None]


def test_each_fitted_cell_names_the_mask_it_lies_on():
    """A 0/1 mask's regions are numbered as scipy.ndimage.label numbers them; a cell
    split in two names its mask twice; a cell on no mask (added by the fit) names none."""
    from types import SimpleNamespace

    from napari_symbac.fit.report import mask_labels

    masks = np.zeros((10, 20), np.uint8)
    masks[1:4, 1:9] = 1  # region 1
    masks[6:9, 1:9] = 1  # region 2
    fitted = np.zeros((10, 20), np.int64)
    fitted[1:4, 1:5], fitted[1:4, 5:9] = 7, 8  # region 1, split in two
    fitted[6:9, 2:10] = 3  # region 2, one pixel column beyond it
    fitted[2:5, 12:18] = 4  # on no mask
    result = SimpleNamespace(
        scene=SimpleNamespace(camera_labels=lambda: fitted),
        cells_table=lambda: {"ids": [7, 8, 3, 4]},
    )
    assert mask_labels(result, masks) == [1, 1, 2, None]
    assert mask_labels(result, masks * 9) == [1, 1, 2, None]  # 0/9: the same regions
    instances = np.where(masks > 0, np.where(np.arange(10)[:, None] < 5, 12, 5), 0)
    assert mask_labels(result, instances) == [12, 12, 5, None]  # instance ids as given
