"""One export at a time into a folder: a lock file that names the export holding it.

Found as a user: two exports into one folder at once (a command line beside the Export
dock, or one run twice) each computed every item, racing on the same files. The second
is refused, naming the first and the fix. A lock left by an export that was killed is
taken over when its process is gone from this machine; one from another machine is
named, with the way to remove it.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import time
from collections.abc import Iterator
from pathlib import Path

from napari_symbac.export.atomic import ExportError, explain_os_error

__all__ = ["LOCK", "export_lock"]

#: The lock's file name in the dataset folder (hidden: no objection to the folder).
LOCK = ".napari-symbac-export.lock"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


def _holder(path: Path) -> dict:
    with contextlib.suppress(OSError, ValueError):
        holder = json.loads(path.read_text("utf-8"))
        if isinstance(holder, dict):
            return holder
    return {}


def _stale(holder: dict) -> bool:
    """Whether the export that wrote ``holder`` is gone: its process is not running on
    this machine (an unreadable lock, being written or left half-written, is not)."""
    pid = holder.get("pid")
    if holder.get("host") != socket.gethostname() or not isinstance(pid, int):
        return False
    return pid != os.getpid() and not _alive(pid)


@contextlib.contextmanager
def export_lock(out_dir: Path) -> Iterator[None]:
    """Hold ``out_dir``'s export lock while the block runs (``out_dir`` is created if
    missing).

    Raises
    ------
    ExportError
        If another export, running or not known to be gone, holds it (the message names
        its process, machine and start, and the fix), or the folder cannot be written.
    """
    path = Path(out_dir) / LOCK
    mine = {
        "host": socket.gethostname(),
        "pid": os.getpid(),
        "started": time.strftime("%Y-%m-%d %H:%M:%S"),
    }
    for _ in range(2):
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            descriptor = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            holder = _holder(path)
            if _stale(holder):
                path.unlink(missing_ok=True)
                continue
            raise ExportError(_refusal(out_dir, path, holder), path) from None
        except OSError as err:
            raise explain_os_error(err, out_dir) from err
        with os.fdopen(descriptor, "w", encoding="utf-8") as file:
            json.dump(mine, file)
        break
    else:  # pragma: no cover - another export took it between our removal and retry
        raise ExportError(_refusal(out_dir, path, _holder(path)), path)
    try:
        yield
    finally:
        if _holder(path).get("pid") == os.getpid():
            path.unlink(missing_ok=True)


def _refusal(out_dir: Path, path: Path, holder: dict) -> str:
    who = (
        f"process {holder.get('pid')} on {holder.get('host')}, started {holder.get('started')}"
        if holder
        else "its lock is being written"
    )
    return (
        f"another export is writing into {out_dir} ({who}): wait for it to finish, or export "
        f"to another folder; if no export is running there (one stopped on another machine), "
        f"delete {path}"
    )
