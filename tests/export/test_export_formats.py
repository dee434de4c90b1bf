"""Every format round-trips through the readers its training code uses."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
import tifffile
from _export_synthetic import LINEAGE_PARENTS, PRESENT, TIMESERIES_FRAMES, SyntheticSource
from scipy import ndimage
from skimage.draw import polygon as draw_polygon

from napari_symbac.export import (
    FORMATS,
    ExportItem,
    instance_dtype,
    semantic_from_labels,
    write_items,
)
from napari_symbac.export.formats import rle_decode, rle_encode


@pytest.fixture(scope="module")
def frame_items() -> list[ExportItem]:
    source = SyntheticSource(6)
    return [item for unit in range(6) for item in source.make_unit(unit)]


@pytest.fixture(scope="module")
def series_items_() -> list[ExportItem]:
    source = SyntheticSource(2, kind="timeseries", val_every=2)
    return [item for unit in range(2) for item in source.make_unit(unit)]


@pytest.fixture(scope="module")
def frames_export(tmp_path_factory, frame_items) -> Path:
    out = tmp_path_factory.mktemp("frames")
    formats = ["tiff", "png", "delta", "omnipose", "stardist", "coco", "ome-zarr"]
    report = write_items(frame_items, out, formats)
    assert report.complete
    return out


@pytest.fixture(scope="module")
def series_export(tmp_path_factory, series_items_) -> Path:
    out = tmp_path_factory.mktemp("series")
    report = write_items(series_items_, out, ["tiff", "ctc", "trackmate", "ome-zarr"])
    assert report.complete
    return out


def _separated(semantic: np.ndarray, labels: np.ndarray) -> bool:
    """Each 4-connected component of the semantic mask lies in exactly one cell."""
    components, n = ndimage.label(semantic > 0)
    return all(np.unique(labels[components == k]).size == 1 for k in range(1, n + 1))


def test_semantic_from_labels_separates_touching_cells():
    labels = np.zeros((10, 12), np.uint16)
    labels[2:8, 1:6] = 1
    labels[2:8, 6:11] = 2  # touches cell 1 along a column
    semantic = semantic_from_labels(labels)
    assert semantic.dtype == np.uint8
    assert set(np.unique(semantic)) == {0, 1}
    assert _separated(semantic, labels)
    assert ndimage.label(semantic)[1] == 2
    # only the boundary column of the higher label is cleared
    assert semantic.sum() == (labels > 0).sum() - 6


def test_instance_dtype_never_wraps():
    assert instance_dtype(65535) == np.uint16
    assert instance_dtype(65536) == np.uint32
    assert instance_dtype(2**32) == np.uint64


def test_tiff_and_png_round_trip(frames_export, frame_items):
    for item in frame_items:
        for fmt, ext, read in (("tiff", "tif", tifffile.imread), ("png", "png", iio.imread)):
            base = frames_export / fmt / item.split
            image = read(base / "images" / f"{item.name}.{ext}")
            labels = read(base / "labels" / f"{item.name}.{ext}")
            semantic = read(base / "semantic" / f"{item.name}.{ext}")
            assert image.dtype == np.uint16
            assert image.shape == item.image.shape
            np.testing.assert_array_equal(image, item.image)
            assert labels.dtype == np.uint16
            np.testing.assert_array_equal(labels, item.labels)
            assert semantic.dtype == np.uint8
            np.testing.assert_array_equal(semantic, item.semantic)
            assert _separated(semantic, labels)


def test_splits_follow_items(frames_export, frame_items):
    val = {item.name for item in frame_items if item.split == "val"}
    assert val  # the fixture has validation items
    on_disk = {p.stem for p in (frames_export / "stardist" / "val" / "images").glob("*.tif")}
    assert on_disk == val


def test_delta_layout(frames_export, frame_items):
    for item in frame_items:
        img = iio.imread(frames_export / "delta" / item.split / "img" / f"{item.name}.png")
        seg = iio.imread(frames_export / "delta" / item.split / "seg" / f"{item.name}.png")
        assert img.dtype == np.uint16
        np.testing.assert_array_equal(img, item.image)
        assert seg.dtype == np.uint8
        assert set(np.unique(seg)) <= {0, 255}
        # cells are separated by zeros: one connected component per cell
        n_cells = np.unique(item.labels).size - 1
        assert ndimage.label(seg > 0)[1] == n_cells
        assert _separated(seg, item.labels)


def test_touching_cells_in_fixture(frame_items):
    # the separation tests above are only meaningful if some cells touch
    touching = False
    for item in frame_items:
        grown = ndimage.grey_dilation(item.labels, size=(3, 1))
        touching |= bool(np.any((grown != item.labels) & (item.labels > 0) & (grown > 0)))
    assert touching


def test_omnipose_masks_next_to_images(frames_export, frame_items):
    for item in frame_items:
        folder = frames_export / "omnipose" / item.split
        image = tifffile.imread(folder / f"{item.name}.tif")
        masks = tifffile.imread(folder / f"{item.name}_masks.tif")
        np.testing.assert_array_equal(image, item.image)
        assert masks.dtype == np.uint16
        np.testing.assert_array_equal(masks, item.labels)
    # cellpose pairs every image with IMAGE_masks.tif: no image lacks its mask
    for folder in (frames_export / "omnipose").iterdir():
        images = {p.stem for p in folder.glob("*.tif") if not p.stem.endswith("_masks")}
        masks = {p.stem[: -len("_masks")] for p in folder.glob("*_masks.tif")}
        assert images == masks


def test_stardist_images_and_masks(frames_export, frame_items):
    for item in frame_items:
        folder = frames_export / "stardist" / item.split
        image = tifffile.imread(folder / "images" / f"{item.name}.tif")
        masks = tifffile.imread(folder / "masks" / f"{item.name}.tif")
        assert image.shape == masks.shape == item.image.shape
        np.testing.assert_array_equal(masks, item.labels)


def test_rle_round_trip():
    rng = np.random.default_rng(3)
    for shape in [(5, 7), (1, 1), (16, 3)]:
        for mask in (rng.random(shape) > 0.5, np.ones(shape, bool), np.zeros(shape, bool)):
            rle = rle_encode(mask)
            assert sum(rle["counts"]) == mask.size
            np.testing.assert_array_equal(rle_decode(rle), mask)
    # COCO RLE starts with the count of zeros, column-major
    assert rle_encode(np.array([[1, 0], [1, 1]], bool))["counts"] == [0, 2, 1, 1]


def test_coco_polygons(frames_export, frame_items):
    by_split = {
        split: json.loads(
            (frames_export / "coco" / "annotations" / f"instances_{split}.json").read_text()
        )
        for split in ("train", "val")
    }
    all_ids = []
    for split, data in by_split.items():
        assert data["categories"] == [{"id": 1, "name": "cell", "supercategory": "bacterium"}]
        items = {item.index + 1: item for item in frame_items if item.split == split}
        assert {im["id"] for im in data["images"]} == set(items)
        for image in data["images"]:
            png = iio.imread(frames_export / "coco" / "images" / image["file_name"])
            assert png.shape == (image["height"], image["width"])
        for ann in data["annotations"]:
            all_ids.append(ann["id"])
            item = items[ann["image_id"]]
            mask = item.labels == ann["cell_id"]
            assert ann["area"] == mask.sum()
            assert ann["iscrowd"] == 0
            x, y, w, h = ann["bbox"]
            rows, cols = np.nonzero(mask)
            assert (x, y, w, h) == (cols.min(), rows.min(), np.ptp(cols) + 1, np.ptp(rows) + 1)
            raster = np.zeros(mask.shape, bool)
            for poly in ann["segmentation"]:
                xs, ys = np.asarray(poly[0::2]), np.asarray(poly[1::2])
                rr, cc = draw_polygon(ys - 0.5, xs - 0.5, shape=mask.shape)
                raster[rr, cc] = True
            iou = (raster & mask).sum() / (raster | mask).sum()
            assert iou > 0.85, iou
        n_cells = sum(np.unique(it.labels).size - 1 for it in items.values())
        assert len(data["annotations"]) == n_cells
    assert len(set(all_ids)) == len(all_ids)


def test_coco_rle_is_exact(tmp_path, frame_items):
    write_items(frame_items[:3], tmp_path, ["coco"], coco_segmentation="rle")
    data = json.loads((tmp_path / "coco" / "annotations" / "instances_train.json").read_text())
    items = {item.index + 1: item for item in frame_items}
    assert data["annotations"]
    for ann in data["annotations"]:
        mask = items[ann["image_id"]].labels == ann["cell_id"]
        np.testing.assert_array_equal(rle_decode(ann["segmentation"]), mask)


def _read_zarr_array(folder: Path) -> np.ndarray:
    """A minimal Zarr v2 reader (uncompressed, '/'-separated chunks)."""
    meta = json.loads((folder / ".zarray").read_text())
    assert meta["zarr_format"] == 2
    assert meta["compressor"] is None
    assert meta["dimension_separator"] == "/"
    shape, chunks = meta["shape"], meta["chunks"]
    out = np.full(shape, meta["fill_value"], dtype=np.dtype(meta["dtype"]))
    grid = [range(-(-s // c)) for s, c in zip(shape, chunks)]
    for key in np.ndindex(*[len(g) for g in grid]):
        path = folder.joinpath(*map(str, key))
        if not path.exists():
            continue
        block = np.frombuffer(path.read_bytes(), dtype=out.dtype).reshape(chunks)
        out[tuple(slice(k * c, (k + 1) * c) for k, c in zip(key, chunks))] = block
    return out


def test_ome_zarr_images(frames_export, frame_items):
    for item in frame_items:
        root = frames_export / "ome-zarr" / item.split / f"{item.name}.zarr"
        attrs = json.loads((root / ".zattrs").read_text())
        (ms,) = attrs["multiscales"]
        assert ms["version"] == "0.4"
        assert [a["name"] for a in ms["axes"]] == ["y", "x"]
        assert json.loads((root / "labels" / ".zattrs").read_text())["labels"] == [
            "cells",
            "semantic",
        ]
        label_attrs = json.loads((root / "labels" / "cells" / ".zattrs").read_text())
        assert label_attrs["image-label"]["source"]["image"] == "../../"
        np.testing.assert_array_equal(_read_zarr_array(root / "0"), item.image)
        cells = _read_zarr_array(root / "labels" / "cells" / "0")
        assert cells.dtype == np.uint16
        np.testing.assert_array_equal(cells, item.labels)
        np.testing.assert_array_equal(
            _read_zarr_array(root / "labels" / "semantic" / "0"), item.semantic
        )


def test_ome_zarr_time_series(series_export, series_items_):
    for series in (0, 1):
        frames = [it for it in series_items_ if it.series == series]
        root = series_export / "ome-zarr" / frames[0].split / f"s{series:04d}.zarr"
        (ms,) = json.loads((root / ".zattrs").read_text())["multiscales"]
        assert [a["name"] for a in ms["axes"]] == ["t", "y", "x"]
        assert ms["datasets"][0]["coordinateTransformations"][0]["scale"] == [3.0, 0.065, 0.065]
        stack = _read_zarr_array(root / "0")
        assert stack.shape == (TIMESERIES_FRAMES, *frames[0].image.shape)
        np.testing.assert_array_equal(stack, np.stack([it.image for it in frames]))
        labels = _read_zarr_array(root / "labels" / "cells" / "0")
        np.testing.assert_array_equal(labels, np.stack([it.labels for it in frames]))


def test_ctc_layout_and_man_track(series_export, series_items_):
    for series in (0, 1):
        frames = [it for it in series_items_ if it.series == series]
        split = frames[0].split
        seq = series_export / "ctc" / split / f"{frames[0].sequence + 1:02d}"
        gt = series_export / "ctc" / split / f"{frames[0].sequence + 1:02d}_GT"
        for it in frames:
            image = tifffile.imread(seq / f"t{it.frame:03d}.tif")
            tra = tifffile.imread(gt / "TRA" / f"man_track{it.frame:03d}.tif")
            seg = tifffile.imread(gt / "SEG" / f"man_seg{it.frame:03d}.tif")
            np.testing.assert_array_equal(image, it.image)
            assert tra.dtype == np.uint16
            np.testing.assert_array_equal(tra, it.labels)
            np.testing.assert_array_equal(seg, it.labels)
        table = np.loadtxt(gt / "TRA" / "man_track.txt", dtype=int, ndmin=2)
        assert table.shape == (len(LINEAGE_PARENTS), 4)
        for label, begin, end, parent in table:
            assert (begin, end) == (min(PRESENT[label]), max(PRESENT[label]))
            assert parent == LINEAGE_PARENTS[label]
            # the track label is the mask value in every frame of [begin, end]
            for t in range(begin, end + 1):
                assert label in tifffile.imread(gt / "TRA" / f"man_track{t:03d}.tif")


def test_trackmate_xml(series_export):
    root = ET.parse(series_export / "trackmate" / "train" / "s0000.xml").getroot()
    model = root.find("Model")
    spots = {s.get("ID"): s for s in model.iter("Spot")}
    n_spots = sum(len(PRESENT[c]) for c in PRESENT)
    assert len(spots) == n_spots == int(model.find("AllSpots").get("nspots"))
    edges = [(e.get("SPOT_SOURCE_ID"), e.get("SPOT_TARGET_ID")) for e in model.iter("Edge")]
    # links within each cell's life, plus one per daughter
    within = sum(len(PRESENT[c]) - 1 for c in PRESENT)
    assert len(edges) == within + 2
    for a, b in edges:
        assert int(spots[b].get("FRAME")) == int(spots[a].get("FRAME")) + 1
    tracks = model.find("AllTracks").findall("Track")
    assert len(tracks) == 2  # lineage trees of founders 1 and 4
    splits = sorted(int(t.get("NUMBER_SPLITS")) for t in tracks)
    assert splits == [0, 1]
    spot = next(s for s in spots.values() if s.get("name") == "cell_4" and s.get("FRAME") == "0")
    assert float(spot.get("POSITION_Y")) == pytest.approx(45 * 0.065, abs=0.065)
    assert float(spot.get("POSITION_T")) == 0.0
    assert root.find("Settings/ImageData").get("nframes") == str(TIMESERIES_FRAMES)


def test_wide_labels_use_uint32(tmp_path):
    source = SyntheticSource(1, kind="timeseries", id_offset=70_000)
    items = source.make_unit(0)
    assert items[0].labels.max() > 65535
    write_items(items, tmp_path, ["tiff", "ctc"])
    tra = tifffile.imread(tmp_path / "ctc" / "train" / "01_GT" / "TRA" / "man_track000.tif")
    assert tra.dtype == np.uint32
    np.testing.assert_array_equal(tra, items[0].labels)
    labels = tifffile.imread(tmp_path / "tiff" / "train" / "labels" / "s0000_t0005.tif")
    assert labels.dtype == np.uint32
    assert labels.max() == 70_003
    with pytest.raises(ValueError, match="65535"):
        write_items(items, tmp_path / "png", ["png"])


def test_tracking_formats_reject_single_images(tmp_path, frame_items):
    with pytest.raises(ValueError, match="timeseries"):
        write_items(frame_items[:1], tmp_path, ["ctc"])


def test_registry_lists_every_format():
    assert set(FORMATS) == {
        "tiff",
        "png",
        "delta",
        "omnipose",
        "stardist",
        "coco",
        "ctc",
        "trackmate",
        "ome-zarr",
    }
