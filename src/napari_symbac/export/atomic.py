"""Atomic file writes and clear messages for disk errors.

Every file of a dataset is first written under a temporary name in its final folder and
then moved into place with :func:`os.replace`, which is atomic on POSIX and Windows for
two paths on the same file system. A crash, a kill or a cancel therefore never leaves a
half-written image or mask under its final name: at worst a hidden temporary file
(``.NAME.tmp-PID-RANDOM.EXT``), which :func:`remove_stale_temporaries` sweeps away when
the export is run again.
"""

from __future__ import annotations

import errno
import json
import os
import re
import shutil
import tempfile
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "EXPORT_RESUMES",
    "TIFF_KINDS",
    "TIFF_KIND_KEY",
    "ExportError",
    "a_few",
    "atomic_path",
    "check_output_folder",
    "earlier_run",
    "explain_os_error",
    "remove_earlier_run",
    "remove_stale_temporaries",
    "staging_folder",
    "tiff_metadata",
    "visible_entries",
    "write_bytes",
    "write_json",
    "write_png",
    "write_text",
    "write_tiff",
]

_TEMP_RE = re.compile(r"^\..+\.tmp-\d+-[0-9a-f]{8}(\.[A-Za-z0-9]+)?$")


#: What an export adds to a disk error's advice (:func:`explain_os_error`).
EXPORT_RESUMES = "the export keeps its finished items and completes the rest"


class ExportError(RuntimeError):
    """An export stopped for a reason the user can fix (disk full, no permission, ...).

    Attributes
    ----------
    path
        The file or folder the export was writing when it stopped (``None`` if unknown).
    errno
        The operating-system error number, if the cause was an :class:`OSError`.
    """

    def __init__(
        self, message: str, path: str | os.PathLike | None = None, errno_: int | None = None
    ):
        super().__init__(message)
        self.path = None if path is None else str(path)
        self.errno = errno_

    def __reduce__(self):  # keep path and errno when sent back from a dask worker
        return (type(self), (str(self), self.path, self.errno))


def explain_os_error(err: OSError, path: str | os.PathLike | None = None) -> ExportError:
    """Turn an :class:`OSError` raised while writing into an :class:`ExportError`.

    The message names the path and says how to fix the problem, then to run the step
    (a command, a widget's button) again: every step that writes uses these writers;
    an export adds that it resumes (:data:`EXPORT_RESUMES`).
    """
    where = str(path if path is not None else (err.filename or "the output folder"))
    again = "then run it again"
    if err.errno in (errno.ENOSPC, errno.EDQUOT) or is_short_write(err):
        message = (
            f"the disk is full (no space left on device) while writing {where}: free some "
            f"space on that disk or choose an output folder on another disk, {again}"
        )
        return ExportError(message, where, errno.ENOSPC if err.errno is None else err.errno)
    elif err.errno in (errno.EACCES, errno.EPERM) or isinstance(err, PermissionError):
        message = (
            f"permission denied while writing {where}: choose an output folder you can "
            f"write to, or give yourself write permission on it (e.g. chmod u+w), {again}"
        )
    elif err.errno == errno.EROFS:
        message = (
            f"{where} is on a read-only file system: choose an output folder on a writable "
            f"disk, {again}"
        )
    else:
        message = f"could not write {where}: {err.strerror or err}; fix the cause, {again}"
    return ExportError(message, where, err.errno)


def is_short_write(err: OSError) -> bool:
    """Whether ``err`` is numpy's short write ("11776 requested and 7824 written", no
    errno), which on a local disk means it is full (found as a user: a full disk during
    a TIFF export said "could not write ...: 11776 requested and 7824 written")."""
    short = re.fullmatch(r"\d+ requested and \d+ written", str(err))
    return err.errno is None and short is not None


def atomic_path(path: Path) -> Path:
    """A unique temporary path beside ``path`` with the same extension."""
    return path.with_name(f".{path.stem}.tmp-{os.getpid()}-{uuid.uuid4().hex[:8]}{path.suffix}")


@contextmanager
def _replacing(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path; on success move it to ``path``, on failure delete it."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise explain_os_error(err, path.parent) from err
    tmp = atomic_path(path)
    try:
        yield tmp
        os.replace(tmp, path)
    except OSError as err:
        _unlink_quietly(tmp)
        raise explain_os_error(err, path) from err
    except BaseException:
        _unlink_quietly(tmp)
        raise


def _unlink_quietly(path: Path) -> None:
    with suppress(OSError):
        path.unlink()


def _atomic(path: str | os.PathLike, write: Callable[[Path], Any]) -> Path:
    with _replacing(path) as tmp:
        write(tmp)
    return Path(path)


def write_bytes(path: str | os.PathLike, data: bytes, *, sync: bool = True) -> Path:
    """Write ``data`` to ``path`` atomically.

    ``sync=True`` also flushes the file to the disk (``fsync``) before it takes its
    name, so it survives a power cut; without it, it survives a crash or kill of the
    process (what the atomic rename guarantees) like the images and masks.
    """

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as handle:
            handle.write(data)
            if sync:
                handle.flush()
                os.fsync(handle.fileno())

    return _atomic(path, write)


def write_text(path: str | os.PathLike, text: str, *, sync: bool = True) -> Path:
    """Write UTF-8 ``text`` to ``path`` atomically (``sync``: see :func:`write_bytes`)."""
    return write_bytes(path, text.encode("utf-8"), sync=sync)


def write_json(
    path: str | os.PathLike, data: Any, *, indent: int | None = None, sync: bool = True
) -> Path:
    """Write ``data`` as JSON (keys in insertion order, no NaN) to ``path`` atomically."""
    return write_text(path, json.dumps(data, indent=indent, allow_nan=False) + "\n", sync=sync)


#: What a TIFF holds, recorded in its metadata under :data:`TIFF_KIND_KEY`.
TIFF_KINDS = ("image", "labels", "semantic")
#: Metadata key (ImageJ description or tifffile JSON description) naming the kind.
TIFF_KIND_KEY = "napari_symbac"
_IMAGEJ_DTYPES = (np.uint8, np.uint16, np.float32)


def tiff_metadata(
    array: np.ndarray,
    *,
    pixel_size_um: float | None = None,
    kind: str = "image",
    frame_interval_min: float | None = None,
) -> dict[str, Any]:
    """Keyword arguments of :func:`tifffile.imwrite` that record pixel size and kind.

    uint8, uint16 and float32 arrays are written as ImageJ hyperstacks (``resolution`` in
    pixels per micrometre, ``unit=um``, ``finterval`` in seconds for ``(T, Y, X)``
    stacks), which ImageJ/Fiji, tifffile, napari and this plugin's reader all read.
    Wider label images (uint32), which ImageJ cannot hold, carry the resolution in
    pixels per centimetre (TIFF ``ResolutionUnit`` 3) and a JSON description with their
    axes. Both
    name the kind (``image``, ``labels``, ``semantic``) under :data:`TIFF_KIND_KEY`,
    so the reader reopens masks as napari Labels layers.
    """
    if kind not in TIFF_KINDS:
        raise ValueError(f"TIFF kind must be one of {TIFF_KINDS}, got {kind!r}")
    if pixel_size_um is not None and not (
        isinstance(pixel_size_um, (int, float)) and np.isfinite(pixel_size_um) and pixel_size_um > 0
    ):
        raise ValueError(f"pixel_size_um must be a positive number, got {pixel_size_um!r}")
    axes = "TYX"[-array.ndim :] if array.ndim <= 3 else None
    if array.dtype in _IMAGEJ_DTYPES and axes is not None:
        metadata: dict[str, Any] = {"axes": axes, TIFF_KIND_KEY: kind}
        kwargs: dict[str, Any] = {"imagej": True, "metadata": metadata}
        if pixel_size_um is not None:
            kwargs["resolution"] = (1 / pixel_size_um, 1 / pixel_size_um)
            metadata["unit"] = "um"
        if frame_interval_min is not None and array.ndim == 3:
            metadata["finterval"] = float(frame_interval_min) * 60.0
        return kwargs
    metadata = {TIFF_KIND_KEY: kind}
    if axes is not None:  # tifffile's JSON description names them: "TYX", not "QYX"
        metadata["axes"] = axes
    kwargs = {"metadata": metadata}
    if pixel_size_um is not None:
        per_cm = 1e4 / pixel_size_um
        kwargs |= {"resolution": (per_cm, per_cm), "resolutionunit": "CENTIMETER"}
        metadata["pixel_size_um"] = float(pixel_size_um)
    return kwargs


def write_tiff(
    path: str | os.PathLike,
    array: np.ndarray,
    *,
    pixel_size_um: float | None = None,
    kind: str = "image",
    frame_interval_min: float | None = None,
    compression: str | None = None,
) -> Path:
    """Write ``array`` as a TIFF atomically (no timestamps: reproducible bytes).

    Pixel size and kind are recorded as :func:`tiff_metadata` describes. A stack of one
    frame, ``(1, Y, X)``, is written as that frame: readers (tifffile, scikit-image,
    napari) give an ImageJ file of one frame back as ``(Y, X)``, and a uint32 label
    image, not an ImageJ file, is now read back so too (found as a user: ``render`` of
    a one-frame simulation wrote images.tif and semantic.tif that read as (512, 512) and
    labels.tif as (1, 512, 512)).
    """
    import tifffile

    array = np.ascontiguousarray(array)
    if array.ndim == 3 and array.shape[0] == 1:
        array = array[0]
    kwargs = tiff_metadata(
        array, pixel_size_um=pixel_size_um, kind=kind, frame_interval_min=frame_interval_min
    )
    if compression is not None:
        kwargs["compression"] = compression
    return _atomic(path, lambda tmp: tifffile.imwrite(tmp, array, **kwargs))


def write_png(path: str | os.PathLike, array: np.ndarray) -> Path:
    """Write a 2-D uint8 or uint16 ``array`` as a greyscale PNG atomically."""
    import imageio.v3 as iio

    array = np.ascontiguousarray(array)
    if array.ndim != 2 or array.dtype not in (np.uint8, np.uint16):
        raise ValueError(
            f"PNG holds 2-D uint8 or uint16 images only, got {array.dtype} {array.shape}: "
            "use the tiff format for wider masks"
        )
    return _atomic(path, lambda tmp: iio.imwrite(tmp, array, extension=".png"))


def remove_stale_temporaries(folder: str | os.PathLike) -> int:
    """Delete temporary files that an interrupted export left under ``folder``.

    Returns the number of files removed. Only names made by :func:`atomic_path` match.
    """
    removed = 0
    folder = Path(folder)
    if not folder.is_dir():
        return 0
    for root, _dirs, files in os.walk(folder):
        for name in files:
            if _TEMP_RE.match(name):
                _unlink_quietly(Path(root) / name)
                removed += 1
    return removed


_STAGING_RE = re.compile(r"^\.(?P<name>.+)\.partial-(?P<pid>\d+)-[A-Za-z0-9_]+$")


def staging_folder(out: str | os.PathLike) -> Path:
    """A new hidden folder beside ``out`` (``.OUT.partial-PID-RANDOM``) in which a
    command makes its outputs before moving them into ``out``.

    Staging folders of ``out`` that a process no longer running left behind (killed:
    found as a user, ``kill -9`` of ``calibrate`` left 43 files, 6.7 MB, which the next
    run ignored) are removed first; those of a running process are left alone.
    """
    out = Path(out).resolve()
    parent = out.parent
    parent.mkdir(parents=True, exist_ok=True)
    for entry in parent.iterdir():
        match = _STAGING_RE.match(entry.name)
        if match and match["name"] == out.name and not _running(int(match["pid"])):
            shutil.rmtree(entry, ignore_errors=True)
    return Path(tempfile.mkdtemp(prefix=f".{out.name}.partial-{os.getpid()}-", dir=parent))


def _running(pid: int) -> bool:
    """Whether a process ``pid`` runs (one of another user's counts as running)."""
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):
        return True
    return True


def check_output_folder(
    path: str | os.PathLike, option: str = "--out", *, staged: bool = False
) -> Path:
    """``path`` as a folder to write into, checked before any work is done.

    Parameters
    ----------
    path
        The folder to write into (created later if missing).
    option
        How messages name it (the command's option, or "the output folder").
    staged
        Whether the command makes its outputs in a hidden folder beside ``path`` first
        (``fit``, ``calibrate``): its parent must then be writable as well.

    Raises
    ------
    ValueError
        If ``path`` is a file, lies inside a file, or it (or the folder it would be made
        in) cannot be written; the message names the path and the fix.
    """
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise ValueError(
            f"{option} {out} is a file, not a folder: give the path of a folder (it is "
            "created if missing), or move the file away"
        )
    for folder in (out, out.resolve().parent) if staged else (out,):
        _check_writable(out, folder, option)
    return out


def earlier_run(out: str | os.PathLike, command: str, owns: Callable[[str], bool]) -> list[Path]:
    """What an earlier run of ``command`` left in ``out``: to be removed when this run's
    files are in, so that none of them is taken for this run's (found as a user: a second
    ``diagnose`` into a folder kept the first one's ``effect_*.png`` of effects it did
    not accept, and ``fit`` into a diagnosis' folder mixed the two). Call it before any
    work.

    Parameters
    ----------
    owns
        Whether a name (of an entry directly in ``out``) is one ``command`` writes.

    Raises
    ------
    ValueError
        If ``out`` holds anything else (hidden files aside), naming a few and the fix.
    """
    out = Path(out)
    if not out.is_dir():
        return []
    entries = visible_entries(out)
    foreign = [e.name for e in entries if not owns(e.name)]
    if foreign:
        raise ValueError(
            f"--out {out} holds files napari-symbac {command} does not write "
            f"({a_few(foreign)}): "
            f"give a new or empty folder, or the folder of an earlier {command} (whose "
            "files are then replaced)"
        )
    return entries


def visible_entries(folder: Path) -> list[Path]:
    """The entries of ``folder``, sorted, hidden ones (``.DS_Store``, a lock) aside."""
    return sorted(e for e in folder.iterdir() if not e.name.startswith("."))


def a_few(names: list[str]) -> str:
    """The first three of ``names`` for a message, ``...`` when there are more."""
    return ", ".join(names[:3]) + (", ..." if len(names) > 3 else "")


def remove_earlier_run(entries: list[Path]) -> None:
    """Remove what :func:`earlier_run` found (files and folders)."""
    for entry in entries:
        if entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry)
        else:
            entry.unlink(missing_ok=True)


def _nearest_existing(path: Path) -> Path:
    """``path`` itself if it exists, else its nearest existing parent."""
    while not path.exists() and path.parent != path:
        path = path.parent
    return path


def _check_writable(out: Path, folder: Path, option: str) -> None:
    """Refuse ``out`` when ``folder`` (``out`` or its parent) cannot be created or written:
    a file in the way, or no permission (probed with a temporary file, so that a read-only
    disk is found whoever runs the command)."""
    existing = _nearest_existing(folder)
    if not existing.is_dir():
        raise ValueError(
            f"{option} {out} cannot be created: {existing} is a file, not a folder: check "
            "that the path is right, or move the file away"
        )
    try:
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError as err:
        if existing == out:
            problem = "is not writable"
        elif out.exists():  # a staged command's parent
            problem = (
                f"cannot be written: its outputs are made beside it, in {existing}, which "
                "is not writable"
            )
        else:
            problem = f"cannot be created: {existing} is not writable"
        if err.errno in (errno.EACCES, errno.EPERM):
            fix = (
                "give a folder you can write to, or give yourself write permission on it "
                "(e.g. chmod u+w)"
            )
        else:  # a read-only disk, or no files at all there (/proc, /sys)
            fix = "give a folder on a writable disk"
        raise ValueError(f"{option} {out} {problem} ({err.strerror or err}): {fix}") from None
