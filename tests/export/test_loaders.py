"""Each format opened by the library its users load it with (the ``test`` extra).

pycocotools (COCO), py-ctcmetrics (CTC), ome-zarr (OME-Zarr), pytrackmate (TrackMate
XML), tifffile and this plugin's own reader (pixel size, labels reopen as Labels). DeLTA
itself needs TensorFlow, which is too heavy for the test extra: its training sets are
checked by reading them the way ``delta.data.trainGenerator_seg`` / ``_track`` do (same
file name in each folder, masks binarised, weights raw), through the snippet of
``docs/export.md``, which is executed here as written.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import shutil
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
import tifffile
from _export_synthetic import LINEAGE_PARENTS, PRESENT, TIMESERIES_FRAMES, SyntheticSource

from napari_symbac.export import write_items

DOCS = Path(__file__).resolve().parents[2] / "docs" / "export.md"


@pytest.fixture(scope="module")
def series_items_():
    # units 0 and 1 go to train, unit 2 to val: train/01, train/02 and val/01 in CTC
    source = SyntheticSource(3, kind="timeseries", val_every=3)
    return [item for unit in range(3) for item in source.make_unit(unit)]


@pytest.fixture(scope="module")
def series_export(tmp_path_factory, series_items_) -> Path:
    out = tmp_path_factory.mktemp("loaders") / "dataset"
    formats = ["tiff", "delta", "ctc", "trackmate", "ome-zarr", "coco"]
    report = write_items(series_items_, out, formats, coco_segmentation="rle")
    assert report.complete
    return out


# --------------------------------------------------------------------------------------
# COCO: pycocotools
# --------------------------------------------------------------------------------------


def test_coco_with_pycocotools(series_export, series_items_):
    from pycocotools.coco import COCO
    from pycocotools.cocoeval import COCOeval

    with contextlib.redirect_stdout(io.StringIO()):
        coco = COCO(str(series_export / "coco" / "annotations" / "instances_train.json"))
    train = [it for it in series_items_ if it.split == "train"]
    assert len(coco.getImgIds()) == len(train)
    for item in train[:4]:
        image = coco.loadImgs(item.index + 1)[0]
        assert image["file_name"] == f"{item.name}.png"
        for annotation in coco.loadAnns(coco.getAnnIds(imgIds=image["id"])):
            np.testing.assert_array_equal(
                coco.annToMask(annotation), item.labels == annotation["cell_id"]
            )
    # ground truth scored as detections: AP = 1
    detections = [{**a, "score": 1.0} for a in coco.loadAnns(coco.getAnnIds())]
    with contextlib.redirect_stdout(io.StringIO()):
        result = coco.loadRes(detections)
        evaluation = COCOeval(coco, result, "segm")
        evaluation.evaluate()
        evaluation.accumulate()
        evaluation.summarize()
    assert evaluation.stats[0] == pytest.approx(1.0)


# --------------------------------------------------------------------------------------
# CTC: py-ctcmetrics
# --------------------------------------------------------------------------------------


def test_ctc_sequences_numbered_per_split(series_export):
    ctc = series_export / "ctc"
    assert sorted(p.name for p in (ctc / "train").iterdir()) == ["01", "01_GT", "02", "02_GT"]
    assert sorted(p.name for p in (ctc / "val").iterdir()) == ["01", "01_GT"]


@pytest.mark.parametrize(("split", "sequence"), [("train", "01"), ("train", "02"), ("val", "01")])
def test_ctc_with_py_ctcmetrics(series_export, tmp_path, split, sequence):
    """The ground truth scored as a result: valid, and every metric 1."""
    from ctc_metrics import evaluate_sequence, validate_sequence

    gt = series_export / "ctc" / split / f"{sequence}_GT"
    res = tmp_path / f"{sequence}_RES"
    res.mkdir()
    for mask in sorted((gt / "TRA").glob("man_track*.tif")):
        shutil.copy(mask, res / mask.name.replace("man_track", "mask"))
    shutil.copy(gt / "TRA" / "man_track.txt", res / "res_track.txt")
    with contextlib.redirect_stdout(io.StringIO()):
        validity = validate_sequence(str(res), threads=1)
        scores = evaluate_sequence(str(res), str(gt), threads=1)
    assert validity["Valid"] == 1
    perfect = ("SEG", "TRA", "DET", "LNK", "CT", "TF", "HOTA", "CHOTA", "MOTA", "IDF1")
    for metric in perfect:
        assert scores[metric] == pytest.approx(1.0), metric
    assert scores["AOGM"] == 0
    # CCA and BC are undefined here: 6 frames hold no complete cell cycle


# --------------------------------------------------------------------------------------
# OME-Zarr: ome-zarr
# --------------------------------------------------------------------------------------


def test_ome_zarr_with_ome_zarr_py(series_export, series_items_):
    from ome_zarr.io import parse_url
    from ome_zarr.reader import Reader

    frames = [it for it in series_items_ if it.series == 0]
    nodes = list(Reader(parse_url(str(series_export / "ome-zarr" / "train" / "s0000.zarr")))())
    image = nodes[0]
    data = np.asarray(image.data[0])
    np.testing.assert_array_equal(data, np.stack([it.image for it in frames]))
    axes = image.metadata["axes"]
    assert [a["name"] for a in axes] == ["t", "y", "x"]
    labels = [node for node in nodes if "image-label" in node.zarr.root_attrs]
    assert labels
    cells = next(n for n in labels if n.zarr.path.rstrip("/").endswith("cells"))
    np.testing.assert_array_equal(
        np.asarray(cells.data[0]), np.stack([it.labels for it in frames])
    )


# --------------------------------------------------------------------------------------
# TrackMate: pytrackmate and TrackMate's layout
# --------------------------------------------------------------------------------------


def test_trackmate_with_pytrackmate(series_export):
    from pytrackmate import trackmate_peak_import

    xml = series_export / "trackmate" / "train" / "s0000.xml"
    spots = trackmate_peak_import(str(xml), get_tracks=True)
    assert len(spots) == sum(len(frames) for frames in PRESENT.values())
    assert spots["t_stamp"].max() == TIMESERIES_FRAMES - 1
    # two lineage trees: founder 1 with daughters 2, 3 and founder 4
    assert spots["label"].nunique() == 2
    np.testing.assert_allclose(spots["t"], spots["t_stamp"] * 3.0)


def test_trackmate_settings_and_image_beside_it(series_export, series_items_):
    import xml.etree.ElementTree as ET

    xml = series_export / "trackmate" / "train" / "s0000.xml"
    root = ET.parse(xml).getroot()
    settings = root.find("Settings")
    for tag in (
        "ImageData",
        "BasicSettings",
        "DetectorSettings",
        "InitialSpotFilter",
        "SpotFilterCollection",
        "TrackerSettings",
        "TrackFilterCollection",
        "AnalyzerCollection",
    ):
        assert settings.find(tag) is not None, tag
    declared = {
        f.get("feature") for f in root.find("Model/FeatureDeclarations/SpotFeatures")
    }
    for spot in root.iter("Spot"):
        assert declared <= set(spot.attrib)
    # what TrackMate 7's TmXmlReader parses: dimensions of its Dimension enum, every
    # spot, edge and track attribute but the names a number, a GUI state
    dimensions = {"NONE", "QUALITY", "COST", "INTENSITY", "POSITION", "LENGTH", "AREA", "TIME"}
    for feature in root.iter("Feature"):
        assert feature.get("dimension") in dimensions
        assert feature.get("isint") in ("true", "false")
    for element in (*root.iter("Spot"), *root.iter("Edge"), *root.iter("Track")):
        for key, value in element.attrib.items():
            if key != "name":
                float(value)
    assert root.find("GUIState") is not None
    filtered = {t.get("TRACK_ID") for t in root.iter("TrackID")}
    assert filtered == {t.get("TRACK_ID") for t in root.iter("Track")}
    image_data = settings.find("ImageData")
    stack_path = xml.parent / image_data.get("folder") / image_data.get("filename")
    with tifffile.TiffFile(stack_path) as tif:
        stack = tif.asarray()
        assert tif.imagej_metadata["finterval"] == pytest.approx(180.0)
    frames = [it for it in series_items_ if it.series == 0]
    np.testing.assert_array_equal(stack, np.stack([it.image for it in frames]))
    assert int(image_data.get("nframes")) == stack.shape[0]
    assert (int(image_data.get("height")), int(image_data.get("width"))) == stack.shape[1:]


# --------------------------------------------------------------------------------------
# TIFF: pixel size everywhere, labels reopen as Labels
# --------------------------------------------------------------------------------------


def test_every_tiff_carries_the_pixel_size(series_export):
    from napari_symbac.io import read_recording

    tiffs = sorted(series_export.rglob("*.tif"))
    assert len(tiffs) > 50
    for path in tiffs:
        assert read_recording(path).pixel_size_um == pytest.approx(0.065, rel=1e-6), path


@pytest.mark.parametrize(
    ("relative", "layer_type"),
    [
        ("tiff/train/images/s0000_t0003.tif", "image"),
        ("tiff/train/labels/s0000_t0003.tif", "labels"),
        ("tiff/train/semantic/s0000_t0003.tif", "labels"),
        ("ctc/train/01/t003.tif", "image"),
        ("ctc/train/01_GT/SEG/man_seg003.tif", "labels"),
        ("trackmate/train/s0000.tif", "image"),
    ],
)
def test_reader_opens_masks_as_labels(series_export, relative, layer_type):
    from napari_symbac.io import napari_get_reader

    path = str(series_export / relative)
    [(_data, meta, kind)] = napari_get_reader(path)(path)
    assert kind == layer_type
    assert meta["scale"][-2:] == pytest.approx((0.065, 0.065))


def test_labels_named_by_convention_open_as_labels(tmp_path):
    """Masks written by other tools carry no marker: their names say what they are."""
    from napari_symbac.io import napari_get_reader

    mask = np.zeros((8, 8), np.uint16)
    mask[2:5, 2:5] = 3
    paths = [tmp_path / "cell_masks.tif", tmp_path / "man_track007.tif"]
    (tmp_path / "masks").mkdir()
    paths.append(tmp_path / "masks" / "a.tif")
    for path in paths:
        tifffile.imwrite(path, mask)
        [(_data, _meta, kind)] = napari_get_reader(str(path))(str(path))
        assert kind == "labels", path
    tifffile.imwrite(tmp_path / "field.tif", mask)
    [(_data, _meta, kind)] = napari_get_reader(str(tmp_path / "field.tif"))(
        str(tmp_path / "field.tif")
    )
    assert kind == "image"


# --------------------------------------------------------------------------------------
# DeLTA
# --------------------------------------------------------------------------------------


def _docs_snippet(marker: str) -> str:
    blocks = re.findall(r"```python\n(.*?)```", DOCS.read_text("utf-8"), flags=re.S)
    return next(block for block in blocks if marker in block)


def test_delta_docs_snippet_runs(series_export, monkeypatch):
    monkeypatch.chdir(series_export.parent)
    namespace: dict = {}
    exec(compile(_docs_snippet("# reads as DeLTA does"), str(DOCS), "exec"), namespace)
    assert namespace["x"].shape[-1] == 4  # img, seg, previmg, segall
    assert namespace["y"].shape[-1] == 2  # mot_dau, wei


def _read(folder: Path, name: str) -> np.ndarray:
    return iio.imread(folder / name)


def test_delta_segmentation_weights(tmp_path):
    item = SyntheticSource(3).make_unit(2)[0]  # three touching cells
    write_items([item], tmp_path, ["delta"])
    base = tmp_path / "delta" / item.split
    weights = _read(base / "wei", f"{item.name}.png").astype(float) / 100
    seg = _read(base / "seg", f"{item.name}.png") > 0
    assert weights.min() >= 1.0
    np.testing.assert_allclose(weights[seg], 1.0)  # cells: class weight 1
    # the one-pixel gaps separating touching cells weigh most:
    # 1 + 12 exp(-(1 + 1)^2 / (2 * 2^2)) = 8.28 (U-Net eq. 2, w0 = 12, sigma = 2 px)
    gap = (item.labels > 0) & ~seg
    assert gap.sum() >= 2 * 5
    assert np.median(weights[gap]) == pytest.approx(1 + 12 * np.exp(-0.5), abs=0.01)
    far = ~seg & (weights < 1.001)
    assert far.sum() > 0.3 * (~seg).sum()  # background far from any pair of cells


def test_delta_tracking_set(series_export, series_items_):
    base = series_export / "delta" / "train" / "tracking"
    folders = ["img", "seg", "previmg", "segall", "mot_dau", "wei"]
    names = [sorted(p.name for p in (base / f).iterdir()) for f in folders]
    assert all(n == names[0] for n in names)  # the same file name in every folder
    frames = {(it.series, it.frame): it for it in series_items_}
    n_samples = sum(
        len(np.unique(frames[(s, t - 1)].labels)) - 1
        for (s, t), it in frames.items()
        if it.split == "train" and t >= 1
    )
    assert len(names[0]) == n_samples
    # cell 1 divides after frame 2: at frame 3 its sample holds daughters 2 and 3
    division = "s0000_t0003_cell000001.png"
    mot_dau = _read(base / "mot_dau", division) > 0
    labels = frames[(0, 3)].labels
    assert set(np.unique(labels[mot_dau])) == {2, 3}
    seed = _read(base / "seg", division) > 0
    np.testing.assert_array_equal(seed, frames[(0, 2)].labels == 1)
    np.testing.assert_array_equal(_read(base / "previmg", division), frames[(0, 2)].image)
    np.testing.assert_array_equal(_read(base / "img", division), frames[(0, 3)].image)
    # cell 4 is gone at frame 5: an empty target, its former neighbours weigh most
    gone = _read(base / "mot_dau", "s0000_t0005_cell000004.png")
    assert not gone.any()
    assert LINEAGE_PARENTS[4] == 0
    weights = _read(base / "wei", division).astype(float) / 100
    assert weights[mot_dau].min() == pytest.approx(20.0)
    assert weights[~(_read(base / "segall", division) > 0)].max() == pytest.approx(1.0)


def test_delta_frames_kind_has_no_tracking(tmp_path):
    items = [it for unit in range(2) for it in SyntheticSource(2).make_unit(unit)]
    write_items(items, tmp_path, ["delta"])
    assert not (tmp_path / "delta" / "train" / "tracking").exists()
    assert len(os.listdir(tmp_path / "delta" / "train" / "wei")) == 2


def test_render_command_writes_calibrated_tiffs(tmp_path):
    from napari_symbac.cli import main
    from napari_symbac.io import napari_get_reader, read_recording
    from napari_symbac.settings import PipelineSettings

    assert main(["simulate", "--frames", "3", "--out", str(tmp_path / "sim")]) == 0
    assert main(["render", str(tmp_path / "sim"), "--out", str(tmp_path / "r")]) == 0
    pixel = PipelineSettings().microscope.pixel_size_um
    kinds = {}
    for name in ("images", "labels", "semantic"):
        path = str(tmp_path / "r" / f"{name}.tif")
        assert read_recording(path).pixel_size_um == pytest.approx(pixel, rel=1e-6)
        [(data, meta, kinds[name])] = napari_get_reader(path)(path)
        assert data.shape[0] == 3
        assert meta["scale"] == pytest.approx((1.0, pixel, pixel))
    assert kinds == {"images": "image", "labels": "labels", "semantic": "labels"}
    with tifffile.TiffFile(tmp_path / "r" / "images.tif") as tif:
        frame_s = 60 * PipelineSettings().simulation.frame_interval_min
        assert tif.imagej_metadata["finterval"] == pytest.approx(frame_s)
    assert sorted(p.name for p in (tmp_path / "r").iterdir()) == [
        "images.tif",
        "labels.tif",
        "semantic.tif",
    ]


def test_weight_png_never_has_a_maximum_of_255():
    """DeLTA divides an image whose maximum is 255 by 255; weights must not be read so."""
    from napari_symbac.export.weights import to_weight_png

    stored = to_weight_png(np.array([[1.0, 2.55], [2.0, 1.5]]))
    assert stored.max() == 256
    np.testing.assert_array_equal(stored.ravel()[[0, 2, 3]], [100, 200, 150])
    with pytest.raises(ValueError, match="16-bit PNG"):
        to_weight_png(np.array([[-1.0]]))
