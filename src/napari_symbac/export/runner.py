"""Run an export: serially in this process or in parallel through dask.distributed.

Work is split into *units* (an image, or a whole time series) that an
:class:`ItemSource` turns into items. Each unit is a pure function of the dataset
settings and its index, so the order in which units run does not matter: a serial run,
a local cluster and a remote scheduler all write the same bytes.
"""

from __future__ import annotations

import contextlib
import math
import os
import threading
import time
import uuid
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

from napari_symbac.export.atomic import (
    EXPORT_RESUMES,
    ExportError,
    remove_earlier_run,
    remove_stale_temporaries,
)
from napari_symbac.export.cluster import (
    check_workers,
    close_quietly,
    connect_scheduler,
    local_cluster,
    silenced,
    start_workers_ignoring_interrupts,
)
from napari_symbac.export.formats import FormatWriter, get_writer
from napari_symbac.export.item import ExportItem
from napari_symbac.export.lock import export_lock
from napari_symbac.export.manifest import (
    ITEMS_DIR,
    check_or_start_manifest,
    finish_manifest,
    finished_items,
    read_entries,
    write_item,
)

__all__ = [
    "ExportReport",
    "ItemSource",
    "manifest_header",
    "run_export",
    "write_items",
]

Progress = Callable[[int, int], None]
Cancel = Callable[[], bool] | Any  # a callable returning True to stop, or a threading.Event


@runtime_checkable
class ItemSource(Protocol):
    """What an export draws its items from (must pickle, to travel to dask workers)."""

    @property
    def n_units(self) -> int:
        """Number of units of work (images, or time series)."""

    def unit_names(self, unit: int) -> list[str]:
        """Names of the items that ``unit`` makes, without making them."""

    def make_unit(self, unit: int) -> list[ExportItem]:
        """Make the items of ``unit`` (a pure function of the source and ``unit``)."""

    def header(self) -> dict[str, Any]:
        """Dataset-level manifest fields (``settings``, ``formats``, ``kind``, ``seed``...)."""


@dataclass(frozen=True)
class ExportReport:
    """What an export did.

    Attributes
    ----------
    out_dir
        The dataset folder.
    n_items
        Items the dataset holds when complete.
    n_written, n_skipped
        Items written by this run, and items found finished from an earlier run.
    cancelled
        Whether the run stopped early because it was cancelled (re-run to complete it).
    seconds
        Wall time of the run.
    workers
        Worker processes used (1 for a serial run).
    formats
        Formats written.
    files
        Dataset-level files written at the end (manifest, COCO JSON, ``man_track.txt``...).
    """

    out_dir: Path
    n_items: int
    n_written: int
    n_skipped: int
    cancelled: bool
    seconds: float
    workers: int
    formats: tuple[str, ...]
    files: tuple[str, ...] = field(default_factory=tuple)

    @property
    def complete(self) -> bool:
        """Whether every item of the dataset is on disk."""
        return not self.cancelled and self.n_written + self.n_skipped == self.n_items

    def __str__(self) -> str:
        state = "complete" if self.complete else "CANCELLED - run again to resume"
        return (
            f"export to {self.out_dir}: {state}; {self.n_items} images "
            f"({self.n_written} written, {self.n_skipped} already there) in "
            f"{', '.join(self.formats)}; {self.seconds:.1f} s with {self.workers} worker(s)"
        )


def _is_cancelled(cancel: Cancel | None) -> bool:
    if cancel is None:
        return False
    if hasattr(cancel, "is_set"):
        return bool(cancel.is_set())
    return bool(cancel())


def _writers(formats: Sequence[str], options: dict[str, Any]) -> list[FormatWriter]:
    return [get_writer(name, **options) for name in formats]


def run_units(
    source: ItemSource,
    units: Sequence[int],
    out_dir: str,
    formats: Sequence[str],
    options: dict[str, Any],
    skip: Sequence[str] = (),
    fft_threads: int | None = None,
    stop: str | None = None,
) -> list[dict[str, Any]]:
    """Make and write the items of ``units``, skipping the names in ``skip``.

    This is the function that runs on a dask worker; it returns the manifest entries
    written (entries of skipped items are not returned). ``fft_threads`` sets the
    default thread count of :mod:`scipy.fft` meanwhile (1 on dask workers: one worker
    process per core, no oversubscription). ``stop`` names a :class:`distributed.Event`
    checked before a unit (at most every :data:`STOP_CHECK_S`: each check asks the
    scheduler): once it is set (the export was cancelled or interrupted) the task
    returns what it has written.
    """
    if fft_threads is not None:
        from scipy import fft

        with fft.set_workers(fft_threads):
            return run_units(source, units, out_dir, formats, options, skip, stop=stop)
    out = Path(out_dir)
    writers = _writers(formats, options)
    skip = set(skip)
    entries = []
    next_check = time.monotonic()
    for unit in units:
        if all(name in skip for name in source.unit_names(unit)):
            continue
        if stop is not None and time.monotonic() >= next_check:
            if _stop_is_set(stop):
                break
            next_check = time.monotonic() + STOP_CHECK_S
        for item in source.make_unit(unit):
            if item.name not in skip:
                entries.append(write_item(out, item, writers))
            for writer in writers:
                writer.remember(item)
    return entries


def _stop_is_set(name: str) -> bool:
    from distributed import Event

    return Event(name).is_set()  # the worker's own client


def _chunks(units: list[int], size: int) -> list[list[int]]:
    return [units[i : i + size] for i in range(0, len(units), size)]


#: Seconds a local cluster takes to start (worker processes, imports) on a small, idle
#: machine. It grows with the machine's load: on 2 shared cores, 5-7 s at load average
#: 7 and 13 s at 11 (first item of a 2-worker export before this process wrote any).
LOCAL_CLUSTER_START_S = 4.0


def cluster_start_estimate_s() -> float:
    """:data:`LOCAL_CLUSTER_START_S` scaled by the load per core (when above 1).

    The environment variable ``NAPARI_SYMBAC_CLUSTER_START_S`` replaces the constant
    (``0`` always starts the workers).

    Raises
    ------
    ValueError
        If that variable is not a number >= 0.
    """
    text = os.environ.get("NAPARI_SYMBAC_CLUSTER_START_S")
    base = LOCAL_CLUSTER_START_S
    if text is not None:
        try:
            base = float(text)
        except ValueError:
            base = math.nan
        if not base >= 0:
            raise ValueError(
                f"NAPARI_SYMBAC_CLUSTER_START_S={text!r} must be a number of seconds >= 0 "
                "(0 always starts the workers); unset it for the default"
            )
    try:
        load = os.getloadavg()[0]
    except (AttributeError, OSError):  # no load average (Windows)
        load = 0.0
    return base * max(1.0, load / (os.cpu_count() or 1))


def _small_enough_for_one_process(
    units: deque[int], write_unit: Callable[[int], None], workers: int, cancel: Cancel | None
) -> bool:
    """Write the first two units here, timing the second; is the rest quicker done here?

    The first unit includes the simulation (which the workers then receive with the
    source); the second is the per-unit cost. Workers pay off when the rest would take
    this process more than ``workers / (workers - 1)`` times the start of a cluster
    (:func:`cluster_start_estimate_s`).
    """
    threshold = cluster_start_estimate_s() * workers / (workers - 1)  # checked before writing
    seconds = math.inf
    for _ in range(2):
        if not units or _is_cancelled(cancel):
            return True
        start = time.perf_counter()
        write_unit(units.popleft())
        seconds = time.perf_counter() - start
    return len(units) * seconds < threshold


def _start_cluster_while_working(
    workers: int,
    units: deque[int],
    write_unit: Callable[[int], None],
    cancel: Cancel | None,
) -> tuple[Any, Any]:
    """Start a local cluster in a helper thread; meanwhile write ``units`` here.

    Starting the worker processes (a fresh interpreter each, imports) takes seconds; the
    units this process writes meanwhile are units the cluster need not do. Writing stops
    after the unit in progress once the cluster is up (or the export is cancelled); the
    units not taken are left in ``units``.

    Ctrl-C: the worker processes are forked with SIGINT ignored from a fork server that
    this thread starts first (:func:`~napari_symbac.export.cluster.
    start_workers_ignoring_interrupts`); this thread takes Ctrl-C throughout: a
    ``KeyboardInterrupt`` while writing here waits for the start and closes the cluster.
    """
    from distributed import Client

    started: dict[str, Any] = {}
    up = threading.Event()

    def start() -> None:
        try:
            started["cluster"] = local_cluster(workers)
            started["client"] = Client(started["cluster"], set_as_default=False)
        except BaseException as err:  # re-raised in the calling thread
            started["error"] = err
        finally:
            up.set()

    helper = threading.Thread(target=start, name="napari-symbac-cluster-start", daemon=True)
    start_workers_ignoring_interrupts()  # here: only the main thread sets signal handlers
    try:
        helper.start()
        while units and not up.is_set() and not _is_cancelled(cancel):
            write_unit(units.popleft())
    except BaseException:
        if helper.ident is not None:  # started
            helper.join()
        close_quietly(started.get("client"), started.get("cluster"))
        raise
    helper.join()
    if "error" in started:
        close_quietly(started.get("client"), started.get("cluster"))
        raise started["error"]
    return started["cluster"], started["client"]


def _run_dask(
    source: ItemSource,
    pending: list[int],
    batch_size: int | None,
    skip_of: Callable[[list[int]], list[str]],
    out_dir: Path,
    formats: Sequence[str],
    options: dict[str, Any],
    *,
    workers: int,
    client: Any,
    on_entries: Callable[[list[dict[str, Any]]], None],
    cancel: Cancel | None,
    overlap_start: bool,
) -> tuple[bool, int]:
    cluster = None
    if client is None and not overlap_start:
        from distributed import Client

        cluster = local_cluster(workers)
        client = Client(cluster, set_as_default=False)
    elif client is None:
        units = deque(pending)

        def write_unit(unit: int) -> None:
            on_entries(
                run_units(source, [unit], str(out_dir), formats, options, skip_of([unit]))
            )

        if _small_enough_for_one_process(units, write_unit, workers, cancel):
            while units and not _is_cancelled(cancel):
                write_unit(units.popleft())
            return _is_cancelled(cancel) and bool(units), 1
        cluster, client = _start_cluster_while_working(workers, units, write_unit, cancel)
        pending = list(units)
    from distributed import Event, as_completed  # imported once workers are wanted (~1 s)

    cancelled = _is_cancelled(cancel)
    where = "the local worker processes" if cluster is not None else (
        f"the dask scheduler at {client.scheduler.address}"
    )
    try:
        n_workers = len(client.scheduler_info().get("workers", {})) or workers
        if cancelled or not pending:
            return cancelled, n_workers
        if cluster is None:
            _check_workers_see(client, out_dir, where)
        if batch_size is None:
            batch_size = max(1, min(MAX_BATCH_UNITS, len(pending) // (8 * n_workers)))
        token = uuid.uuid4().hex[:8]
        try:  # the source carries what this process has already computed (a simulation)
            source_future = client.scatter(source, broadcast=True, hash=False)
        except Exception as err:  # no worker, or workers that cannot unpickle it
            raise _cluster_failure(err, where, out_dir) from err
        stop = Event(f"symbac-export-stop-{token}", client=client)
        futures = [
            client.submit(
                run_units,
                source_future,
                batch,
                str(out_dir),
                list(formats),
                options,
                skip_of(batch),
                1,
                stop.name,
                key=f"symbac-export-{token}-{i}",
                pure=False,
                retries=0,
            )
            for i, batch in enumerate(_chunks(pending, batch_size))
        ]
        lost = _lost_task_errors()
        try:
            # the export's own client, not dask's default: found as a user, a scheduler's
            # address failed with dask's "No clients found" (as_completed asked the default)
            for future in as_completed(futures, loop=client.loop):
                try:
                    entries = future.result()
                except lost as err:
                    raise _cluster_failure(err, where, out_dir) from err
                on_entries(entries)
                if _is_cancelled(cancel):
                    cancelled = True
                    break
        finally:
            _stop_tasks(client, futures, stop)
    finally:
        close_quietly(client, cluster)
    return cancelled, n_workers


#: Units per dask task at most: the progress moves once a task ends (found as a user:
#: with 32, "1 of 200" was shown 13 s in, with ~50 items on disk).
MAX_BATCH_UNITS = 8

#: Seconds between a task's checks that the export goes on (a round trip to the
#: scheduler each, ~1 ms: before every image of ~20 ms it cost a few percent).
STOP_CHECK_S = 0.25

#: Seconds an interrupted or cancelled export waits for the tasks running on the
#: workers to end (each stops before its next unit).
STOP_WAIT_S = 60.0


def _lost_task_errors() -> tuple[type[BaseException], ...]:
    """The errors of a task that the cluster lost (not raised by the task itself)."""
    from concurrent.futures import CancelledError

    from distributed import KilledWorker
    from distributed.comm.core import CommClosedError

    return CancelledError, KilledWorker, CommClosedError


def _stop_tasks(client: Any, futures: list[Any], stop: Any) -> None:
    """Stop the export's tasks and wait for those running to end.

    Found as a user: after Ctrl-C, a scheduler's workers went on writing items for
    seconds after the command had said "interrupted" (a folder deleted then came back,
    and the rerun was refused). The workers stop before their next unit once ``stop``
    is set; this waits for them (a second Ctrl-C leaves at once), then cancels what is
    left.
    """
    try:
        if any(not future.done() for future in futures):
            stop.set()
            deadline = time.monotonic() + STOP_WAIT_S
            # polled: dask's wait() asks the default client, and the export's is not one
            while any(not f.done() for f in futures) and time.monotonic() < deadline:
                time.sleep(0.05)
    except (KeyboardInterrupt, Exception):  # a second Ctrl-C, a lost cluster: leave
        pass
    finally:
        with contextlib.suppress(Exception):
            client.cancel(futures)


def _check_workers_see(client: Any, out_dir: Path, where: str) -> None:
    """Refuse, before any item is computed, a user's scheduler whose workers do not see
    ``out_dir`` at the same path: a probe file written here must be there for each of
    them. Found as a user: a worker without the shared folder computed all 200 items
    before the export said so (for a lab's 100,000 items, hours lost).

    Raises
    ------
    ExportError
        Naming the workers that do not see the folder and the fix.
    """
    probe = out_dir / f".symbac-probe-{uuid.uuid4().hex}"
    probe.write_bytes(b"")
    try:
        seen = client.run(os.path.isfile, str(probe))
    except Exception as err:  # workers that cannot be reached or run it
        raise _cluster_failure(err, where, out_dir) from err
    finally:
        with contextlib.suppress(OSError):
            probe.unlink()
    blind = sorted(worker for worker, sees in seen.items() if not sees)
    if blind:
        raise ExportError(
            f"{len(blind)} of the {len(seen)} workers of {where} do not see the output "
            f"folder {out_dir} ({', '.join(blind[:3])}{', ...' * (len(blind) > 3)}): the "
            "workers must see it at the same path as this machine (a shared file system "
            "mounted at the same place); give such a path as the output folder, or start "
            "those workers where it is; nothing was computed",
            out_dir,
        )


def _cluster_failure(err: BaseException, where: str, out_dir: Path) -> ExportError:
    """What went wrong with ``where`` (not with an item), and what to do, as one line.

    Found as a user: a worker restarted (out of memory, killed), a scheduler that went
    away, a scheduler without workers and workers without napari-symbac each ended the
    export with dask's traceback or its raw text ("No valid workers found").
    """
    import napari_symbac

    text = " ".join(str(err).split()) or type(err).__name__  # dask's text, on one line
    items = out_dir / ITEMS_DIR
    if items.is_dir() and any(items.iterdir()):
        kept = f"run the same command again: {EXPORT_RESUMES}"
    else:  # found as a user: "keeps its finished items" where there was none
        kept = "then run the same command again (no item was finished)"
    if "No valid workers" in text:
        return ExportError(
            f"{where} has no worker to run the export on: start some (`dask worker "
            f"ADDRESS`, on machines that see {out_dir} at the same path); {kept}",
            out_dir,
        )
    if "napari_symbac" in text and ("ImportError" in text or "ModuleNotFound" in text):
        return ExportError(
            f"the workers of {where} cannot import napari_symbac ({text}): install "
            f"napari-symbac {napari_symbac.__version__}, as here, in the workers' "
            f"environment; {kept}",
            out_dir,
        )
    return ExportError(
        f"{where} lost the export's tasks ({type(err).__name__}: {text}): a worker died or "
        "was restarted (out of memory, killed) or the scheduler went away; " + kept,
        out_dir,
    )


def manifest_header(source: ItemSource, formats: Sequence[str]) -> dict[str, Any]:
    """The header of the manifest that an export of ``source`` in ``formats`` writes."""
    return {**source.header(), "formats": list(formats)}


def check_out_dir(out_dir: str | os.PathLike) -> Path:
    """``out_dir`` as an absolute path, refusing a path that exists and is not a folder.

    Raises
    ------
    ExportError
        If ``out_dir`` is an existing file.
    """
    out = Path(out_dir).resolve()
    if out.exists() and not out.is_dir():
        raise ExportError(
            f"the output path {out} is a file, not a folder: give the path of a folder "
            "(it is created if missing), or move the file away",
            out,
        )
    return out


def run_export(
    source: ItemSource,
    out_dir: str | os.PathLike,
    formats: Sequence[str] | str,
    *,
    options: dict[str, Any] | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: Progress | None = None,
    cancel: Cancel | None = None,
    batch_size: int | None = None,
    overlap_start: bool = True,
) -> ExportReport:
    """Export every item of ``source`` to ``out_dir``, resuming an earlier run.

    Parameters
    ----------
    source
        Where items come from (see :class:`ItemSource`).
    out_dir
        Dataset folder; created if missing.
    formats
        Names of formats in :data:`~napari_symbac.export.formats.FORMATS` (one name
        alone is taken too).
    options
        Writer options (``coco_segmentation``).
    workers
        Worker processes of a local dask cluster (on 127.0.0.1 only); ``None`` is one
        per core, ``1`` (or fewer units than two) runs serially in this process; more
        than the machine's cores is capped to them. While the workers start, this
        process writes items itself (see :func:`_start_cluster_while_working`).
    scheduler
        Address of a running dask scheduler (``tcp://host:8786``) to use instead; its
        workers must see ``out_dir`` at the same path. It is contacted (for at most
        :data:`SCHEDULER_TIMEOUT_S`) before anything is written.
    progress
        Called as ``progress(done, total)`` in items (finished ones from an earlier run
        count as done).
    cancel
        A callable returning ``True``, or a :class:`threading.Event`, checked between
        units; finished items stay on disk and a later run completes the rest.
    batch_size
        Units per dask task (default: about four tasks per worker, at most 32 units).
    overlap_start
        Write items in this process while a local cluster's workers start (default);
        ``False`` leaves every item to the workers.

    Raises
    ------
    ExportError
        Disk full, permission denied, ``out_dir`` is a file or holds a different export,
        or no scheduler answers at ``scheduler``.
    ValueError
        ``workers`` below 1 or an unknown format.
    """
    start = time.perf_counter()
    out = check_out_dir(out_dir)
    options = dict(options or {})
    formats = (formats,) if isinstance(formats, str) else tuple(formats)  # "tiff": one
    writers = _writers(formats, options)  # validates the names early
    n_workers = check_workers(workers)
    # connect before writing anything: a wrong address leaves no folder behind
    client = None if scheduler is None else connect_scheduler(scheduler)
    existed = out.exists()
    new = not existed or not any(out.iterdir())
    # a user's scheduler lost mid-export: the client logs its reconnection attempts,
    # tracebacks and all, while the export's own error says what happened and what to do
    # (found as a user: 34 lines of dask's before the one line); errors of the tasks
    # reach the export as exceptions, not through this log
    quiet = silenced("distributed.client") if client is not None else contextlib.nullcontext()
    try:
        with quiet, export_lock(out):
            check_or_start_manifest(out, manifest_header(source, formats))
            return _run_export(
                source, out, formats, writers, options, n_workers, client, progress,
                cancel, batch_size, overlap_start, start,
            )
    except ExportError as err:
        if err.errno is None:  # not the disk's (a cluster's, a setting's): say it as it is
            if new:
                _remove_unfinished_start(out, keep_folder=existed)
            raise
        raise ExportError(f"{err}: {EXPORT_RESUMES}", err.path, err.errno) from err
    except Exception:
        if new:
            _remove_unfinished_start(out, keep_folder=existed)
        raise
    finally:
        if client is not None:
            close_quietly(client, None)


def _remove_unfinished_start(out: Path, keep_folder: bool) -> None:
    """Remove what an export that failed before finishing any item wrote into a new or
    empty ``out`` (its manifest; the folder too unless it was there before): found as a
    user, settings whose first image could not be drawn (a pixel size of 65 um) left a
    manifest.json, and the corrected rerun was refused as "another export". An export
    with a finished item keeps it, to resume."""
    items = out / ITEMS_DIR
    if not out.is_dir() or (items.is_dir() and any(items.iterdir())):
        return
    with contextlib.suppress(OSError):  # the export's own error is the one to say
        remove_earlier_run(list(out.iterdir()))
        if not keep_folder:
            out.rmdir()


def _run_export(
    source: ItemSource,
    out: Path,
    formats: tuple[str, ...],
    writers: list[FormatWriter],
    options: dict[str, Any],
    n_workers: int,
    client: Any,
    progress: Progress | None,
    cancel: Cancel | None,
    batch_size: int | None,
    overlap_start: bool,
    start: float,
) -> ExportReport:
    remove_stale_temporaries(out)

    names_of = {unit: source.unit_names(unit) for unit in range(source.n_units)}
    all_names = [name for names in names_of.values() for name in names]
    total = len(all_names)
    done = set(finished_items(out, all_names))
    n_skipped = len(done)
    pending = [u for u, names in names_of.items() if not all(n in done for n in names)]
    state = {"done": n_skipped, "written": 0}
    reported: set[str] = set()  # the items that this run's workers say they wrote
    if progress is not None:
        progress(state["done"], total)

    def on_entries(entries: list[dict[str, Any]]) -> None:
        reported.update(entry["name"] for entry in entries)
        state["written"] += len(entries)
        state["done"] += len(entries)
        if progress is not None:
            progress(state["done"], total)

    def skip_of(units: Iterable[int]) -> list[str]:
        return [n for u in units for n in names_of[u] if n in done]

    cancelled = False
    if pending and (client is not None or (n_workers > 1 and len(pending) > 1)):
        cancelled, n_workers = _run_dask(
            source,
            pending,
            batch_size,
            skip_of,
            out,
            formats,
            options,
            workers=n_workers,
            client=client,
            on_entries=on_entries,
            cancel=cancel,
            overlap_start=overlap_start,
        )
    else:
        n_workers = 1
        for unit in pending:
            if _is_cancelled(cancel):
                cancelled = True
                break
            on_entries(run_units(source, [unit], str(out), formats, options, skip_of([unit])))

    files: tuple[str, ...] = ()
    entries = read_entries(out, all_names)
    if cancelled:  # the items of tasks that finished after the cancel count too (found
        # as a user: "83 written" said where 92 were on disk)
        state["written"] = max(state["written"], len(entries) - n_skipped)
    if not cancelled:
        if len(entries) != total:
            missing = sorted(set(all_names) - {e["name"] for e in entries})
            unseen = [name for name in missing if name in reported]
            if unseen:  # found as a user: "run it again" then failed the same way forever
                raise ExportError(
                    f"the workers wrote {len(unseen)} item(s) (e.g. "
                    f"{', '.join(unseen[:5])}) that this machine does not see in {out}: "
                    "the workers must see the output folder at the same path as this "
                    "machine (a shared file system mounted at the same place); give such a "
                    "path as the output folder",
                    out,
                )
            missing = missing[:5]
            raise ExportError(
                f"export to {out} finished with {total - len(entries)} item(s) missing "
                f"(e.g. {', '.join(missing)}): run it again to complete them",
                out,
            )
        written = {writer.name: writer.finalize(out, entries) for writer in writers}
        finish_manifest(out, entries, written)
        files = (*(f for paths in written.values() for f in paths), "manifest.json")
    return ExportReport(
        out_dir=out,
        n_items=total,
        n_written=state["written"],
        n_skipped=n_skipped,
        cancelled=cancelled,
        seconds=time.perf_counter() - start,
        workers=n_workers,
        formats=formats,
        files=files,
    )


class _ListSource:
    """An :class:`ItemSource` over items already in memory.

    A unit is one independent image, or the consecutive frames of one time series (so
    that writers which need the previous frame, DeLTA tracking, see the whole series).
    """

    def __init__(self, items: Sequence[ExportItem], header: dict[str, Any]) -> None:
        names = [item.name for item in items]
        if len(set(names)) != len(names):
            raise ValueError("write_items: item names must be unique")
        self.units: list[list[ExportItem]] = []
        for item in items:
            last = self.units[-1][-1] if self.units else None
            if (
                last is not None
                and item.is_timeseries
                and (last.series, last.split) == (item.series, item.split)
            ):
                self.units[-1].append(item)
            else:
                self.units.append([item])
        self._header = header

    @property
    def n_units(self) -> int:
        return len(self.units)

    def unit_names(self, unit: int) -> list[str]:
        return [item.name for item in self.units[unit]]

    def make_unit(self, unit: int) -> list[ExportItem]:
        return list(self.units[unit])

    def header(self) -> dict[str, Any]:
        return self._header


def write_items(
    items: Sequence[ExportItem],
    out_dir: str | os.PathLike,
    formats: Sequence[str],
    *,
    header: dict[str, Any] | None = None,
    coco_segmentation: str = "polygon",
    progress: Progress | None = None,
    cancel: Cancel | None = None,
) -> ExportReport:
    """Write items already in memory as a dataset (serially, atomically, resumable).

    Parameters
    ----------
    items
        The items, e.g. from :func:`~napari_symbac.export.series_items` for a rendered
        time series.
    out_dir
        Dataset folder.
    formats
        Format names, e.g. ``("tiff", "ctc")``, or one name.
    header
        Extra manifest fields, typically ``{"settings": to_dict(pipeline_settings)}``.
    coco_segmentation
        ``"polygon"`` or ``"rle"`` outlines in the COCO format.
    progress, cancel
        ``progress(done, total)`` after each item; ``cancel()`` returning True (or an
        event that is set) stops after the item in progress: run again to resume.
    """
    header = {"kind": "items", "settings": None, **(header or {})}
    return run_export(
        _ListSource(items, header),
        out_dir,
        formats,
        options={"coco_segmentation": coco_segmentation},
        workers=1,
        progress=progress,
        cancel=cancel,
    )
