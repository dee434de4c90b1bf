"""The processes an export runs on: a local dask cluster or a user's scheduler.

Everything here fails early and clearly: the number of workers is checked (and capped
to the cores), a scheduler address is parsed and contacted before anything is written,
local workers ignore Ctrl-C (the main process handles it and shuts them down), and
dask's shutdown chatter is kept out of the user's terminal.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import os
import signal
import threading
from collections.abc import Iterator
from typing import Any

from napari_symbac.export.atomic import ExportError

__all__ = [
    "SCHEDULER_TIMEOUT_S",
    "check_scheduler_address",
    "check_workers",
    "close_quietly",
    "connect_scheduler",
    "local_cluster",
    "start_workers_ignoring_interrupts",
]


#: Modules the fork server imports before it forks the workers.
_WORKER_PRELOAD = ("distributed", "napari_symbac.export.runner")


def start_workers_ignoring_interrupts() -> str:
    """Start multiprocessing's fork server with SIGINT ignored; the start method to use.

    Ctrl-C in a terminal interrupts every process of the foreground group; the workers
    would each print a ``KeyboardInterrupt`` traceback. The fork server is started here
    with SIGINT ignored for the moment its process is spawned: it keeps ignoring it, and
    every worker it forks inherits that, so the workers go on until this process, which
    handles the interrupt, shuts them down. This process ignores SIGINT only for that
    spawn, before any item is written. (Before, it ignored SIGINT for the whole start of
    the cluster, a second or more on a loaded machine, and a Ctrl-C pressed then was
    lost: the export ran to its end.) Only the main thread can change a signal handler;
    elsewhere (a GUI thread, which gets no Ctrl-C) the server starts as it is. Without a
    fork server (Windows) the workers are spawned as before.

    Returns
    -------
    str
        ``"forkserver"``, or ``"spawn"`` where there is none.
    """
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return "spawn"
    from multiprocessing import forkserver

    # imported once in the server, not again in every worker it forks
    forkserver.set_forkserver_preload(list(_WORKER_PRELOAD))
    if threading.current_thread() is not threading.main_thread():
        forkserver.ensure_running()
        return "forkserver"
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        forkserver.ensure_running()
    finally:
        signal.signal(signal.SIGINT, previous)
    return "forkserver"


def local_cluster(workers: int):
    """A dask ``LocalCluster`` of ``workers`` single-threaded processes on 127.0.0.1.

    No dashboard; the worker processes ignore Ctrl-C (see module notes). dask starts
    workers with ``MALLOC_TRIM_THRESHOLD_=65536`` (to hand memory back to the system),
    which turns off glibc's adaptive mmap threshold: every frame-sized temporary array
    is then a fresh ``mmap`` with its page faults, and an item took 1.6x as long (63 vs
    38 ms, serial units with and without it). An export worker holds one item at a
    time, so the workers start without it.
    """
    import dask
    from distributed import LocalCluster

    config = {
        "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
        "distributed.worker.multiprocessing-method": start_workers_ignoring_interrupts(),
    }
    cluster = None
    try:
        with dask.config.set(config):
            cluster = LocalCluster(
                n_workers=workers,
                threads_per_worker=1,
                processes=True,
                host="127.0.0.1",
                dashboard_address=None,
                # without a dashboard the scheduler still serves health/metrics over HTTP, on
                # port 8787 of every interface by default: a dask dashboard already running
                # there made it warn "Port 8787 is already in use" on the user's terminal.
                # A free port on the loopback interface instead (port 0: no clash, no warning).
                scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
                # the workers' stderr is the user's terminal: a worker whose heartbeat meets
                # an already-closed scheduler at shutdown (Ctrl-C) logs a traceback at ERROR.
                # Task errors still reach this process as exceptions, so workers log nothing.
                silence_logs=logging.CRITICAL,
                # one item needs little memory; do not let dask pause workers on small machines
                memory_limit=0,
            )
    except BaseException:  # a Ctrl-C while the cluster starts: close what has started
        if cluster is not None:
            close_quietly(None, cluster)
        raise
    return cluster


@contextlib.contextmanager
def silenced(*names: str) -> Iterator[None]:
    """The loggers ``names`` silenced for the block (their levels restored after)."""
    loggers = [logging.getLogger(name) for name in names]
    levels = [logger.level for logger in loggers]
    for logger in loggers:
        logger.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        for logger, level in zip(loggers, levels):
            logger.setLevel(level)


def close_quietly(client: Any | None, cluster: Any | None) -> None:
    """Close a client (and its local cluster) without the workers' shutdown chatter.

    On Ctrl-C the worker processes receive the interrupt too; their
    ``KeyboardInterrupt`` / ``CancelledError`` logs would bury the one line the
    command prints, so dask's loggers are silenced while everything shuts down.
    """
    with silenced("distributed", "tornado", "asyncio"):
        if client is not None:
            with contextlib.suppress(Exception):
                client.close(timeout=10)
        if cluster is not None:
            with contextlib.suppress(Exception):
                cluster.close(timeout=10)


#: Seconds to wait for a ``scheduler`` address to answer before giving up.
SCHEDULER_TIMEOUT_S = 10.0


def connect_scheduler(address: str, timeout_s: float | None = None) -> Any:
    """A :class:`distributed.Client` of the scheduler at ``address``, or a clear error.

    Raises
    ------
    ExportError
        If nothing answers at ``address`` within ``timeout_s`` (default
        :data:`SCHEDULER_TIMEOUT_S`); nothing has been written at that point.
    """
    from distributed import Client

    timeout_s = SCHEDULER_TIMEOUT_S if timeout_s is None else timeout_s
    address = check_scheduler_address(address)
    try:
        with silenced("distributed"):
            _identify_scheduler(address, timeout_s)
            return Client(address, timeout=timeout_s, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as err:
        raise _no_scheduler(address, timeout_s, err) from err


def _no_scheduler(address: str, timeout_s: float, why: object) -> ExportError:
    return ExportError(
        f"no dask scheduler answered at {address} within {timeout_s:g} s ({why}): start "
        "one there (`dask scheduler` plus `dask worker ADDRESS`), check the address (the "
        "scheduler's port, 8786 by default, not its dashboard's), or leave out the "
        "scheduler to use local worker processes; nothing was written",
        None,
    )


def _identify_scheduler(address: str, timeout_s: float) -> None:
    """Ask ``address`` what it is (dask's ``identity`` call), all within ``timeout_s``.

    A client handshakes without a limit on the answer, so a server that is not dask's
    held it for good (found as a user: an HTTP server, such as the dashboard's port, hung
    ``export`` for over 11 minutes; another answered bytes that dask read as a 3 EiB
    frame, and a traceback followed). Any failure to get a scheduler's identity is an
    :class:`ExportError` that says what answered.
    """
    import asyncio
    import concurrent.futures

    from distributed.core import rpc

    async def ask() -> object:
        remote = rpc(address, timeout=timeout_s)
        try:
            return await remote.identity()
        finally:
            await remote.close_rpc()

    def run() -> object:  # its own event loop, in a thread: a notebook's loop may run here
        return asyncio.run(asyncio.wait_for(ask(), timeout_s))

    try:
        with concurrent.futures.ThreadPoolExecutor(1) as pool:
            identity = pool.submit(run).result()
    except (OSError, TimeoutError, asyncio.TimeoutError) as err:
        raise _no_scheduler(address, timeout_s, str(err) or "no answer") from err
    except Exception as err:  # the bytes of a server that is not dask's
        raise _no_scheduler(
            address,
            timeout_s,
            # the reply read as dask's protocol fails as it may: a frame length of EiB is a
            # MemoryError (found as a user: "not dask: MemoryError" read as our memory)
            "something answered that is not a dask scheduler, its reply unreadable as "
            f"dask's protocol: {type(err).__name__}",
        ) from err
    kind = identity.get("type") if isinstance(identity, dict) else None
    if kind != "Scheduler":
        answered = f"a dask {kind or 'server'} answered, not a scheduler"
        raise _no_scheduler(address, timeout_s, answered)


def check_scheduler_address(address: object) -> str:
    """The address as dask takes it (spaces and a trailing ``/`` removed: found as a
    user, ``tcp://host:8786/`` was refused with "invalid literal for int()"); an address
    dask cannot parse is refused before a client is built for it (and, in the Export
    dock, before its job starts).

    Raises
    ------
    ValueError
        Naming the address, what is wrong with it and an example.
    """
    from distributed.comm.addressing import parse_address, parse_host_port

    example = "such as tcp://10.0.0.5:8786"
    if not isinstance(address, str) or not address.strip():
        raise ValueError(f"the scheduler address must be text {example}, got {address!r}")
    from distributed.comm.registry import backends

    given, address = address, address.strip().rstrip("/")

    try:
        protocol, location = parse_address(address)
        if protocol not in backends:  # found as a user: http:// stalled 20 s first
            raise ValueError(f"unknown scheme {protocol!r}; dask's are {', '.join(backends)}")
        if protocol in ("tcp", "tls"):
            parse_host_port(location)
    except ValueError as err:
        raise ValueError(
            f"the scheduler address {given!r} is not a dask address ({err}): give one "
            f"{example}"
        ) from err
    return address


def check_workers(workers: int | None) -> int:
    """The number of local worker processes to start for ``workers``.

    ``None`` means one per core; more than the machine's cores is capped to them (extra
    processes only compete for the same cores).

    Raises
    ------
    ValueError
        If ``workers`` is not an integer >= 1.
    """
    cores = os.cpu_count() or 1
    if workers is None:
        return cores
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(
            f"workers must be an integer >= 1 (1 runs in this process), got {workers!r}"
        )
    return min(workers, cores)
