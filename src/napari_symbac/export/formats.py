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

    def remember(self, item: ExportItem) -> None:
        """Called with every item of a unit in order, written or not (resumed runs).

        Writers whose items depend on the previous frame (DeLTA tracking) keep it.
        """

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
    """DeLTA 2.x training sets, segmentation and (for time series) tracking.

    Segmentation, as ``delta.data.trainGenerator_seg(batch, img, seg, wei, ...)`` reads
    it: ``delta/{split}/{img,seg,wei}/{name}.png`` with ``img`` the 16-bit image, ``seg``
    an 8-bit mask (255 in cells, touching cells separated by background) and ``wei`` the
    U-Net border weight map (:func:`~napari_symbac.export.weights.segmentation_weights`,
    16-bit, ``100 * w``).

    Tracking, for every frame ``t >= 1`` of a time series and every cell ``c`` of frame
    ``t - 1``, as ``delta.data.trainGenerator_track(batch, img, seg, previmg, segall,
    mot_dau, wei, ...)`` reads it: ``delta/{split}/tracking/{img,seg,previmg,segall,
    mot_dau,wei}/{name}_cell{c}.png`` with ``img`` frame ``t``, ``previmg`` frame
    ``t - 1``, ``seg`` the seed (cell ``c`` in frame ``t - 1``), ``segall`` every cell
    of frame ``t``, ``mot_dau`` cell ``c`` and the daughters it divided into in frame
    ``t`` (empty if it left the trench) and ``wei`` the tracking weight map
    (:func:`~napari_symbac.export.weights.tracking_weights`).
    """

    name = "delta"

    def __init__(self) -> None:
        self._previous: ExportItem | None = None

    def remember(self, item: ExportItem) -> None:
        self._previous = item

    def write_item(self, out_dir: Path, item: ExportItem) -> list[str]:
        from napari_symbac.export.weights import segmentation_weights, to_weight_png

        base = out_dir / self.name / item.split
        paths = [base / d / f"{item.name}.png" for d in ("img", "seg", "wei")]
        write_png(paths[0], item.image_uint16())
        write_png(paths[1], (item.semantic * 255).astype(np.uint8))
        write_png(paths[2], to_weight_png(segmentation_weights(item.labels * item.semantic)))
        paths += self._write_tracking(base / "tracking", item)
        return [_rel(out_dir, p) for p in paths]

    def _write_tracking(self, base: Path, item: ExportItem) -> list[Path]:
        from napari_symbac.export.weights import to_weight_png, tracking_weights

        previous = self._previous
        if not (
            item.is_timeseries
            and item.frame
            and previous is not None
            and previous.series == item.series
            and previous.frame == item.frame - 1
        ):
            return []
        separated = item.labels * item.semantic
        daughters: dict[int, list[int]] = defaultdict(list)
        before = set(np.unique(previous.labels).tolist())
        for cell in np.unique(item.labels):
            parent = int(item.parents.get(int(cell), 0))
            if cell and int(cell) not in before and parent:
                daughters[parent].append(int(cell))
        width = max(6, len(str(item.max_label)))
        all_cells = (item.semantic * 255).astype(np.uint8)
        image, previous_image = item.image_uint16(), previous.image_uint16()
        paths = []
        for cell in np.unique(previous.labels):
            if not cell:
                continue
            track = np.isin(separated, [int(cell), *daughters.get(int(cell), [])])
            name = f"{item.name}_cell{int(cell):0{width}d}.png"
            files = {
                "img": image,
                "seg": ((previous.labels == cell) * 255).astype(np.uint8),
                "previmg": previous_image,
                "segall": all_cells,
                "mot_dau": (track * 255).astype(np.uint8),
                "wei": to_weight_png(tracking_weights(track, separated > 0)),
            }
            for folder, array in files.items():
                paths.append(base / folder / name)
                write_png(paths[-1], array)
        return paths


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
    first frame, last frame, parent label or 0). ``SS`` numbers the series of each split
    from 01 (:attr:`ExportItem.sequence`), as the CTC tools expect; frames have at least
    three digits.
    """

    name = "ctc"
    timeseries_only = True

    def _dirs(self, out_dir: Path, split: str, sequence: int) -> tuple[Path, Path]:
        seq = f"{sequence + 1:02d}"
        base = out_dir / self.name / split
        return base / seq, base / f"{seq}_GT"

    def write_item(self, out_dir: Path, item: ExportItem) -> list[str]:
        self._check(item)
        images, gt = self._dirs(out_dir, item.split, item.sequence)
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
        for (split, _series), group in _series_groups(records).items():
            lines = [f"{cell} {b} {e} {p}" for cell, (b, e, p) in _tracks(group).items()]
            sequence = int(group[0].get("sequence", _series))
            path = self._dirs(out_dir, split, sequence)[1] / "TRA" / "man_track.txt"
            write_text(path, "\n".join(lines) + ("\n" if lines else ""))
            written.append(_rel(out_dir, path))
        return written


#: TrackMate feature declarations: key -> (name, short name, dimension, is integer).
_TRACKMATE_FEATURES = {
    "SpotFeatures": {
        "QUALITY": ("Quality", "Quality", "QUALITY", False),
        "POSITION_X": ("X", "X", "POSITION", False),
        "POSITION_Y": ("Y", "Y", "POSITION", False),
        "POSITION_Z": ("Z", "Z", "POSITION", False),
        "POSITION_T": ("T", "T", "TIME", False),
        "FRAME": ("Frame", "Frame", "NONE", True),
        "RADIUS": ("Radius", "R", "LENGTH", False),
        "VISIBILITY": ("Visibility", "Visibility", "NONE", True),
        "AREA": ("Area", "Area", "AREA", False),
    },
    "EdgeFeatures": {
        "SPOT_SOURCE_ID": ("Source spot ID", "Source ID", "NONE", True),
        "SPOT_TARGET_ID": ("Target spot ID", "Target ID", "NONE", True),
        "LINK_COST": ("Edge cost", "Cost", "COST", False),
    },
    "TrackFeatures": {
        "TRACK_INDEX": ("Track index", "Index", "NONE", True),
        "TRACK_ID": ("Track ID", "ID", "NONE", True),
        "NUMBER_SPOTS": ("Number of spots in track", "N spots", "NONE", True),
        "NUMBER_SPLITS": ("Number of split events", "N splits", "NONE", True),
    },
}


def _number(value: float) -> str:
    return repr(round(float(value), 6))


class TrackMateWriter(FormatWriter):
    """TrackMate XML, one file per series, beside the image stack it annotates.

    ``trackmate/{split}/s{SSSS}.xml`` and ``trackmate/{split}/s{SSSS}.tif`` (the series
    as one ``(T, Y, X)`` uint16 ImageJ stack with pixel size and frame interval, which
    the XML's ``ImageData`` names; the frames are also kept one per file in
    ``s{SSSS}_frames/`` so that an interrupted export resumes). Each cell in each frame
    is a spot at its centroid (micrometres and minutes) named ``cell_{id}``, with
    ``RADIUS`` and ``AREA`` from its mask; consecutive frames of a cell are linked, and
    a mother's last spot to each daughter's first, so a TrackMate track is a lineage
    tree. The file follows TrackMate 7's layout: ``Model`` with ``FeatureDeclarations``,
    ``AllSpots``, ``AllTracks``, ``FilteredTracks``; ``Settings`` with ``ImageData``,
    ``BasicSettings``, the manual detector and tracker, ``InitialSpotFilter``, the
    (empty) spot and track filter collections and ``AnalyzerCollection``.
    """

    name = "trackmate"
    timeseries_only = True

    @staticmethod
    def _stem(series: int) -> str:
        return f"s{series:04d}"

    def write_item(self, out_dir: Path, item: ExportItem) -> list[str]:
        self._check(item)
        width = max(4, len(str(max(int(item.n_frames or 1) - 1, 0))))
        folder = out_dir / self.name / item.split / f"{self._stem(item.series)}_frames"
        path = folder / f"t{item.frame:0{width}d}.tif"
        write_tiff(path, item.image_uint16(), pixel_size_um=item.pixel_size_um)
        return [_rel(out_dir, path)]

    def finalize(self, out_dir: Path, records: Sequence[Record]) -> list[str]:
        import tifffile

        written = []
        for (split, series), group in _series_groups(records).items():
            base = out_dir / self.name / split
            stem = self._stem(series)
            frames = [
                next(f for f in record["files"][self.name] if f"/{stem}_frames/" in f)
                for record in group
            ]
            stack = np.stack([tifffile.imread(out_dir / f) for f in frames])
            image = base / f"{stem}.tif"
            write_tiff(
                image,
                stack,
                pixel_size_um=float(group[0].get("pixel_size_um", 1.0)),
                frame_interval_min=float(group[0].get("frame_interval_min", 1.0)),
            )
            xml = base / f"{stem}.xml"
            write_bytes(xml, self._xml(group, image.name))
            written += [_rel(out_dir, image), _rel(out_dir, xml)]
        return written

    @staticmethod
    def _xml(group: Sequence[Record], image_name: str) -> bytes:
        px = float(group[0].get("pixel_size_um", 1.0))
        dt = float(group[0].get("frame_interval_min", 1.0))
        height, width = group[0]["shape"]
        n_frames = int(group[0].get("n_frames") or len(group))
        spot_of: dict[tuple[int, int], int] = {}
        root = ET.Element("TrackMate", version="7.11.1")
        ET.SubElement(root, "Log").text = "Ground truth written by napari-symbac."
        model = ET.SubElement(root, "Model", spatialunits="µm", timeunits="min")
        declarations = ET.SubElement(model, "FeatureDeclarations")
        for kind, features in _TRACKMATE_FEATURES.items():
            element = ET.SubElement(declarations, kind)
            for key, (name, short, dimension, is_int) in features.items():
                ET.SubElement(
                    element,
                    "Feature",
                    feature=key,
                    name=name,
                    shortname=short,
                    dimension=dimension,
                    isint=str(is_int).lower(),
                )
        all_spots = ET.SubElement(model, "AllSpots", nspots="0")
        n_spots = 0
        radius_max = 0.0
        for record in group:
            frame = int(record["frame"])
            in_frame = ET.SubElement(all_spots, "SpotsInFrame", frame=str(frame))
            for cell, _parent, y, x, area in record["objects"]:
                spot_id = n_spots
                n_spots += 1
                spot_of[(cell, frame)] = spot_id
                radius = float(np.sqrt(area / np.pi)) * px
                radius_max = max(radius_max, radius)
                ET.SubElement(
                    in_frame,
                    "Spot",
                    ID=str(spot_id),
                    name=f"cell_{cell}",
                    QUALITY="1.0",
                    POSITION_X=_number(x * px),
                    POSITION_Y=_number(y * px),
                    POSITION_Z="0.0",
                    POSITION_T=_number(frame * dt),
                    FRAME=str(frame),
                    RADIUS=_number(radius),
                    VISIBILITY="1",
                    AREA=_number(area * px * px),
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
            sources = [a for a, _ in track_edges]
            track = ET.SubElement(
                all_tracks,
                "Track",
                name=f"Track_{track_id}",
                TRACK_INDEX=str(track_id),
                TRACK_ID=str(track_id),
                NUMBER_SPOTS=str(len({s for e in track_edges for s in e})),
                NUMBER_SPLITS=str(sum(1 for s in set(sources) if sources.count(s) > 1)),
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
            # an empty folder is the folder of the XML file, so the dataset can move
            filename=image_name,
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
        ET.SubElement(
            settings,
            "BasicSettings",
            xstart="0",
            xend=str(width - 1),
            ystart="0",
            yend=str(height - 1),
            zstart="0",
            zend="0",
            tstart="0",
            tend=str(n_frames - 1),
        )
        ET.SubElement(
            settings,
            "DetectorSettings",
            DETECTOR_NAME="MANUAL_DETECTOR",
            RADIUS=_number(radius_max or px),
        )
        ET.SubElement(settings, "InitialSpotFilter", feature="QUALITY", value="0.0", isabove="true")
        ET.SubElement(settings, "SpotFilterCollection")
        ET.SubElement(settings, "TrackerSettings", TRACKER_NAME="MANUAL_TRACKER")
        ET.SubElement(settings, "TrackFilterCollection")
        analyzers = ET.SubElement(settings, "AnalyzerCollection")
        for kind in ("SpotAnalyzers", "EdgeAnalyzers", "TrackAnalyzers"):
            ET.SubElement(analyzers, kind)
        ET.SubElement(root, "GUIState", state="ConfigureViews")
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
