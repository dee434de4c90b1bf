"""The manifest of a dataset: how it was made, and which items are finished.

Layout under the output folder::

    manifest.json              dataset header: settings, seed, versions, status, and (once
                               complete) the dataset-level files of each format and
                               every item's entry
    manifest_items/NAME.json   one entry per finished item: split, parameters drawn, files,
                               and a per-cell summary (id, parent, centroid, area)

An item's entry is written last, after all of its files, each file atomically. An item is
finished exactly when its entry exists and names files that all exist, so re-running an
export skips finished items and (re)writes the others.
"""

from __future__ import annotations

import json
import math
import os
import platform
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from napari_symbac.export.atomic import (
    ExportError,
    a_few,
    explain_os_error,
    visible_entries,
    write_json,
    write_text,
)
from napari_symbac.export.formats import FormatWriter
from napari_symbac.export.item import ExportItem, item_objects

__all__ = [
    "ITEMS_DIR",
    "MANIFEST",
    "UNFINISHED",
    "check_manifest",
    "check_or_start_manifest",
    "finish_manifest",
    "finished_items",
    "read_entries",
    "settings_differences",
    "write_item",
]

MANIFEST = "manifest.json"
ITEMS_DIR = "manifest_items"
MANIFEST_VERSION = 1
#: A note beside the manifest while an export is unfinished, removed as it completes
#: (found as a user: an interrupted export's omnipose/train held 6 complete pairs that
#: Cellpose would train on, and only manifest.json's "status" said it was not the
#: dataset asked for).
UNFINISHED = "UNFINISHED.txt"
UNFINISHED_TEXT = (
    "This export is unfinished: the items written so far are whole, but the dataset is "
    "not the one asked for (manifest.json: \"status\": \"incomplete\"; dataset-level files "
    "such as COCO's annotations or the Cell Tracking Challenge's man_track.txt are written "
    "at the end). Run the same export into this folder again to finish it (it resumes "
    "where it stopped), or delete the folder. This file is removed when the export "
    "completes.\n"
)


def _versions() -> dict[str, str]:
    from napari_symbac import __version__

    return {
        "napari_symbac": __version__,
        "numpy": np.__version__,
        "python": platform.python_version(),
    }


def write_item(out_dir: Path, item: ExportItem, writers: Sequence[FormatWriter]) -> dict[str, Any]:
    """Write one item in every format, then its manifest entry; return the entry."""
    files: dict[str, list[str]] = {}
    for writer in writers:
        files[writer.name] = writer.write_item(out_dir, item)
    entry = {
        "name": item.name,
        "index": int(item.index),
        "split": item.split,
        "series": item.series,
        "sequence": item.sequence,
        "frame": item.frame,
        "n_frames": item.n_frames,
        "shape": [int(s) for s in item.image.shape],
        "label_dtype": item.label_dtype.name,
        "pixel_size_um": float(item.pixel_size_um),
        "frame_interval_min": float(item.frame_interval_min),
        "params": dict(item.params),
        "files": files,
        "objects": item_objects(item),
    }
    if item.contrast_to_noise:
        entry["contrast_to_noise"] = {
            str(cell): round(value, 3) if math.isfinite(value) else None
            for cell, value in sorted(item.contrast_to_noise.items())
        }
        entry["faint_cells"] = [int(c) for c in item.faint_cells]
    # not flushed to the disk (fsync): like the item's files it survives a crash or a
    # kill; an entry that a power cut left empty does not parse, so the item is redone
    write_json(out_dir / ITEMS_DIR / f"{item.name}.json", entry, sync=False)
    return entry


def _entry_if_finished(out_dir: Path, name: str) -> dict[str, Any] | None:
    path = out_dir / ITEMS_DIR / f"{name}.json"
    try:
        entry = json.loads(path.read_text("utf-8"))
    except (OSError, json.JSONDecodeError):
        return None
    files = [f for paths in entry.get("files", {}).values() for f in paths]
    if not all((out_dir / f).is_file() for f in files):
        return None
    return entry


def finished_items(out_dir: Path, names: Iterable[str] | None = None) -> dict[str, dict[str, Any]]:
    """Entries of the finished items among ``names`` (all entries in the folder if ``None``)."""
    out_dir = Path(out_dir)
    folder = out_dir / ITEMS_DIR
    if not folder.is_dir():
        return {}
    if names is None:
        names = sorted(p.stem for p in folder.glob("*.json") if not p.name.startswith("."))
        existing = None
    else:
        existing = {p.name for p in os.scandir(folder)}
    done = {}
    for name in names:
        if existing is not None and f"{name}.json" not in existing:
            continue
        entry = _entry_if_finished(out_dir, name)
        if entry is not None:
            done[name] = entry
    return done


def read_entries(out_dir: Path, names: Iterable[str] | None = None) -> list[dict[str, Any]]:
    """Finished entries sorted by item index."""
    return sorted(finished_items(out_dir, names).values(), key=lambda e: (e["index"], e["name"]))


def check_dataset_folder(out_dir: str | os.PathLike) -> None:
    """Refuse a folder that holds other files and no :data:`MANIFEST`: the dataset's
    folders would be written among the user's files. A missing or empty folder, or one
    holding an export (resumed or refused by :func:`check_manifest`), passes;
    hidden files (``.DS_Store``, a lock) are no objection.

    Raises
    ------
    ExportError
        Naming a few of the files and the fix.
    """
    out_dir = Path(out_dir)
    if not out_dir.is_dir() or (out_dir / MANIFEST).is_file():
        return
    others = [entry.name for entry in visible_entries(out_dir)]
    if others:
        raise ExportError(
            f"{out_dir} holds other files ({a_few(others)}) and no {MANIFEST}: the dataset's "
            "folders would be written among them; export to an empty or new folder",
            out_dir / MANIFEST,
        )


def settings_differences(old: Any, new: Any, most: int = 3) -> str:
    """The settings that differ between two manifests' records, as "settings.n_items: 4
    there, 3 here" (at most ``most``, then how many more). Found as a user: `export
    --config calibrated/export_settings.yaml --out calibrated/dataset --n-items 3` said
    only "different settings or formats", leaving the user to compare two JSON files to
    find that it was the number of items."""

    def walk(a: Any, b: Any, where: str) -> list[str]:
        if isinstance(a, dict) and isinstance(b, dict):
            return [
                line
                for key in sorted(set(a) | set(b), key=str)
                for line in walk(a.get(key), b.get(key), f"{where}.{key}" if where else key)
            ]
        if a == b:
            return []
        return [f"{where}: {json.dumps(a)} there, {json.dumps(b)} here"]

    lines = walk(old, new, "")
    more = f", and {len(lines) - most} more" if len(lines) > most else ""
    return "; ".join(lines[:most]) + more


def _document(header: Mapping[str, Any]) -> dict[str, Any]:
    """The manifest an export with ``header`` starts, in plain JSON types (to compare)."""
    document = {
        "manifest_version": MANIFEST_VERSION,
        "generator": "napari-symbac",
        "versions": _versions(),
        **header,
        "status": "incomplete",
    }
    return json.loads(json.dumps(document))


def check_manifest(
    out_dir: str | os.PathLike, header: Mapping[str, Any], *, in_dock: bool = False
) -> dict[str, Any] | None:
    """Check, writing nothing, that an export with ``header`` may be written into
    ``out_dir``: the folder is missing or empty, or holds the same export (a resume).
    ``in_dock``: the fixes are said in the Export dock's words, not the command's.

    Returns
    -------
    dict or None
        The folder's manifest when it holds the same export, else ``None``.

    Raises
    ------
    ExportError
        If the folder holds an export made with other settings, another render backend
        or another version of napari-symbac (items would not match), or holds other
        files and no manifest; the message names the difference and the fix.
    """
    return _check_against(Path(out_dir), _document(header), in_dock=in_dock)


def _check_against(
    out_dir: Path, document: Mapping[str, Any], *, in_dock: bool = False
) -> dict[str, Any] | None:
    """:func:`check_manifest` of the manifest ``document`` an export would start."""
    path = out_dir / MANIFEST
    check_dataset_folder(out_dir)
    if path.is_file():
        try:
            old = json.loads(path.read_text("utf-8"))
        except (OSError, json.JSONDecodeError) as err:
            raise ExportError(
                f"{path} exists but cannot be read ({err}): delete it or export to another folder",
                path,
            ) from err
        keys = ("settings", "formats", "kind")
        if any(old.get(k) != document.get(k) for k in keys):
            # the settings hold the formats and kind too: said once
            same = old.get("settings") == document.get("settings")
            changed = (
                settings_differences(
                    {k: old.get(k) for k in keys}, {k: document.get(k) for k in keys}
                )
                if same
                else settings_differences(old.get("settings"), document.get("settings"))
            )
            resume = (
                "choose the settings it was made with (its manifest.json records them)"
                if in_dock
                else "use its own settings, which its manifest records "
                f"(`napari-symbac export --config {path} --out {out_dir}`)"
            )  # found as a user: the dock named the command, and fields it does not show
            raise ExportError(
                f"{out_dir} already holds an export made with different settings or formats "
                f"({changed}); to resume it {resume}, or export to a new folder",
                path,
            )
        if old.get("render_backend", "scipy") != document.get("render_backend", "scipy"):
            option = "'render on'" if in_dock else "--backend"
            raise ExportError(
                f"{out_dir} was rendered with the {old.get('render_backend', 'scipy')} backend, "
                f"this run uses {document.get('render_backend', 'scipy')} (another noise "
                f"stream): resume it with {option} as recorded in manifest.json, or export "
                "to a new folder",
                path,
            )
        if old.get("versions", {}).get("napari_symbac") != document["versions"]["napari_symbac"]:
            raise ExportError(
                f"{out_dir} was exported by napari-symbac "
                f"{old.get('versions', {}).get('napari_symbac')}, this is "
                f"{document['versions']['napari_symbac']}: items would differ, so export to "
                "a new folder (or install the version that made it to resume)",
                path,
            )
        return old
    return None


def check_or_start_manifest(out_dir: Path, header: Mapping[str, Any]) -> dict[str, Any]:
    """Start ``manifest.json`` in ``out_dir``, or check that it describes the same export.

    Raises
    ------
    ExportError
        As :func:`check_manifest`, or if the folder cannot be written.
    """
    out_dir = Path(out_dir)
    path = out_dir / MANIFEST
    document = _document(header)
    old = _check_against(out_dir, document)
    if old is not None and old.get("status") == "complete":
        return old
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise explain_os_error(err, out_dir) from err
    write_json(path, document, indent=2)
    write_text(out_dir / UNFINISHED, UNFINISHED_TEXT)
    return document


def finish_manifest(
    out_dir: Path,
    entries: Sequence[Mapping[str, Any]],
    files: Mapping[str, Sequence[str]] | None = None,
) -> Path:
    """Mark the manifest complete and list every item's entry and dataset-level file.

    ``files`` maps a format to the dataset-level files it wrote (COCO JSON,
    ``man_track.txt``, TrackMate XML and image stacks), relative to ``out_dir``; they
    are recorded under ``"files"``, so the manifest names every file of the dataset.
    """
    path = Path(out_dir) / MANIFEST
    document = json.loads(path.read_text("utf-8"))
    document["status"] = "complete"
    document["n_items"] = len(entries)
    document["files"] = {name: list(paths) for name, paths in (files or {}).items()}
    document["items"] = list(entries)
    write_json(path, document, indent=1)
    (Path(out_dir) / UNFINISHED).unlink(missing_ok=True)
    return path
