"""Dataset formats: one writer per training tool, behind a small registry.

A writer has two methods:

``write_item(out_dir, item) -> list[str]``
    Write the files of one :class:`~napari_symbac.export.item.ExportItem` (image first,
    then its masks, each atomically) and return their paths relative to ``out_dir``.
``finalize(out_dir, records) -> list[str]``
    Write dataset-level files (COCO JSON, ``man_track.txt``, TrackMate XML) from the
    manifest entries of all finished items, without reading the masks back.

Every layout puts the training and validation items in ``train/`` and ``val/`` folders
under the format's own folder, e.g. ``stardist/train/images/000001.tif``. See
``docs/export.md`` for a snippet that loads each format.
"""

from __future__ import annotations

import itertools
import json
import xml.etree.ElementTree as ET
from collections import defaultdict
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from napari_symbac.export.atomic import write_bytes, write_json, write_png, write_text, write_tiff
from napari_symbac.export.item import ExportItem

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
]

Record = Mapping[str, Any]


class FormatWriter:
    """Base class of the writers; subclasses set :attr:`name` and override the methods."""

    #: Registry key and folder name.
    name: ClassVar[str] = ""
    #: Whether the format only makes sense for time series (tracking formats).
    timeseries_only: ClassVar[bool] = False

    def write_item(self, out_dir: Path, item: ExportItem) -> list[str]:
        """Write one item's files; return their paths relative to ``out_dir``."""
        raise NotImplementedError

    def finalize(self, out_dir: Path, records: Sequence[Record]) -> list[str]:
        """Write dataset-level files from the manifest entries of all items."""
        return []

    def _check(self, item: ExportItem) -> None:
        if self.timeseries_only and not item.is_timeseries:
            raise ValueError(
                f"the {self.name!r} format holds time series (tracking ground truth); item "
                f"{item.name} is a single image: export with kind='timeseries'"
            )


def _rel(out_dir: Path, path: Path) -> str:
    return path.relative_to(out_dir).as_posix()


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
        return [_rel(out_dir, p) for p in paths]


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
        return [_rel(out_dir, p) for p in paths]


class DeltaWriter(FormatWriter):
    """DeLTA 2.x segmentation training set: ``delta/{split}/{img,seg}/{name}.png``.

    ``img`` is the 16-bit image, ``seg`` an 8-bit binary mask (255 in cells) with touching
    cells separated by background pixels, as ``delta.data.trainGenerator_seg`` expects.
    Weight maps (``wei/``) are computed by DeLTA itself (``delta.data.seg_weights``).
    """

    name = "delta"

    def write_item(self, out_dir: Path, item: ExportItem) -> list[str]:
        base = out_dir / self.name / item.split
        paths = [base / "img" / f"{item.name}.png", base / "seg" / f"{item.name}.png"]
        write_png(paths[0], item.image_uint16())
        write_png(paths[1], (item.semantic * 255).astype(np.uint8))
        return [_rel(out_dir, p) for p in paths]


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
        return [_rel(out_dir, p) for p in paths]


class StarDistWriter(FormatWriter):
    """StarDist: ``stardist/{split}/images/{name}.tif`` and ``.../masks/{name}.tif``."""

    name = "stardist"

    def write_item(self, out_dir: Path, item: ExportItem) -> list[str]:
        base = out_dir / self.name / item.split
        paths = [base / "images" / f"{item.name}.tif", base / "masks" / f"{item.name}.tif"]
        write_tiff(paths[0], item.image_uint16(), pixel_size_um=item.pixel_size_um)
        write_tiff(paths[1], item.instance_mask(), pixel_size_um=item.pixel_size_um, kind="labels")
        return [_rel(out_dir, p) for p in paths]


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
        return [_rel(out_dir, image_path), _rel(out_dir, part_path)]

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
            written.append(_rel(out_dir, path))
        return written


# --------------------------------------------------------------------------------------
# Tracking
# --------------------------------------------------------------------------------------


def _series_groups(records: Sequence[Record]) -> dict[tuple[str, int], list[Record]]:
    groups: dict[tuple[str, int], list[Record]] = defaultdict(list)
    for record in records:
        if record.get("series") is None:
            continue
        groups[(record["split"], int(record["series"]))].append(record)
    for group in groups.values():
        group.sort(key=lambda r: r["frame"])
    return dict(sorted(groups.items(), key=lambda kv: kv[0][1]))


def _frame_digits(n_frames: int) -> int:
    return max(3, len(str(max(int(n_frames) - 1, 0))))


def _tracks(group: Sequence[Record]) -> dict[int, tuple[int, int, int]]:
    """Cell id -> (first frame, last frame, parent id) from the manifest entries of a series."""
    first: dict[int, int] = {}
    last: dict[int, int] = {}
    parent: dict[int, int] = {}
    for record in group:
        for cell, par, *_ in record["objects"]:
            first.setdefault(cell, record["frame"])
            last[cell] = record["frame"]
            parent[cell] = par
    return {
        cell: (first[cell], last[cell], parent[cell] if parent[cell] in first else 0)
        for cell in sorted(first)
    }


class CtcWriter(FormatWriter):
    """Cell Tracking Challenge layout, one sequence per series.

    ``ctc/{split}/{SS}/t{TTT}.tif`` (uint16 images), ``ctc/{split}/{SS}_GT/TRA/man_track{TTT}.tif``
    and ``.../SEG/man_seg{TTT}.tif`` (instance masks, value = track label = cell id) and
    ``ctc/{split}/{SS}_GT/TRA/man_track.txt`` with one ``L B E P`` line per track (label,
    first frame, last frame, parent label or 0). ``SS`` numbers series from 01; frames
    have at least three digits.
    """

    name = "ctc"
    timeseries_only = True

    def _dirs(self, out_dir: Path, split: str, series: int) -> tuple[Path, Path]:
        seq = f"{series + 1:02d}"
        base = out_dir / self.name / split
        return base / seq, base / f"{seq}_GT"

    def write_item(self, out_dir: Path, item: ExportItem) -> list[str]:
        self._check(item)
        images, gt = self._dirs(out_dir, item.split, item.series)
        t = f"{item.frame:0{_frame_digits(item.n_frames or item.frame + 1)}d}"
        paths = [images / f"t{t}.tif", gt / "TRA" / f"man_track{t}.tif"]
        paths.append(gt / "SEG" / f"man_seg{t}.tif")
        px = item.pixel_size_um
        write_tiff(paths[0], item.image_uint16(), pixel_size_um=px)
        mask = item.instance_mask()
        write_tiff(paths[1], mask, pixel_size_um=px, kind="labels")
        write_tiff(paths[2], mask, pixel_size_um=px, kind="labels")
        return [_rel(out_dir, p) for p in paths]

    def finalize(self, out_dir: Path, records: Sequence[Record]) -> list[str]:
        written = []
        for (split, series), group in _series_groups(records).items():
            lines = [f"{cell} {b} {e} {p}" for cell, (b, e, p) in _tracks(group).items()]
            path = self._dirs(out_dir, split, series)[1] / "TRA" / "man_track.txt"
            write_text(path, "\n".join(lines) + ("\n" if lines else ""))
            written.append(_rel(out_dir, path))
        return written


class TrackMateWriter(FormatWriter):
    """TrackMate XML, one file per series: ``trackmate/{split}/s{SSSS}.xml``.

    Each cell in each frame is a spot at its centroid (physical units, micrometres and
    minutes) named ``cell_{id}``; consecutive frames of a cell are linked, and a mother's
    last spot links to each daughter's first spot. A TrackMate track is a lineage tree.
    """

    name = "trackmate"
    timeseries_only = True

    def write_item(self, out_dir: Path, item: ExportItem) -> list[str]:
        self._check(item)
        return []  # everything comes from the manifest entries, in finalize

    def finalize(self, out_dir: Path, records: Sequence[Record]) -> list[str]:
        written = []
        for (split, series), group in _series_groups(records).items():
            path = out_dir / self.name / split / f"s{series:04d}.xml"
            write_bytes(path, self._xml(group))
            written.append(_rel(out_dir, path))
        return written

    @staticmethod
    def _xml(group: Sequence[Record]) -> bytes:
        px = float(group[0].get("pixel_size_um", 1.0))
        dt = float(group[0].get("frame_interval_min", 1.0))
        height, width = group[0]["shape"]
        n_frames = int(group[0].get("n_frames") or len(group))
        spot_of: dict[tuple[int, int], int] = {}
        root = ET.Element("TrackMate", version="7.11.1")
        model = ET.SubElement(root, "Model", spatialunits="µm", timeunits="min")
        all_spots = ET.SubElement(model, "AllSpots", nspots="0")
        n_spots = 0
        for record in group:
            frame = int(record["frame"])
            in_frame = ET.SubElement(all_spots, "SpotsInFrame", frame=str(frame))
            for cell, _parent, y, x, area in record["objects"]:
                spot_id = n_spots
                n_spots += 1
                spot_of[(cell, frame)] = spot_id
                ET.SubElement(
                    in_frame,
                    "Spot",
                    ID=str(spot_id),
                    name=f"cell_{cell}",
                    POSITION_X=repr(round(x * px, 6)),
                    POSITION_Y=repr(round(y * px, 6)),
                    POSITION_Z="0.0",
                    POSITION_T=repr(round(frame * dt, 6)),
                    FRAME=str(frame),
                    RADIUS=repr(round(float(np.sqrt(area / np.pi)) * px, 6)),
                    QUALITY="1.0",
                    VISIBILITY="1",
                )
        all_spots.set("nspots", str(n_spots))
        tracks = _tracks(group)
        edges: list[tuple[int, int]] = []
        frames_of: dict[int, list[int]] = defaultdict(list)
        for cell, frame in sorted(spot_of, key=lambda cf: (cf[0], cf[1])):
            frames_of[cell].append(frame)
        for cell, frames in frames_of.items():
            for a, b in itertools.pairwise(frames):
                edges.append((spot_of[(cell, a)], spot_of[(cell, b)]))
            parent = tracks[cell][2]
            if parent:
                edges.append((spot_of[(parent, frames_of[parent][-1])], spot_of[(cell, frames[0])]))
        # tracks are the connected components (lineage trees) of the spot graph
        root_of = list(range(n_spots))

        def find(i: int) -> int:
            while root_of[i] != i:
                root_of[i] = root_of[root_of[i]]
                i = root_of[i]
            return i

        for a, b in edges:
            root_of[find(a)] = find(b)
        components: dict[int, list[tuple[int, int]]] = defaultdict(list)
        for a, b in edges:
            components[find(a)].append((a, b))
        all_tracks = ET.SubElement(model, "AllTracks")
        filtered = ET.SubElement(model, "FilteredTracks")
        for track_id, (_root, track_edges) in enumerate(sorted(components.items())):
            track = ET.SubElement(
                all_tracks,
                "Track",
                name=f"Track_{track_id}",
                TRACK_ID=str(track_id),
                TRACK_INDEX=str(track_id),
                NUMBER_SPOTS=str(len({s for e in track_edges for s in e})),
                NUMBER_SPLITS=str(
                    sum(
                        1
                        for s in {a for a, _ in track_edges}
                        if [a for a, _ in track_edges].count(s) > 1
                    )
                ),
            )
            for a, b in sorted(track_edges):
                ET.SubElement(
                    track, "Edge", SPOT_SOURCE_ID=str(a), SPOT_TARGET_ID=str(b), LINK_COST="0.0"
                )
            ET.SubElement(filtered, "TrackID", TRACK_ID=str(track_id))
        settings = ET.SubElement(root, "Settings")
        ET.SubElement(
            settings,
            "ImageData",
            filename="",
            folder="",
            width=str(width),
            height=str(height),
            nslices="1",
            nframes=str(n_frames),
            pixelwidth=repr(px),
            pixelheight=repr(px),
            voxeldepth="1.0",
            timeinterval=repr(dt),
        )
        ET.indent(root)
        return ET.tostring(root, encoding="UTF-8", xml_declaration=True) + b"\n"


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
            written.append(_rel(out_dir, chunk))
            write_json(group / "0" / ".zarray", self._zarray(shape, chunks, data.dtype), indent=2)
            attrs = self._multiscales(name, axes, scale)
            if group != root:
                attrs["image-label"] = {"version": "0.4", "source": {"image": "../../"}}
            write_json(group / ".zattrs", attrs, indent=2)
            write_json(group / ".zgroup", {"zarr_format": 2}, indent=2)
        write_json(root / "labels" / ".zgroup", {"zarr_format": 2}, indent=2)
        write_json(root / "labels" / ".zattrs", {"labels": ["cells", "semantic"]}, indent=2)
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
