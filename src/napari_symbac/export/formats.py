"""Dataset formats: one writer per training tool, behind a small registry.

Writers follow :class:`~napari_symbac.export.writer.FormatWriter`. Every layout puts
the training and validation items in ``train/`` and ``val/`` folders under the format's
own folder, e.g. ``stardist/train/images/000001.tif``. DeLTA lives in
:mod:`napari_symbac.export.delta`, the tracking formats (CTC, TrackMate) in
:mod:`napari_symbac.export.tracking`. See ``docs/export.md`` for a snippet that loads
each format.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from napari_symbac.export.atomic import write_bytes, write_json, write_png, write_tiff
from napari_symbac.export.delta import DeltaWriter
from napari_symbac.export.item import ExportItem
from napari_symbac.export.tracking import CtcWriter, TrackMateWriter
from napari_symbac.export.writer import FormatWriter, Record, relative

__all__ = [
    "FORMATS",
    "CocoWriter",
    "CtcWriter",
    "DeltaWriter",
    "FormatWriter",
    "OmeZarrWriter",
    "OmniposeWriter",
    "PngWriter",
    "StarDistWriter",
    "TiffWriter",
    "TrackMateWriter",
    "get_writer",
    "rle_decode",
    "rle_encode",
    "tracking_formats",
]

# --------------------------------------------------------------------------------------
# Image/mask pairs
# --------------------------------------------------------------------------------------


class TiffWriter(FormatWriter):
    """Plain TIFFs: ``tiff/{split}/{images,labels,semantic}/{name}.tif``.

    ``images`` uint16, ``labels`` uint16/uint32 instance masks (value = cell id),
    ``semantic`` uint8 (1 in cells, 0 between touching cells and in the background).
    """

    name = "tiff"

    def write_item(self, out_dir: Path, item: ExportItem) -> list[str]:
        base = out_dir / self.name / item.split
        paths = [base / "images" / f"{item.name}.tif", base / "labels" / f"{item.name}.tif"]
        paths.append(base / "semantic" / f"{item.name}.tif")
        px = item.pixel_size_um
        write_tiff(paths[0], item.image_uint16(), pixel_size_um=px)
        write_tiff(paths[1], item.instance_mask(), pixel_size_um=px, kind="labels")
        write_tiff(paths[2], item.semantic, pixel_size_um=px, kind="semantic")
        return [relative(out_dir, p) for p in paths]


class PngWriter(FormatWriter):
    """Plain PNGs: ``png/{split}/{images,labels,semantic}/{name}.png``.

    16-bit images and instance masks, 8-bit semantic masks (0/1). PNG cannot hold more
    than 65535 labels: use ``tiff`` for such masks.
    """

    name = "png"

    def write_item(self, out_dir: Path, item: ExportItem) -> list[str]:
        if item.label_dtype.itemsize > 2:
            raise ValueError(
                f"item {item.name} has cell ids above 65535, which a 16-bit PNG cannot hold: "
                "use the 'tiff' format"
            )
        base = out_dir / self.name / item.split
        paths = [base / d / f"{item.name}.png" for d in ("images", "labels", "semantic")]
        write_png(paths[0], item.image_uint16())
        write_png(paths[1], item.instance_mask())
        write_png(paths[2], item.semantic)
        return [relative(out_dir, p) for p in paths]


class OmniposeWriter(FormatWriter):
    """Omnipose / Cellpose: ``omnipose/{split}/{name}.tif`` beside ``{name}_masks.tif``.

    Masks are uint16/uint32 instance masks, as ``cellpose.io.load_train_test_data(train_dir,
    test_dir, mask_filter="_masks")`` reads them.
    """

    name = "omnipose"

    def write_item(self, out_dir: Path, item: ExportItem) -> list[str]:
        base = out_dir / self.name / item.split
        paths = [base / f"{item.name}.tif", base / f"{item.name}_masks.tif"]
        write_tiff(paths[0], item.image_uint16(), pixel_size_um=item.pixel_size_um)
        write_tiff(paths[1], item.instance_mask(), pixel_size_um=item.pixel_size_um, kind="labels")
        return [relative(out_dir, p) for p in paths]


class StarDistWriter(FormatWriter):
    """StarDist: ``stardist/{split}/images/{name}.tif`` and ``.../masks/{name}.tif``."""

    name = "stardist"

    def write_item(self, out_dir: Path, item: ExportItem) -> list[str]:
        base = out_dir / self.name / item.split
        paths = [base / "images" / f"{item.name}.tif", base / "masks" / f"{item.name}.tif"]
        write_tiff(paths[0], item.image_uint16(), pixel_size_um=item.pixel_size_um)
        write_tiff(paths[1], item.instance_mask(), pixel_size_um=item.pixel_size_um, kind="labels")
        return [relative(out_dir, p) for p in paths]


# --------------------------------------------------------------------------------------
# COCO
# --------------------------------------------------------------------------------------


def rle_encode(mask: np.ndarray) -> dict[str, Any]:
    """Uncompressed COCO run-length encoding of a binary mask (column-major, from 0s)."""
    mask = np.asarray(mask, dtype=bool)
    flat = mask.ravel(order="F").astype(np.int8)
    changes = np.flatnonzero(np.diff(np.concatenate([[0], flat, [0]])))
    # runs alternate 0s, 1s, 0s, ...; the first run counts zeros (possibly 0 of them)
    bounds = np.concatenate([[0], changes, [flat.size]])
    counts = np.diff(bounds)
    if counts.size and counts[-1] == 0:
        counts = counts[:-1]
    return {"counts": [int(c) for c in counts], "size": [int(mask.shape[0]), int(mask.shape[1])]}


def rle_decode(rle: Mapping[str, Any]) -> np.ndarray:
    """Inverse of :func:`rle_encode` (uncompressed RLE only)."""
    height, width = rle["size"]
    values = np.zeros(height * width, dtype=bool)
    position, value = 0, False
    for count in rle["counts"]:
        values[position : position + count] = value
        position += count
        value = not value
    return values.reshape((height, width), order="F")


def _polygons(mask: np.ndarray) -> list[list[float]]:
    """COCO polygons ``[x0, y0, x1, y1, ...]`` (pixel corners at integers) of a mask."""
    from skimage.measure import approximate_polygon, find_contours

    padded = np.pad(mask.astype(np.float32), 1)
    polygons = []
    for contour in find_contours(padded, 0.5):
        contour = approximate_polygon(contour, tolerance=0.25)
        if len(contour) < 4:  # closed contour: first point repeated
            continue
        # back to unpadded pixel centres, then to COCO's continuous coordinates
        ys = contour[:-1, 0] - 1 + 0.5
        xs = contour[:-1, 1] - 1 + 0.5
        flat = np.empty(2 * ys.size)
        flat[0::2], flat[1::2] = xs, ys
        polygons.append([round(float(v), 2) for v in flat])
    return polygons


class CocoWriter(FormatWriter):
    """COCO instance segmentation: ``coco/images/{name}.png`` (16-bit) and
    ``coco/annotations/instances_{train,val}.json``.

    Parameters
    ----------
    segmentation
        ``"polygon"`` (outline polygons, ``iscrowd=0``) or ``"rle"`` (uncompressed RLE,
        exact, as ``pycocotools.mask.frPyObjects`` reads it).
    """

    name = "coco"

    def __init__(self, segmentation: str = "polygon") -> None:
        if segmentation not in ("polygon", "rle"):
            raise ValueError(f"COCO segmentation must be 'polygon' or 'rle', got {segmentation!r}")
        self.segmentation = segmentation

    def write_item(self, out_dir: Path, item: ExportItem) -> list[str]:
        base = out_dir / self.name
        image_path = base / "images" / f"{item.name}.png"
        write_png(image_path, item.image_uint16())
        labels = item.labels
        annotations = []
        for cell in np.unique(labels):
            if cell == 0:
                continue
            mask = labels == cell
            rows = np.flatnonzero(mask.any(axis=1))
            cols = np.flatnonzero(mask.any(axis=0))
            if self.segmentation == "rle":
                segmentation: Any = rle_encode(mask)
            else:
                segmentation = _polygons(mask)
            annotations.append(
                {
                    "cell_id": int(cell),
                    "category_id": 1,
                    "iscrowd": 0,
                    "area": int(mask.sum()),
                    "bbox": [
                        int(cols[0]),
                        int(rows[0]),
                        int(cols[-1] - cols[0] + 1),
                        int(rows[-1] - rows[0] + 1),
                    ],
                    "segmentation": segmentation,
                }
            )
        part = {
            "image": {
                "id": int(item.index) + 1,
                "file_name": f"{item.name}.png",
                "height": int(labels.shape[0]),
                "width": int(labels.shape[1]),
            },
            "annotations": annotations,
        }
        part_path = base / "annotations" / "parts" / f"{item.name}.json"
        write_json(part_path, part)
        return [relative(out_dir, image_path), relative(out_dir, part_path)]

    def finalize(self, out_dir: Path, records: Sequence[Record]) -> list[str]:
        written = []
        base = out_dir / self.name / "annotations"
        n_annotations = 0  # ids unique across splits, so the files can be merged
        for split in ("train", "val"):
            images, annotations = [], []
            for record in records:
                if record["split"] != split:
                    continue
                part = json.loads((base / "parts" / f"{record['name']}.json").read_text("utf-8"))
                images.append(part["image"])
                for annotation in part["annotations"]:
                    n_annotations += 1
                    image_id = part["image"]["id"]
                    annotations.append({"id": n_annotations, "image_id": image_id} | annotation)
            if not images:
                continue
            dataset = {
                "info": {"description": "napari-symbac synthetic micrographs", "version": "1.0"},
                "licenses": [],
                "categories": [{"id": 1, "name": "cell", "supercategory": "bacterium"}],
                "images": images,
                "annotations": annotations,
            }
            path = base / f"instances_{split}.json"
            write_json(path, dataset)
            written.append(relative(out_dir, path))
        return written


# --------------------------------------------------------------------------------------
# OME-Zarr (written by hand: Zarr v2 arrays, uncompressed, OME-NGFF 0.4 metadata)
# --------------------------------------------------------------------------------------


class OmeZarrWriter(FormatWriter):
    """OME-Zarr (OME-NGFF 0.4), written without the ``zarr`` package.

    Independent images: one group per item, ``ome-zarr/{split}/{name}.zarr`` with the
    image at ``0`` (axes ``y, x``) and the label images ``labels/cells`` (instance) and
    ``labels/semantic``. Time series: one group per series, ``ome-zarr/{split}/s{SSSS}.zarr``
    with axes ``t, y, x`` and one chunk per frame, so each frame is written atomically on
    its own. Arrays are Zarr v2, uncompressed, ``dimension_separator`` ``"/"``; any
    OME-Zarr reader (``ome-zarr-py``, napari-ome-zarr, ``zarr.open``) opens them.
    """

    name = "ome-zarr"

    @staticmethod
    def _multiscales(name: str, axes: list[dict[str, str]], scale: list[float]) -> dict[str, Any]:
        return {
            "multiscales": [
                {
                    "version": "0.4",
                    "name": name,
                    "axes": axes,
                    "datasets": [
                        {
                            "path": "0",
                            "coordinateTransformations": [{"type": "scale", "scale": scale}],
                        }
                    ],
                }
            ]
        }

    @staticmethod
    def _zarray(shape: tuple[int, ...], chunks: tuple[int, ...], dtype: np.dtype) -> dict[str, Any]:
        return {
            "zarr_format": 2,
            "shape": list(shape),
            "chunks": list(chunks),
            "dtype": np.dtype(dtype).newbyteorder("<").str,
            "compressor": None,
            "fill_value": 0,
            "order": "C",
            "filters": None,
            "dimension_separator": "/",
        }

    def write_item(self, out_dir: Path, item: ExportItem) -> list[str]:
        if item.is_timeseries:
            root = out_dir / self.name / item.split / f"s{item.series:04d}.zarr"
            n_frames = int(item.n_frames or item.frame + 1)
            lead: tuple[int, ...] = (n_frames,)
            key: tuple[int, ...] = (item.frame,)
            axes = [{"name": "t", "type": "time", "unit": "minute"}]
            scale = [float(item.frame_interval_min)]
        else:
            root = out_dir / self.name / item.split / f"{item.name}.zarr"
            lead, key, axes, scale = (), (), [], []
        axes = [
            *axes,
            {"name": "y", "type": "space", "unit": "micrometer"},
            {"name": "x", "type": "space", "unit": "micrometer"},
        ]
        scale = [*scale, float(item.pixel_size_um), float(item.pixel_size_um)]
        shape = lead + item.image.shape
        chunks = (1,) * len(lead) + item.image.shape
        arrays = [
            (root, item.image_uint16(), "image"),
            (root / "labels" / "cells", item.instance_mask(), "cells"),
            (root / "labels" / "semantic", item.semantic, "semantic"),
        ]
        written = []
        for group, data, name in arrays:
            chunk = group / "0" / "/".join(str(k) for k in (*key, 0, 0))
            write_bytes(
                chunk, np.ascontiguousarray(data.astype(data.dtype.newbyteorder("<"))).tobytes()
            )
            written.append(relative(out_dir, chunk))
            write_json(group / "0" / ".zarray", self._zarray(shape, chunks, data.dtype), indent=2)
            attrs = self._multiscales(name, axes, scale)
            if group != root:
                attrs["image-label"] = {"version": "0.4", "source": {"image": "../../"}}
            write_json(group / ".zattrs", attrs, indent=2)
            write_json(group / ".zgroup", {"zarr_format": 2}, indent=2)
            written += [
                relative(out_dir, p)
                for p in (group / "0" / ".zarray", group / ".zattrs", group / ".zgroup")
            ]
        write_json(root / "labels" / ".zgroup", {"zarr_format": 2}, indent=2)
        write_json(root / "labels" / ".zattrs", {"labels": ["cells", "semantic"]}, indent=2)
        # the stores' metadata too: a copy made from the manifest opens (found as a user)
        written += [relative(out_dir, root / "labels" / name) for name in (".zgroup", ".zattrs")]
        return written


#: Name -> writer class. Add a format by subclassing :class:`FormatWriter` and registering it.
FORMATS: dict[str, Callable[..., FormatWriter]] = {
    cls.name: cls
    for cls in (
        TiffWriter,
        PngWriter,
        DeltaWriter,
        OmniposeWriter,
        StarDistWriter,
        CocoWriter,
        CtcWriter,
        TrackMateWriter,
        OmeZarrWriter,
    )
}


def tracking_formats(formats: Iterable[str]) -> list[str]:
    """The formats among ``formats`` that hold tracking ground truth and so need a time
    series (``timeseries_only``), in their order; unknown names are left out."""
    known = [f for f in formats if f in FORMATS]
    return [f for f in known if FORMATS[f].timeseries_only]  # type: ignore[attr-defined]


def get_writer(name: str, **options: Any) -> FormatWriter:
    """The writer registered as ``name``; ``options`` go to its constructor if it takes any.

    Raises
    ------
    ValueError
        If no format of that name exists (the message lists the known ones).
    """
    if name not in FORMATS:
        raise ValueError(f"unknown export format {name!r}; known formats: {', '.join(FORMATS)}")
    cls = FORMATS[name]
    if name == "coco":
        return cls(segmentation=options.get("coco_segmentation", "polygon"))
    return cls()
