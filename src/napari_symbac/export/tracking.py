"""Tracking ground truth: Cell Tracking Challenge folders and TrackMate XML.

Both are assembled at the end of an export from the manifest entries of a series
(cell ids, parents, centroids and areas), so the masks are never read back.
"""

from __future__ import annotations

import itertools
import xml.etree.ElementTree as ET
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from napari_symbac.export.atomic import write_bytes, write_text, write_tiff
from napari_symbac.export.item import ExportItem
from napari_symbac.export.writer import FormatWriter, Record, relative

__all__ = ["CtcWriter", "TrackMateWriter"]


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
        return [relative(out_dir, p) for p in paths]

    def finalize(self, out_dir: Path, records: Sequence[Record]) -> list[str]:
        written = []
        for (split, _series), group in _series_groups(records).items():
            lines = [f"{cell} {b} {e} {p}" for cell, (b, e, p) in _tracks(group).items()]
            sequence = int(group[0].get("sequence", _series))
            path = self._dirs(out_dir, split, sequence)[1] / "TRA" / "man_track.txt"
            write_text(path, "\n".join(lines) + ("\n" if lines else ""))
            written.append(relative(out_dir, path))
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
        return [relative(out_dir, path)]

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
            written += [relative(out_dir, image), relative(out_dir, xml)]
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
