"""Atomic writes, resume after a fault or a kill, cancellation, disk errors, dask."""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import _export_synthetic
import cloudpickle
import numpy as np
import pytest
import tifffile
from _export_synthetic import SyntheticSource, tree_digest

from napari_symbac.export import ExportError, run_export
from napari_symbac.export.atomic import EXPORT_RESUMES, write_tiff
from napari_symbac.export.manifest import ITEMS_DIR, UNFINISHED

FORMATS = ("tiff", "omnipose", "stardist", "coco")
HERE = Path(__file__).resolve().parent


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> dict[str, bytes]:
    """Files of an uninterrupted serial export of 12 synthetic items."""
    out = tmp_path_factory.mktemp("reference")
    report = run_export(SyntheticSource(12), out, FORMATS, workers=1)
    assert report.complete
    assert report.n_written == 12
    assert report.n_skipped == 0
    return tree_digest(out)


def _images_without_masks(out: Path) -> list[str]:
    """Masks whose image is missing, and partial (temporary) files under their final name."""
    problems = []
    for mask in (out / "stardist").rglob("masks/*.tif"):
        image = mask.parent.parent / "images" / mask.name
        if not mask.name.startswith(".") and not image.exists():
            problems.append(str(mask))
    for mask in (out / "omnipose").rglob("*_masks.tif"):
        image = mask.with_name(mask.name.replace("_masks", ""))
        if not mask.name.startswith(".") and not image.exists():
            problems.append(str(mask))
    for path in out.rglob("*.tif"):
        if not path.name.startswith("."):
            tifffile.imread(path)  # every final-named file is complete
    return problems


def test_reference_is_reproducible(tmp_path, reference):
    run_export(SyntheticSource(12), tmp_path, FORMATS, workers=1)
    assert tree_digest(tmp_path) == reference


def test_manifest_records_items(tmp_path, reference):
    manifest = json.loads(reference["manifest.json"])
    assert manifest["status"] == "complete"
    assert manifest["n_items"] == 12
    assert len(manifest["items"]) == 12
    assert manifest["seed"] == 0
    assert manifest["versions"]["napari_symbac"]
    entry = manifest["items"][4]
    assert entry["name"] == "000004"
    assert entry["params"]["unit"] == 4
    assert entry["files"]["stardist"] == [
        f"stardist/{entry['split']}/images/000004.tif",
        f"stardist/{entry['split']}/masks/000004.tif",
    ]


def test_fault_then_resume_completes_identically(tmp_path, reference):
    flag = tmp_path / "fail"
    flag.touch()
    out = tmp_path / "out"
    source = SyntheticSource(12, fail_at=7, fail_flag=str(flag))
    with pytest.raises(RuntimeError, match="injected fault in unit 7"):
        run_export(source, out, FORMATS, workers=1)
    assert _n_entries(out) == 7
    assert json.loads((out / "manifest.json").read_text())["status"] == "incomplete"
    # found as a user: only the manifest's status said the folder is not the dataset
    assert "This export is unfinished" in (out / UNFINISHED).read_text()
    assert not _images_without_masks(out)
    flag.unlink()
    report = run_export(source, out, FORMATS, workers=1)
    assert report.complete
    assert report.n_skipped == 7
    assert report.n_written == 5
    assert not (out / UNFINISHED).exists()
    assert tree_digest(out) == reference


def _n_entries(out):
    """Finished item entries; a kill mid-write can leave a hidden ``.NAME.tmp-...json``,
    which pathlib's ``*.json`` would count (it matches dot files)."""
    return sum(not p.name.startswith(".") for p in (out / ITEMS_DIR).glob("*.json"))


def test_killed_export_resumes(tmp_path, reference):
    """Kill a serial export (SIGKILL) in a subprocess midway, then resume it."""
    out = tmp_path / "out"
    script = textwrap.dedent(
        f"""
        import sys
        sys.path.insert(0, {str(HERE)!r})
        from _export_synthetic import SyntheticSource
        from napari_symbac.export import run_export
        run_export(SyntheticSource(12, delay_s=0.25), {str(out)!r}, {FORMATS!r}, workers=1)
        """
    )
    proc = subprocess.Popen([sys.executable, "-c", script])
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            items = out / ITEMS_DIR
            if items.is_dir() and _n_entries(out) >= 4:
                break
            if proc.poll() is not None:
                pytest.fail("the export finished before it could be killed")
            time.sleep(0.02)
        else:
            pytest.fail("the export did not start in 60 s")
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    done = _n_entries(out)
    assert 4 <= done < 12
    assert not _images_without_masks(out)
    report = run_export(SyntheticSource(12), out, FORMATS, workers=1)
    assert report.complete
    assert report.n_skipped == done
    assert tree_digest(out) == reference


def test_missing_file_is_rewritten(tmp_path, reference):
    run_export(SyntheticSource(12), tmp_path, FORMATS, workers=1)
    (tmp_path / "stardist" / "train" / "masks" / "000003.tif").unlink()
    report = run_export(SyntheticSource(12), tmp_path, FORMATS, workers=1)
    assert report.n_written == 1
    assert report.n_skipped == 11
    assert tree_digest(tmp_path) == reference


def test_stale_temporary_files_are_removed(tmp_path, reference):
    """A run killed mid-write leaves temporaries beside its items: the next run removes
    them."""
    cancelled = run_export(SyntheticSource(12), tmp_path, FORMATS, workers=1, cancel=lambda: True)
    assert not cancelled.complete
    stale = tmp_path / "stardist" / "train" / "images" / ".000001.tmp-123-deadbeef.tif"
    stale.parent.mkdir(parents=True, exist_ok=True)
    stale.write_bytes(b"partial")
    run_export(SyntheticSource(12), tmp_path, FORMATS, workers=1)
    assert not stale.exists()
    assert tree_digest(tmp_path) == reference


def test_cancel_between_items_then_resume(tmp_path, reference):
    event = threading.Event()
    seen = []

    def progress(done: int, total: int) -> None:
        seen.append((done, total))
        if done >= 5:
            event.set()

    report = run_export(
        SyntheticSource(12), tmp_path, FORMATS, workers=1, progress=progress, cancel=event
    )
    assert report.cancelled
    assert not report.complete
    assert report.n_written == 5
    assert seen == [(k, 12) for k in range(6)]
    assert "CANCELLED" in str(report)
    report = run_export(SyntheticSource(12), tmp_path, FORMATS, workers=1, cancel=lambda: False)
    assert report.complete
    assert report.n_skipped == 5
    assert tree_digest(tmp_path) == reference


def test_other_settings_in_same_folder_refused(tmp_path):
    run_export(SyntheticSource(3), tmp_path, ["tiff"], workers=1)
    with pytest.raises(ExportError, match="different settings"):
        run_export(SyntheticSource(4), tmp_path, ["tiff"], workers=1)
    with pytest.raises(ExportError, match="different settings"):
        run_export(SyntheticSource(3), tmp_path, ["png"], workers=1)


@pytest.mark.parametrize(
    "full",
    [lambda src: OSError(errno.ENOSPC, "No space left on device", str(src)),
     # numpy's short write, no errno (found as a user: a TIFF export on a full disk said
     # "could not write ...: 11776 requested and 7824 written")
     lambda src: OSError("11776 requested and 7824 written")],
)  # fmt: skip
def test_disk_full_stops_with_clear_message(tmp_path, monkeypatch, full):
    real_replace = os.replace
    calls = {"n": 0}

    def replace(src, dst):
        calls["n"] += 1
        if calls["n"] > 20:  # the disk fills up during the export
            raise full(src)
        return real_replace(src, dst)

    monkeypatch.setattr(os, "replace", replace)
    with pytest.raises(ExportError) as info:
        run_export(SyntheticSource(12), tmp_path, FORMATS, workers=1)
    message = str(info.value)
    assert "disk is full" in message
    assert "free some space" in message
    assert message.endswith(f"then run it again: {EXPORT_RESUMES}")
    assert info.value.errno == errno.ENOSPC
    assert info.value.path
    assert Path(info.value.path).parent.is_relative_to(tmp_path)
    assert not list(tmp_path.rglob(".*.tmp-*"))  # the failed temporary file is removed
    monkeypatch.setattr(os, "replace", real_replace)
    assert run_export(SyntheticSource(12), tmp_path, FORMATS, workers=1).complete


def test_permission_denied_names_path_and_fix(tmp_path, monkeypatch):
    def deny(*args, **kwargs):
        raise PermissionError(errno.EACCES, "Permission denied", str(tmp_path / "x"))

    monkeypatch.setattr(os, "replace", deny)
    target = tmp_path / "a" / "b.tif"
    with pytest.raises(ExportError, match="permission denied") as info:
        write_tiff(target, np.zeros((2, 2), np.uint16))
    assert str(target) in str(info.value)
    assert "chmod" in str(info.value)
    assert not list(tmp_path.rglob(".*"))


def test_dask_local_cluster_matches_serial(tmp_path, reference):
    """Two worker processes on 127.0.0.1 write the same bytes as a serial run."""
    cloudpickle.register_pickle_by_value(_export_synthetic)
    try:
        seen = []
        report = run_export(
            SyntheticSource(12),
            tmp_path,
            FORMATS,
            workers=2,
            batch_size=2,
            progress=lambda done, total: seen.append(done),
            overlap_start=False,  # every item from the workers
        )
    finally:
        cloudpickle.unregister_pickle_by_value(_export_synthetic)
    assert report.complete
    assert report.workers == 2
    assert report.n_written == 12
    assert seen[0] == 0
    assert seen[-1] == 12
    assert seen == sorted(seen)
    assert tree_digest(tmp_path) == reference


def test_items_written_while_the_workers_start_match_serial(tmp_path, reference, monkeypatch):
    """This process writes items while the cluster starts; the workers do the rest."""
    monkeypatch.setenv("NAPARI_SYMBAC_CLUSTER_START_S", "0")  # start workers for 12 items
    record = tmp_path / "made"
    record.mkdir()
    cloudpickle.register_pickle_by_value(_export_synthetic)
    seen = []
    try:
        report = run_export(
            SyntheticSource(12, record_dir=str(record)),
            tmp_path / "out",
            FORMATS,
            workers=2,
            batch_size=1,
            progress=lambda done, total: seen.append(done),
        )
    finally:
        cloudpickle.unregister_pickle_by_value(_export_synthetic)
    assert report.complete
    assert report.workers == 2
    assert seen == sorted(seen)
    assert seen[-1] == 12
    made = dict(name.split("-") for name in os.listdir(record))
    assert sorted(map(int, made)) == list(range(12))  # each unit made once
    # the first two units are timed here to decide, then more while the workers start
    assert made["0"] == made["1"] == str(os.getpid())
    assert tree_digest(tmp_path / "out") == reference


def test_small_export_runs_in_this_process(tmp_path, reference, monkeypatch):
    """Twelve quick items: starting two workers would cost more than writing them here."""
    monkeypatch.delenv("NAPARI_SYMBAC_CLUSTER_START_S", raising=False)
    report = run_export(SyntheticSource(12), tmp_path, FORMATS, workers=2)
    assert report.complete
    assert report.workers == 1
    assert tree_digest(tmp_path) == reference


def test_cluster_start_setting_is_checked(tmp_path, monkeypatch):
    monkeypatch.setenv("NAPARI_SYMBAC_CLUSTER_START_S", "soon")
    with pytest.raises(ValueError, match="NAPARI_SYMBAC_CLUSTER_START_S='soon' must be a number"):
        run_export(SyntheticSource(4), tmp_path, ["tiff"], workers=2)
    assert not list((tmp_path / "tiff").rglob("*.tif"))  # refused before writing any item


def test_dask_worker_error_reaches_caller(tmp_path):
    cloudpickle.register_pickle_by_value(_export_synthetic)
    try:
        with pytest.raises(RuntimeError, match="injected fault in unit 3"):
            run_export(
                SyntheticSource(6, fail_at=3),
                tmp_path,
                ["tiff"],
                workers=2,
                batch_size=1,
                overlap_start=False,  # the fault happens on a worker
            )
    finally:
        cloudpickle.unregister_pickle_by_value(_export_synthetic)
    report = run_export(SyntheticSource(6), tmp_path, ["tiff"], workers=1)
    assert report.complete
    assert report.n_written >= 1


def test_local_cluster_on_loopback_and_user_scheduler(tmp_path, reference):
    """The default cluster binds 127.0.0.1 with separate processes; a scheduler address
    works with no dask client of the user's in this process (found as a user: `export
    --scheduler` failed with dask's "No clients found" against a real scheduler; this
    test's own client, the default one, had hidden it) and leaves none set as default."""
    from distributed import Client, default_client

    from napari_symbac.export.cluster import local_cluster

    cloudpickle.register_pickle_by_value(_export_synthetic)
    try:
        with local_cluster(2) as cluster:
            with Client(cluster, set_as_default=False) as client:
                assert cluster.scheduler_address.startswith("tcp://127.0.0.1:")
                workers = client.scheduler_info()["workers"]
                assert len(workers) == 2
                assert all(address.startswith("tcp://127.0.0.1:") for address in workers)
                pids = set(client.run(os.getpid).values())
                assert len(pids) == 2
                # without dask's MALLOC_TRIM_THRESHOLD_ (1.6x slower items, cluster.py)
                trim = client.run(lambda: os.environ.get("MALLOC_TRIM_THRESHOLD_"))
                assert set(trim.values()) == {None}
                assert os.getpid() not in pids
            with pytest.raises(ValueError, match="No clients found"):
                default_client()  # as in a user's `napari-symbac export --scheduler`
            # as copied from a browser's address bar (found as a user: "invalid literal
            # for int()")
            report = run_export(
                SyntheticSource(12), tmp_path, FORMATS, scheduler=cluster.scheduler_address + "/"
            )
            with pytest.raises(ValueError, match="No clients found"):
                default_client()  # the export's client was not left as the default
    finally:
        cloudpickle.unregister_pickle_by_value(_export_synthetic)
    assert report.complete
    assert report.workers == 2
    assert tree_digest(tmp_path) == reference


def test_local_cluster_is_quiet_beside_a_running_dask_dashboard():
    """A dashboard (or anything) on port 8787 made the scheduler's HTTP server warn
    "Port 8787 is already in use" into the user's terminal (and the Ctrl-C test's
    stderr); the local cluster serves on a free loopback port instead."""
    import socket
    import warnings

    from distributed import Client

    from napari_symbac.export.cluster import close_quietly, local_cluster

    taken = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    try:
        try:
            taken.bind(("", 8787))
            taken.listen()
        except OSError as err:  # something else holds it already: the same situation
            if err.errno != errno.EADDRINUSE:
                raise
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            cluster = local_cluster(1)
            client = Client(cluster)
            try:
                assert client.submit(sum, [1, 2]).result(timeout=60) == 3
            finally:
                close_quietly(client, cluster)
    finally:
        taken.close()
    assert not [w for w in caught if "already in use" in str(w.message)]


def test_staging_folders_of_killed_runs_are_removed(tmp_path):
    """Found as a user: `kill -9` of calibrate left `.OUT.partial-*` (43 files, 6.7 MB)
    beside --out, and the next run ignored it. The next run of a command that stages
    (fit, calibrate) removes those of processes no longer running, and only those."""
    from napari_symbac.export.atomic import staging_folder
    from napari_symbac.fit.report import write_atomically

    ended = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                           capture_output=True, text=True, check=True)
    dead_pid = int(ended.stdout)
    out = tmp_path / "out"
    killed = tmp_path / f".out.partial-{dead_pid}-k1ll3d"
    (killed / "dataset").mkdir(parents=True)
    (killed / "dataset" / "item.tif").write_bytes(b"half")
    running = staging_folder(out)  # this process's own, still in use
    another = tmp_path / f".other.partial-{dead_pid}-k1ll3d"  # another output's
    another.mkdir()
    written = write_atomically(out, {"report.txt": lambda p: p.write_text("ok")})
    assert [p.name for p in written] == ["report.txt"]
    assert not killed.exists()
    assert running.is_dir()
    assert running.name.startswith(f".out.partial-{os.getpid()}-")
    assert another.is_dir()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [running.name, another.name, "out"]
    )


def test_a_second_export_into_a_folder_being_written_is_refused(tmp_path, reference):
    """Found as a user: two exports into one folder at once (an Export dock beside a
    command line) each computed every item. The second is refused, naming the first,
    and the first completes as if alone."""
    from napari_symbac.export.lock import LOCK

    out = tmp_path / "ds"
    first_started = threading.Event()
    finished = {}

    def progress(done: int, total: int) -> None:
        first_started.set()

    def first() -> None:
        finished["report"] = run_export(
            SyntheticSource(12, delay_s=0.2), out, FORMATS, workers=1, progress=progress
        )

    thread = threading.Thread(target=first)
    thread.start()
    try:
        assert first_started.wait(60)
        with pytest.raises(ExportError, match="another export is writing into") as refused:
            run_export(SyntheticSource(12), out, FORMATS, workers=1)
    finally:
        thread.join(120)
    said = str(refused.value)
    assert f"process {os.getpid()} on " in said
    assert "wait for it to finish, or export to another folder" in said
    assert finished["report"].complete
    assert not (out / LOCK).exists()
    assert tree_digest(out) == reference


def test_the_lock_of_a_killed_export_is_taken_over_and_another_machines_is_named(
    tmp_path, reference
):
    """An export killed (SIGKILL, power cut) leaves its lock: on this machine, its
    process gone, the next export takes it over; a lock from another machine, whose
    process cannot be seen from here, is named with the file to delete."""
    import socket

    from napari_symbac.export.lock import LOCK

    out = tmp_path / "ds"
    out.mkdir()
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait(60)
    lock = {"host": socket.gethostname(), "pid": gone.pid, "started": "2026-12-03 10:00:00"}
    (out / LOCK).write_text(json.dumps(lock))
    assert run_export(SyntheticSource(12), out, FORMATS, workers=1).complete
    assert tree_digest(out) == reference
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / LOCK).write_text(json.dumps({**lock, "host": "cluster-node-7", "pid": 4242}))
    with pytest.raises(ExportError) as refused:
        run_export(SyntheticSource(12), elsewhere, FORMATS, workers=1)
    said = str(refused.value)
    assert "(process 4242 on cluster-node-7, started 2026-12-03 10:00:00)" in said
    assert said.endswith(f"delete {elsewhere / LOCK}")
    assert [p.name for p in elsewhere.iterdir()] == [LOCK]  # nothing else written
