"""Save and load a whole simulation in an open, versioned format.

A saved simulation is a folder::

    simulation.json   format name and version, package version, settings (as in
                      settings YAML), fates' names, wall polylines
    frames.npz        per-frame cell states, concatenated: ``offsets`` (n_frames + 1)
                      index the rows of ``ids, x_um, y_um, angle_rad, length_um,
                      width_um`` that belong to each frame
    lineage.npz       ``cell_id, parent_id, birth_frame, end_frame, fate`` (index into
                      the fates' names) and ``curvature`` (n, 3)

Only JSON and numpy's NPZ (no pickles) are used, so any language can read it. The
folder is written to a temporary sibling and renamed into place, so a failed save
never leaves a half-written simulation.
"""

from __future__ import annotations

import itertools
import json
import os
import shutil
import tempfile
import zipfile
from pathlib import Path

import numpy as np

import napari_symbac
from napari_symbac.settings import SimulationSettings, from_dict, to_dict
from napari_symbac.sim.cells import FATES, FrameCells, LineageRecord, Simulation

__all__ = [
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "check_simulation_folder",
    "load_simulation",
    "save_simulation",
]

FORMAT_NAME = "napari-symbac-simulation"
#: Version of the folder layout; readers accept this and every older version.
FORMAT_VERSION = 1
_META = "simulation.json"
_FRAME_FIELDS = ("ids", "x_um", "y_um", "angle_rad", "length_um", "width_um")


def save_simulation(sim: Simulation, directory: str | os.PathLike) -> Path:
    """Write ``sim`` to the folder ``directory`` (created, or replaced if it holds a
    saved simulation).

    Raises
    ------
    OSError
        If the folder cannot be written, or exists and holds something other than a
        saved simulation (it is never overwritten then).
    """
    target = check_simulation_folder(directory)
    parent = target.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
        tmp = _new_folder(parent, f".{target.name}.tmp-")
    except OSError as err:
        raise OSError(
            f"cannot save the simulation to {target}: {parent} is not writable "
            f"({err.strerror}); choose another folder"
        ) from err
    try:
        _write(sim, tmp)
        if target.exists():
            backup = Path(tempfile.mkdtemp(prefix=f".{target.name}.old-", dir=parent))
            backup.rmdir()
            target.rename(backup)
            try:
                tmp.rename(target)
            except OSError:
                backup.rename(target)
                raise
            shutil.rmtree(backup, ignore_errors=True)
        else:
            tmp.rename(target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return target


def check_simulation_folder(directory: str | os.PathLike) -> Path:
    """``directory`` as a folder :func:`save_simulation` may write: missing, empty, or
    holding a saved simulation (replaced). Call it before simulating, so that a long run
    is not thrown away at the end.

    Raises
    ------
    FileExistsError
        If it is a file, or a folder that holds other files and no simulation.
    """
    target = Path(directory).expanduser()
    if target.exists() and not target.is_dir():
        raise FileExistsError(
            f"cannot save the simulation to {target}: it is a file; choose a folder path"
        )
    if target.is_dir() and any(target.iterdir()) and not (target / _META).is_file():
        raise FileExistsError(
            f"cannot save the simulation to {target}: the folder holds other files and no "
            f"{_META}; choose an empty or new folder"
        )
    return target


def _new_folder(parent: Path, prefix: str) -> Path:
    """A new folder in ``parent`` with the mode of any new folder (``0o777`` less the
    umask). ``tempfile.mkdtemp`` makes it ``0o700``, and the saved simulation kept that
    mode after the rename: colleagues on a shared machine could not read it."""
    for n in itertools.count():
        folder = parent / f"{prefix}{os.getpid()}-{n}"
        try:
            folder.mkdir()
        except FileExistsError:
            continue
        return folder
    raise AssertionError("unreachable")


def _write(sim: Simulation, folder: Path) -> None:
    frames = sim.frames
    offsets = np.zeros(len(frames) + 1, dtype=np.int64)
    offsets[1:] = np.cumsum([len(f) for f in frames])
    columns = {
        name: (
            np.concatenate([getattr(f, name) for f in frames])
            if frames
            else np.zeros(0, dtype=np.int64 if name == "ids" else float)
        )
        for name in _FRAME_FIELDS
    }
    np.savez_compressed(folder / "frames.npz", offsets=offsets, **columns)
    records = sorted(sim.lineage.values(), key=lambda r: r.cell_id)
    np.savez_compressed(
        folder / "lineage.npz",
        cell_id=np.array([r.cell_id for r in records], dtype=np.int64),
        parent_id=np.array([r.parent_id for r in records], dtype=np.int64),
        birth_frame=np.array([r.birth_frame for r in records], dtype=np.int64),
        end_frame=np.array([r.end_frame for r in records], dtype=np.int64),
        fate=np.array([FATES.index(r.fate) for r in records], dtype=np.int8),
        curvature=np.array([r.curvature for r in records], dtype=float).reshape(-1, 3),
    )
    meta = {
        "format": FORMAT_NAME,
        "format_version": FORMAT_VERSION,
        "napari_symbac_version": napari_symbac.__version__,
        "n_frames": len(frames),
        "n_cells": len(records),
        "fates": list(FATES),
        "settings": to_dict(sim.settings),
        "walls_um": [np.asarray(w, dtype=float).tolist() for w in sim.walls_um],
    }
    (folder / _META).write_text(json.dumps(meta, indent=2), encoding="utf-8")


def _corrupt(folder: Path, what: str) -> ValueError:
    return ValueError(
        f"{folder} is not a readable saved simulation: {what}. Re-run the simulation "
        "(or restore the folder) and save it again"
    )


def load_simulation(directory: str | os.PathLike) -> Simulation:
    """Read a simulation written by :func:`save_simulation` (any format version up to
    :data:`FORMAT_VERSION`; settings fields added since take their defaults).

    Parameters
    ----------
    directory
        The folder ``napari-symbac simulate --out`` (or :func:`save_simulation`) wrote.

    Raises
    ------
    FileNotFoundError
        If the folder or its ``simulation.json`` does not exist.
    ValueError
        If the folder is corrupt or was written by a newer, incompatible version.
    """
    folder = Path(directory).expanduser()
    meta_path = folder / _META
    if not folder.exists():
        raise FileNotFoundError(
            f"{folder} does not exist: give the folder that `napari-symbac simulate --out` "
            "(or napari_symbac.sim.save_simulation) wrote"
        )
    if not meta_path.is_file():
        raise FileNotFoundError(
            f"{folder} is not a saved simulation: {_META} is missing (save one with "
            "napari_symbac.sim.save_simulation or `napari-symbac simulate`)"
        )
    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise _corrupt(folder, f"{_META} is not valid JSON ({err})") from err
    if not isinstance(meta, dict) or meta.get("format") != FORMAT_NAME:
        raise _corrupt(folder, f"{_META} does not describe a {FORMAT_NAME}")
    version = meta.get("format_version")
    if not isinstance(version, int) or version < 1:
        raise _corrupt(folder, f"format_version {version!r} is not a positive integer")
    if version > FORMAT_VERSION:
        raise ValueError(
            f"{folder} was saved in format_version {version} by napari-symbac "
            f"{meta.get('napari_symbac_version', '?')}; this version reads up to "
            f"{FORMAT_VERSION}: upgrade napari-symbac to load it"
        )
    try:
        settings = from_dict(SimulationSettings, meta["settings"])
    except KeyError as err:
        raise _corrupt(folder, "its settings are missing") from err
    except (TypeError, ValueError) as err:
        raise _corrupt(folder, f"its settings are invalid ({err})") from err
    fates = meta.get("fates", list(FATES))
    try:
        with np.load(folder / "frames.npz", allow_pickle=False) as data:
            offsets = data["offsets"]
            columns = {name: data[name] for name in _FRAME_FIELDS}
        with np.load(folder / "lineage.npz", allow_pickle=False) as data:
            lin = {
                k: data[k]
                for k in ("cell_id", "parent_id", "birth_frame", "end_frame", "fate", "curvature")
            }
    except FileNotFoundError as err:
        raise _corrupt(
            folder, f"{Path(err.filename).name if err.filename else 'a file'} is missing"
        ) from err
    except (OSError, KeyError, ValueError, zipfile.BadZipFile, EOFError) as err:
        # numpy's own words for bytes it cannot read as arrays advise unsafe loading
        # (found as a user: "load it unsafely using allow_pickle=" of a damaged file)
        said = "not arrays of numbers" if "allow_pickle" in str(err) else str(err)
        raise _corrupt(folder, f"an array file is damaged ({said})") from err

    n_frames = settings.n_frames
    total = columns["ids"].size
    if (
        offsets.ndim != 1
        or offsets.size != n_frames + 1
        or offsets[0] != 0
        or offsets[-1] != total
        or np.any(np.diff(offsets) < 0)
    ):
        raise _corrupt(folder, f"frames.npz offsets do not describe {n_frames} frames")
    if any(columns[name].shape != (total,) for name in _FRAME_FIELDS):
        raise _corrupt(folder, "frames.npz columns have different lengths")
    frames = [
        FrameCells(*(columns[name][a:b] for name in _FRAME_FIELDS))
        for a, b in itertools.pairwise(offsets)
    ]
    m = lin["cell_id"].size
    if any(lin[k].shape[:1] != (m,) for k in lin) or lin["curvature"].shape != (m, 3):
        raise _corrupt(folder, "lineage.npz columns have different lengths")
    try:
        lineage = {
            int(c): LineageRecord(
                int(c), int(p), int(b), int(e), fates[int(f)], tuple(float(v) for v in curv)
            )
            for c, p, b, e, f, curv in zip(
                lin["cell_id"],
                lin["parent_id"],
                lin["birth_frame"],
                lin["end_frame"],
                lin["fate"],
                lin["curvature"],
            )
        }
    except (IndexError, TypeError) as err:
        raise _corrupt(folder, "lineage.npz has an unknown fate") from err
    if any(r.fate not in FATES for r in lineage.values()):
        raise _corrupt(folder, "lineage.npz has an unknown fate")
    try:
        walls = tuple(np.asarray(w, dtype=float).reshape(-1, 2) for w in meta.get("walls_um", []))
    except (TypeError, ValueError) as err:
        raise _corrupt(folder, "walls_um is not a list of (x, y) polylines") from err
    return Simulation(settings, frames, lineage, walls)
