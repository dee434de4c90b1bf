"""A user's dask scheduler failing under an export: each failure one clear error that
says what to do, and an interrupted export whose workers stop writing.

Found as a user (``export --scheduler``): a restarted worker, a scheduler without
workers and workers without napari-symbac each ended the export with dask's traceback
or its raw text; after Ctrl-C the scheduler's workers went on writing for seconds; and
workers that did not see the output folder made "run it again" fail forever.
"""

from __future__ import annotations

import os
import signal
import threading
import time

import _export_synthetic
import cloudpickle
import pytest
from _export_synthetic import SyntheticSource, tree_digest

from napari_symbac.cli import main
from napari_symbac.export import ExportError, run_export
from napari_symbac.export import runner as export_runner
from napari_symbac.export.atomic import EXPORT_RESUMES

pytest.importorskip("distributed")


@pytest.fixture
def by_value():
    """The test's ItemSource pickled by value: the workers cannot import tests/."""
    cloudpickle.register_pickle_by_value(_export_synthetic)
    yield
    cloudpickle.unregister_pickle_by_value(_export_synthetic)


def _user_cluster(n_workers: int):
    """A scheduler with worker processes (each with its nanny), as `dask scheduler` +
    `dask worker` give; the export's own cluster settings (a LocalCluster with dask's
    defaults leaves its workers' MALLOC_TRIM_THRESHOLD_ in this process's environment,
    which the next local export's workers would then inherit)."""
    from napari_symbac.export.cluster import local_cluster

    return local_cluster(n_workers)


def _n_items(out) -> int:
    items = out / "manifest_items"
    return len(list(items.glob("*.json"))) if items.is_dir() else 0


def test_a_killed_worker_is_one_error_that_says_to_resume(tmp_path, by_value):
    """The only worker killed mid-export (its nanny restarts it; the export's data died
    with it): one ExportError naming the scheduler and saying to run again, and the rerun
    completes the dataset as an uninterrupted run writes it."""
    from distributed import Client

    reference = tmp_path / "reference"
    run_export(SyntheticSource(20), reference, ["tiff"], workers=1)
    out = tmp_path / "ds"
    with _user_cluster(1) as cluster, Client(cluster, set_as_default=False) as client:
        (worker_pid,) = client.run(os.getpid).values()
        killed = []

        def progress(done: int, total: int) -> None:
            if done >= 2 and not killed:
                os.kill(worker_pid, signal.SIGKILL)
                killed.append(done)

        with pytest.raises(ExportError) as raised:
            run_export(
                SyntheticSource(20, delay_s=0.2), out, ["tiff"],
                scheduler=cluster.scheduler_address, batch_size=1, progress=progress,
            )  # fmt: skip
    said = str(raised.value)
    assert killed
    assert f"the dask scheduler at {cluster.scheduler_address} lost the export's tasks" in said
    assert "a worker died or was restarted" in said
    assert EXPORT_RESUMES in said
    assert "\n" not in said
    report = run_export(SyntheticSource(20), out, ["tiff"], workers=1)
    assert report.complete
    assert report.n_skipped >= 2
    assert tree_digest(out) == tree_digest(reference)


def _free_port() -> int:
    import socket

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def test_a_scheduler_killed_mid_export_is_one_line_not_dasks_traceback(tmp_path):
    """A user's `dask scheduler` process killed while the export runs: the export's one
    error, and nothing of dask's on stderr (found as a user: 34 lines, two tracebacks of
    the client's reconnection attempts, came first)."""
    import subprocess
    import sys

    address = f"tcp://127.0.0.1:{_free_port()}"
    dask = [sys.executable, "-m", "distributed.cli"]
    scheduler = subprocess.Popen(
        [*dask[:2], "distributed.cli.dask_scheduler", "--host", "127.0.0.1", "--port",
         address.rsplit(":", 1)[1], "--dashboard-address", "127.0.0.1:0"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    worker = None
    try:
        from distributed import Client

        worker = subprocess.Popen(
            [*dask[:2], "distributed.cli.dask_worker", address, "--nworkers", "1",
             "--nthreads", "1"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=tmp_path,
        )  # fmt: skip
        deadline = time.monotonic() + 60
        while True:  # the scheduler up and its worker registered
            try:
                with Client(address, timeout=5, set_as_default=False) as client:
                    client.wait_for_workers(1, timeout=max(deadline - time.monotonic(), 1))
                break
            except OSError:
                assert time.monotonic() < deadline, "the dask scheduler did not start"
                time.sleep(0.5)

        out = tmp_path / "ds"

        def kill_when_items_are_written() -> None:
            deadline = time.monotonic() + 120
            while _n_items(out) < 4 and time.monotonic() < deadline:
                time.sleep(0.05)
            scheduler.kill()

        killer = threading.Thread(target=kill_when_items_are_written, daemon=True)
        killer.start()
        config = tmp_path / "export.yaml"
        assert main(["defaults", "export", "--out", str(config)]) == 0
        # in a process of its own, as a user runs it: dask's log handlers write to the
        # stderr of the process that imported distributed (here, pytest's capture)
        command = subprocess.run(
            [sys.executable, "-c", "import sys; from napari_symbac.cli import main; "
             "sys.exit(main())", "export", "--config", str(config), "--n-items", "300",
             "--formats", "tiff", "--scheduler", address, "--out", str(out)],
            capture_output=True, text=True, timeout=300,
        )  # fmt: skip
        killer.join(30)
    finally:
        for process in (worker, scheduler):
            if process is not None:
                process.kill()
                process.wait(30)
    code, stderr = command.returncode, command.stderr
    assert code == 2, stderr
    said = [line for line in stderr.splitlines() if not line.startswith("napari-symbac export: ")]
    assert not said, stderr
    assert stderr.splitlines()[-1].startswith(
        f"napari-symbac export: error: the dask scheduler at {address} lost the export's tasks"
    )


def test_a_scheduler_without_workers_says_to_start_some(tmp_path, by_value):
    """Was dask's "No valid workers found" (after ~18 s); nothing is left behind."""
    with (
        _user_cluster(0) as cluster,
        pytest.raises(ExportError, match="has no worker to run the export on") as raised,
    ):
        run_export(SyntheticSource(4), tmp_path / "ds", ["tiff"],
                   scheduler=cluster.scheduler_address)  # fmt: skip
    assert "`dask worker ADDRESS`" in str(raised.value)
    assert cluster.scheduler_address in str(raised.value)
    assert not (tmp_path / "ds").exists()


def test_workers_without_napari_symbac_are_named_with_the_fix(tmp_path):
    """The error dask raises when the workers cannot unpickle the export (found as a
    user: a 62-line traceback from inside distributed's scatter_to_workers). It promises
    to keep finished items only where there are some (found as a user: it did where
    none was)."""
    import napari_symbac

    err = Exception("ImportError('No module named napari_symbac')")
    where = "the dask scheduler at tcp://h:8786"
    said = str(export_runner._cluster_failure(err, where, tmp_path))
    assert said.startswith("the workers of the dask scheduler at tcp://h:8786 cannot import")
    assert f"install napari-symbac {napari_symbac.__version__}" in said
    assert said.endswith("then run the same command again (no item was finished)")
    (tmp_path / export_runner.ITEMS_DIR).mkdir()
    (tmp_path / export_runner.ITEMS_DIR / "item_000000").mkdir()
    said = str(export_runner._cluster_failure(err, where, tmp_path))
    assert said.endswith(f"run the same command again: {EXPORT_RESUMES}")


def test_an_interrupted_export_leaves_no_worker_writing(tmp_path, by_value):
    """Cancelled while a scheduler's worker runs a task of several units: the task stops
    before its next unit and the export returns only when it has, so the folder does not
    change afterwards (found as a user: 34 items appeared in the 3 s after "interrupted",
    and a folder deleted then came back)."""
    cancel = threading.Event()

    def progress(done: int, total: int) -> None:
        if done >= 1:
            cancel.set()

    out = tmp_path / "ds"
    with _user_cluster(1) as cluster:
        report = run_export(
            SyntheticSource(40, delay_s=0.25), out, ["tiff"],
            scheduler=cluster.scheduler_address, batch_size=10, progress=progress,
            cancel=cancel,
        )  # fmt: skip
        assert report.cancelled
        on_disk = _n_items(out)
        # what is on disk, the items of tasks that finished after the cancel too (found
        # as a user: "83 written" said where 92 were)
        assert report.n_written == on_disk
        time.sleep(2.0)  # a task left running would write ~8 more items meanwhile
        assert _n_items(out) == on_disk
    assert on_disk < 20  # the first task's 10 and at most one unit of the second's
    report = run_export(SyntheticSource(40), out, ["tiff"], workers=1)
    assert report.complete


def test_workers_that_do_not_see_the_output_folder_are_named_before_any_item(
    tmp_path, by_value, monkeypatch
):
    """Found as a user: a worker without the shared folder computed every item (200 of
    200) before the export said it could not see them. The workers are asked first
    whether they see a file written in the folder; one that does not (the fault
    injected into its answer) is named, and nothing is computed or left behind."""
    real_connect = export_runner.connect_scheduler

    def connect_to_one_blind_worker(address):
        client = real_connect(address)
        real_run = client.run

        def run(function, *args, **kwargs):
            answers = real_run(function, *args, **kwargs)
            if function is os.path.isfile:
                first = sorted(answers)[0]
                answers[first] = False  # as a worker on a machine without the share
            return answers

        client.run = run
        return client

    monkeypatch.setattr(export_runner, "connect_scheduler", connect_to_one_blind_worker)
    out = tmp_path / "ds"
    with _user_cluster(2) as cluster:
        with pytest.raises(ExportError) as raised:
            run_export(SyntheticSource(20, delay_s=0.2), out, ["tiff"],
                       scheduler=cluster.scheduler_address)  # fmt: skip
        first = sorted(cluster.scheduler_info["workers"])[0]
    said = str(raised.value)
    where = f"the dask scheduler at {cluster.scheduler_address}"
    assert said.startswith(f"1 of the 2 workers of {where}")
    assert f"do not see the output folder {out} ({first})" in said
    assert "nothing was computed" in said
    assert not out.exists()


def test_items_the_workers_wrote_where_this_machine_cannot_see_them(tmp_path, monkeypatch):
    """Workers that write the items on their own disks (the output folder not shared):
    said so, with the fix, instead of "run it again" that then failed the same way."""
    elsewhere = tmp_path / "the workers' disk"
    real_write = export_runner.write_item

    def write_on_their_disk(out, item, writers):
        return real_write(elsewhere, item, writers)

    monkeypatch.setattr(export_runner, "write_item", write_on_their_disk)
    with pytest.raises(ExportError, match="that this machine does not see in") as raised:
        run_export(SyntheticSource(3), tmp_path / "ds", ["tiff"], workers=1)
    assert "must see the output folder at the same path" in str(raised.value)
