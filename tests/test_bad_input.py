"""The bad-input corpus (issue 13): every case a clear error naming the problem and the fix.

Each case is run as a user would (the ``napari-symbac`` command through ``main``, or the
Python API) and checked for: the message, a non-zero exit code, no traceback, and nothing
half-written. ``docs/export.md`` ("Bad input and faults") lists the same cases as a table.
Faults of the machine (a full disk) are injected with ``monkeypatch``; everything else is
real input.
"""

from __future__ import annotations

import errno
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import tifffile

from napari_symbac.cli import LARGE_RUN_FRAMES, main
from napari_symbac.export import (
    ExportError,
    ExportSettings,
    check_export_folder,
    series_items,
    write_items,
)
from napari_symbac.settings import (
    Microscope,
    PipelineSettings,
    SimulationSettings,
    TrenchGeometry,
    save_settings,
)

TINY = PipelineSettings(simulation=SimulationSettings(n_frames=3))


def _run(argv: list[str], capsys) -> tuple[int, str]:
    """Exit code and stderr of ``napari-symbac ARGV``; argparse errors count as exits."""
    try:
        code = main(argv)
    except SystemExit as exit_info:
        code = exit_info.code
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return code, err


def _files(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*")) if folder.exists() else []


@pytest.fixture
def export_config(tmp_path) -> Path:
    path = tmp_path / "export.yaml"
    save_settings(ExportSettings(n_items=2, formats=["tiff"], pipeline=TINY, val_fraction=0), path)
    return path


@pytest.fixture(scope="module")
def saved_simulation(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("sim") / "simulation"
    assert main(["simulate", "--frames", "3", "--out", str(out)]) == 0
    return out


def _enospc(*_args, **_kwargs):
    raise OSError(errno.ENOSPC, "No space left on device")


# --------------------------------------------------------------------------------------
# export
# --------------------------------------------------------------------------------------


def test_export_to_folder_of_another_export(tmp_path, export_config, capsys):
    out = tmp_path / "dataset"
    image = np.full((1, 8, 8), 100, np.uint16)
    write_items(series_items(image, np.zeros((1, 8, 8), np.uint32)), out, ["tiff"])
    before = _files(out)
    code, err = _run(["export", "--config", str(export_config), "--out", str(out)], capsys)
    assert code == 2
    assert "already holds an export made with different settings" in err
    assert "export to a new folder" in err
    assert _files(out) == before


def test_a_normalised_float_image_is_refused_before_it_is_written_as_zeros_and_ones(tmp_path):
    """Found as a user: frames normalised to 0..1 were written by every format as uint16
    images of 0s and 1s, without a word. Refused when the items are made, naming the
    dtype, the values and the fix; counts in floats are written rounded."""
    frames = np.random.default_rng(0).random((2, 8, 8)).astype(np.float32)
    labels = np.zeros((2, 8, 8), np.uint16)
    with pytest.raises(ValueError, match=r"float32 image of values 0\.00274\.\.0\.997 would") as e:
        series_items(frames, labels)
    assert "written as whole counts 0..1" in str(e.value)
    assert "scale it to counts first" in str(e.value)
    out = tmp_path / "counts"  # one format named alone (was "unknown format 't'")
    write_items(series_items(frames * 4000, labels), out, "tiff")
    written = tifffile.imread(out / "tiff" / "train" / "images" / "s0000_t0001.tif")
    np.testing.assert_array_equal(written, np.rint(frames[1] * 4000).astype(np.uint16))


def test_the_folder_of_another_export_is_refused_by_a_check_that_writes_nothing(tmp_path):
    """The check the Export dock makes before its job (found as a user: the refusal came
    only from the job): the same message as the export's own, nothing written; a missing
    folder passes and stays missing."""
    out = tmp_path / "dataset"
    settings = ExportSettings(n_items=2, formats=["tiff"], pipeline=TINY, val_fraction=0)
    check_export_folder(settings, out)
    assert not out.exists()
    image = np.full((1, 8, 8), 100, np.uint16)
    write_items(series_items(image, np.zeros((1, 8, 8), np.uint32)), out, ["tiff"])
    before = _files(out)
    with pytest.raises(ExportError, match="already holds an export made with different"):
        check_export_folder(settings, out)
    assert _files(out) == before


def test_the_advice_to_resume_with_the_exports_own_settings_can_be_followed(
    tmp_path, export_config, capsys
):
    """Found as a user: "to resume it use its own settings (manifest.json records them)",
    and `export --config DIR/manifest.json` refused the manifest's other fields. The
    advice now gives the command; the manifest is read as the settings it records."""
    import shlex

    out = tmp_path / "dataset"
    code, err = _run(["export", "--config", str(export_config), "--out", str(out)], capsys)
    assert code == 0, err
    other = tmp_path / "other.yaml"
    other.write_text(export_config.read_text().replace("n_items: 2", "n_items: 3"))
    code, err = _run(["export", "--config", str(other), "--out", str(out)], capsys)
    assert code == 2
    command = err.split("`napari-symbac ")[1].split("`")[0]
    assert command == f"export --config {out / 'manifest.json'} --out {out}"
    before = _files(out)
    code, err = _run(shlex.split(command), capsys)
    assert code == 0, err
    assert _files(out) == before
    assert json.loads((out / "manifest.json").read_text())["status"] == "complete"


def test_an_export_whose_validation_split_rounds_to_nothing_says_so(tmp_path, capsys):
    """Found as a user: 2 items at val_fraction 0.1 wrote no val folders and no
    instances_val.json, without a word, and the docs' COCO loader failed on it."""
    config = tmp_path / "export.yaml"
    save_settings(ExportSettings(n_items=2, formats=["coco"], pipeline=TINY), config)
    code, err = _run(["export", "--config", str(config), "--out", str(tmp_path / "d")], capsys)
    assert code == 0
    assert "no validation items: val_fraction 0.1 of 2 item(s) rounds to 0" in err
    assert not (tmp_path / "d" / "coco" / "annotations" / "instances_val.json").exists()
    code, err = _run(
        ["export", "--config", str(config), "--out", str(tmp_path / "e"), "--n-items", "10"],
        capsys,
    )
    assert code == 0
    assert "no validation items" not in err
    assert (tmp_path / "e" / "coco" / "annotations" / "instances_val.json").is_file()


def test_the_no_validation_note_names_coco_only_when_it_is_written():
    """Found as a user: a time series in ctc and trackmate was told of "no
    instances_val.json", a COCO file it was never going to write."""
    from napari_symbac.export.dataset import no_validation_note

    tracks = ExportSettings(n_items=2, kind="timeseries", formats=["ctc", "trackmate"],
                            pipeline=TINY)  # fmt: skip
    assert "(no val folders); export more items" in no_validation_note(tracks)
    coco = ExportSettings(n_items=2, formats=["tiff", "coco"], pipeline=TINY)
    assert "(no val folders, no instances_val.json)" in no_validation_note(coco)


def test_an_export_shortened_below_a_full_trench_says_so(tmp_path, capsys):
    """Found as a user: --n-frames 10 drew every image from frames 5-9 of a 16 um trench,
    2 cells each, while the file's first_frame was 23; nothing said."""
    from napari_symbac.export import export_of

    config = tmp_path / "export.yaml"  # as `napari-symbac defaults export` writes it
    save_settings(export_of(PipelineSettings(), n_items=1, formats=["tiff"]), config)
    argv = ["export", "--config", str(config), "--n-items", "1"]
    code, err = _run([*argv, "--out", str(tmp_path / "short"), "--n-frames", "10"], capsys)
    assert code == 0, err
    assert "--n-frames 10: a run of 10 frames does not fill the 16 um trench" in err
    assert "images are drawn from frames 5-9" in err
    code, err = _run([*argv, "--out", str(tmp_path / "long"), "--n-frames", "50"], capsys)
    assert code == 0, err
    assert "does not fill" not in err


def test_a_pipeline_file_exports_a_tracking_dataset_with_kind(tmp_path, capsys):
    """Found as a user: from a fit's settings.yaml (a pipeline file, no kind) there was no
    way to a tracking dataset: ctc was refused for kind frames, and kind: added to the
    file was an unknown field. `--kind timeseries` sets it."""
    config = tmp_path / "settings.yaml"
    save_settings(TINY, config)
    out = tmp_path / "tracks"
    argv = ["export", "--config", str(config), "--out", str(out), "--n-items", "1"]
    code, err = _run([*argv, "--formats", "ctc"], capsys)
    assert code == 2
    assert "`napari-symbac export --kind timeseries`" in err
    code, err = _run([*argv, "--formats", "ctc", "--kind", "timeseries"], capsys)
    assert code == 0, err
    assert json.loads((out / "manifest.json").read_text())["settings"]["kind"] == "timeseries"
    assert list(out.rglob("man_track.txt"))


def test_a_one_frame_pipeline_exports_a_time_series_with_n_frames(tmp_path, capsys):
    """Found as a user: a field fit's settings.yaml holds 1 frame (its cells as
    recorded), and `export --kind timeseries` was refused with "simulate more frames",
    which no option of export could do."""
    import dataclasses

    config = tmp_path / "settings.yaml"
    one = dataclasses.replace(TINY, simulation=SimulationSettings(n_frames=1))
    save_settings(one, config)
    argv = ["export", "--config", str(config), "--n-items", "1", "--kind", "timeseries"]
    code, err = _run([*argv, "--out", str(tmp_path / "refused")], capsys)
    assert code == 2
    assert "needs pipeline.simulation.n_frames >= 2" in err
    assert "napari-symbac export --n-frames N" in err
    assert not (tmp_path / "refused").exists()
    out = tmp_path / "tracks"
    code, err = _run([*argv, "--formats", "ctc", "--n-frames", "3", "--out", str(out)], capsys)
    assert code == 0, err
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["settings"]["pipeline"]["simulation"]["n_frames"] == 3
    assert len(list(out.rglob("01/t*.tif"))) == 3  # the series' three frames
    code, err = _run([*argv, "--n-frames", "0", "--out", str(tmp_path / "z")], capsys)
    assert code == 2
    assert "--n-frames" in err


def test_n_frames_shortens_the_default_export_whatever_its_kind(tmp_path, capsys):
    """Found as a user: `export --kind timeseries --n-frames 10` of the default pipeline
    (50 frames) was refused: "first_frame=16 must be in [0, n_frames=10)", a field the
    time series does not use, set for the 50 frames and checked before the kind."""
    config = tmp_path / "settings.yaml"
    save_settings(PipelineSettings(), config)  # a trench, 50 frames: images from frame 16
    argv = ["export", "--config", str(config), "--n-items", "1", "--n-frames", "4"]
    for kind in ("timeseries", "frames"):
        out = tmp_path / kind
        code, err = _run([*argv, "--kind", kind, "--out", str(out)], capsys)
        assert code == 0, err
        settings = json.loads((out / "manifest.json").read_text())["settings"]
        assert settings["pipeline"]["simulation"]["n_frames"] == 4
        assert settings["first_frame"] == 2  # the filled trench, at most half the run
    export_file = tmp_path / "export.yaml"  # a first_frame the user chose is kept: refused
    export_file.write_text("first_frame: 30\n")
    code, err = _run(["export", "--config", str(export_file), "--n-frames", "10",
                      "--out", str(tmp_path / "refused")], capsys)  # fmt: skip
    assert code == 2
    assert "--n-frames 10: ExportSettings.first_frame=30 must be in [0, n_frames=10)" in err
    assert not (tmp_path / "refused").exists()


def test_a_pixel_size_in_nm_is_named_and_leaves_no_export_behind(tmp_path, capsys):
    """Found as a user: `pixel_size_um: 65` (nm for um) gave "the field of view is
    smaller than one camera pixel (65.0 um)", naming neither file nor field, and export
    left a manifest.json that refused the corrected rerun as another export."""
    import dataclasses

    from napari_symbac.export import export_dataset

    wrong = dataclasses.replace(TINY, microscope=Microscope(pixel_size_um=65.0))
    config = tmp_path / "export.yaml"
    save_settings(ExportSettings(n_items=2, formats=["tiff"], pipeline=wrong), config)
    out = tmp_path / "dataset"
    code, err = _run(["export", "--config", str(config), "--out", str(out)], capsys)
    assert code == 2
    assert f"pixel size 65 um (microscope.pixel_size_um of settings file {config})" in err
    assert not out.exists()
    # from Python (no such check before it): the first image fails, nothing is left
    with pytest.raises(ValueError, match="smaller than one camera pixel"):
        export_dataset(ExportSettings(n_items=2, pipeline=wrong), out, workers=1)
    assert not out.exists()
    out.mkdir()  # a folder of the user's, empty: kept, and empty again
    with pytest.raises(ValueError, match="smaller than one camera pixel"):
        export_dataset(ExportSettings(n_items=2, pipeline=wrong), out, workers=1)
    assert out.is_dir()
    assert not list(out.iterdir())


def test_export_to_a_folder_of_other_files(tmp_path, export_config, capsys):
    """Found as a user: ``export --out`` a folder of their own files wrote the dataset's
    folders among them."""
    out = tmp_path / "project"
    out.mkdir()
    (out / "notes.txt").write_text("my notes")
    (out / ".hidden").write_text("")  # a hidden file (.DS_Store, a lock) is no objection
    code, err = _run(["export", "--config", str(export_config), "--out", str(out)], capsys)
    assert code == 2
    assert "holds other files (notes.txt) and no manifest.json" in err
    assert "empty or new folder" in err
    assert sorted(p.name for p in out.iterdir()) == [".hidden", "notes.txt"]


def test_export_out_is_a_file(tmp_path, export_config, capsys):
    out = tmp_path / "dataset.tif"
    out.write_bytes(b"not a folder")
    code, err = _run(["export", "--config", str(export_config), "--out", str(out)], capsys)
    assert code == 2
    assert "is a file, not a folder" in err
    assert "finished items" not in err  # nothing was written: nothing to resume
    assert out.read_bytes() == b"not a folder"


@pytest.mark.parametrize("workers", ["0", "-1", "two"])
def test_export_workers_below_one(tmp_path, export_config, workers, capsys):
    out = tmp_path / "dataset"
    code, err = _run(
        ["export", "--config", str(export_config), "--out", str(out), "--workers", workers],
        capsys,
    )
    assert code == 2
    assert "--workers" in err
    assert ">= 1" in err or "at least 1" in err
    assert not out.exists()


def test_export_workers_capped_to_cores(tmp_path, export_config, monkeypatch, capsys):
    monkeypatch.setattr(os, "cpu_count", lambda: 1)
    out = tmp_path / "dataset"
    code = main(
        ["export", "--config", str(export_config), "--out", str(out), "--workers", "1000"]
    )
    captured = capsys.readouterr()
    assert code == 0
    assert "--workers 1000 capped to 1" in captured.err
    assert "with 1 worker(s)" in captured.out


@pytest.mark.parametrize("workers", [0, -1, 2.5, True])
def test_api_workers_below_one(tmp_path, workers):
    from napari_symbac.export import export_dataset

    settings = ExportSettings(n_items=1, formats=["tiff"], pipeline=TINY)
    with pytest.raises(ValueError, match=r"workers must be an integer >= 1"):
        export_dataset(settings, tmp_path / "dataset", workers=workers)
    assert not (tmp_path / "dataset").exists()


def test_export_scheduler_that_does_not_answer(tmp_path, export_config, monkeypatch, capsys):
    from napari_symbac.export import cluster

    monkeypatch.setattr(cluster, "SCHEDULER_TIMEOUT_S", 2.0)
    out = tmp_path / "dataset"
    start = time.monotonic()
    code, err = _run(
        [
            "export",
            "--config",
            str(export_config),
            "--out",
            str(out),
            "--scheduler",
            "tcp://127.0.0.1:9",  # the discard port: nothing listens
        ],
        capsys,
    )
    assert code == 2
    assert "no dask scheduler answered at tcp://127.0.0.1:9 within 2 s" in err
    assert "nothing was written" in err
    assert not out.exists()
    assert time.monotonic() - start < 60  # not the 30 s default per attempt, retried


def test_export_scheduler_address_where_no_dask_server_listens(
    tmp_path, export_config, monkeypatch, capsys
):
    """Found as a user: an HTTP server at the address (a dashboard's port) held export
    for over 11 minutes, and an http:// address stalled 20 s before a traceback."""
    import http.server
    import threading

    from napari_symbac.export import cluster

    monkeypatch.setattr(cluster, "SCHEDULER_TIMEOUT_S", 2.0)
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), http.server.BaseHTTPRequestHandler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        address = f"tcp://127.0.0.1:{server.server_address[1]}"
        out = tmp_path / "dataset"
        start = time.monotonic()
        code, err = _run(
            ["export", "--config", str(export_config), "--out", str(out), "--scheduler", address],
            capsys,
        )
        assert code == 2
        assert f"no dask scheduler answered at {address} within 2 s" in err
        assert "not its dashboard's" in err
        assert "Traceback" not in err
        assert not out.exists()
        assert time.monotonic() - start < 60
    finally:
        server.shutdown()
    code, err = _run(
        ["export", "--config", str(export_config), "--out", str(out), "--scheduler",
         "http://localhost:8786"],
        capsys,
    )  # fmt: skip
    assert code == 2  # refused by its scheme, before any connection
    assert "'http://localhost:8786' is not a dask address (unknown scheme 'http'" in err
    assert not out.exists()


def test_export_scheduler_that_answers_bytes_dask_cannot_read(
    tmp_path, export_config, monkeypatch, capsys
):
    """Found as a user: a server answering bytes that dask reads as a frame of exabytes
    was refused as "something answered that is not dask: MemoryError", which reads as our
    own memory running out. Its words say that the reply is not dask's protocol."""
    import socket
    import threading

    from napari_symbac.export import cluster

    monkeypatch.setattr(cluster, "SCHEDULER_TIMEOUT_S", 5.0)
    listener = socket.create_server(("127.0.0.1", 0))
    connections = []

    def answer() -> None:
        while True:
            try:
                connection, _ = listener.accept()
            except OSError:
                return
            connections.append(connection)
            connection.sendall(b"\xff" * 64)  # a frame header of 2**64 - 1 bytes

    threading.Thread(target=answer, daemon=True).start()
    address = f"tcp://127.0.0.1:{listener.getsockname()[1]}"
    out = tmp_path / "dataset"
    try:
        code, err = _run(["export", "--config", str(export_config), "--out", str(out),
                          "--scheduler", address], capsys)  # fmt: skip
    finally:
        listener.close()
        for connection in connections:
            connection.close()
    assert code == 2
    assert "not a dask scheduler, its reply unreadable as dask's protocol" in err
    assert "Traceback" not in err
    assert not out.exists()


def test_export_scheduler_address_that_is_not_one(tmp_path, export_config, capsys):
    out = tmp_path / "dataset"
    code, err = _run(
        ["export", "--config", str(export_config), "--out", str(out), "--scheduler", "nohost"],
        capsys,
    )
    assert code == 2
    assert "the scheduler address 'nohost' is not a dask address" in err
    assert "tcp://10.0.0.5:8786" in err
    assert not out.exists()


def test_export_disk_full_names_path(tmp_path, export_config, monkeypatch, capsys):
    monkeypatch.setattr(tifffile, "imwrite", _enospc)
    out = tmp_path / "dataset"
    code, err = _run(
        ["export", "--config", str(export_config), "--out", str(out), "--workers", "1"], capsys
    )
    assert code == 2
    assert "disk is full" in err
    assert str(out / "tiff") in err
    assert not list(out.rglob("*.tif"))


@pytest.mark.parametrize(
    ("code", "message"),
    [
        (errno.EACCES, "permission denied while writing"),
        (errno.EROFS, "is on a read-only file system: choose an output folder on a writable"),
        (errno.EDQUOT, "the disk is full"),
        (errno.EIO, "could not write"),
    ],
)
def test_export_write_errors_name_path_and_fix(
    tmp_path, export_config, monkeypatch, capsys, code, message
):
    def refuse(*_args, **_kwargs):
        raise OSError(code, os.strerror(code))

    monkeypatch.setattr(tifffile, "imwrite", refuse)
    out = tmp_path / "dataset"
    exit_code, err = _run(
        ["export", "--config", str(export_config), "--out", str(out), "--workers", "1"], capsys
    )
    assert exit_code == 2
    assert message in err
    assert str(out / "tiff") in err
    assert "run it again: the export keeps its finished items" in err
    assert err.count("\n") == 1  # one line
    assert not list(out.rglob("*.tif"))


def test_export_huge_run_asks_for_yes(tmp_path, capsys):
    config = tmp_path / "export.yaml"
    save_settings(ExportSettings(n_items=LARGE_RUN_FRAMES + 1, formats=["tiff"]), config)
    out = tmp_path / "dataset"
    code, err = _run(["export", "--config", str(config), "--out", str(out)], capsys)
    assert code == 2
    assert "add --yes to start it anyway" in err
    assert not out.exists()


@pytest.mark.slow
def test_ctrl_c_during_multi_worker_export(tmp_path):
    """Ctrl-C (SIGINT to the whole process group, as a terminal sends it): one line, 130."""
    config = tmp_path / "export.yaml"
    save_settings(
        ExportSettings(n_items=300, formats=["tiff"], pipeline=TINY, val_fraction=0), config
    )
    out = tmp_path / "dataset"
    command = [sys.executable, "-m", "napari_symbac.cli", "export", "--config", str(config)]
    # The command must start as from a terminal, taking Ctrl-C. A test run started as a
    # background job of a script (`pytest ... &`) has SIGINT ignored, and every child
    # inherits that: the export then rightly ignored the interrupt and ran to its end
    # (seen twice in such runs). A handled SIGINT is reset to the default in the child.
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        process = subprocess.Popen(
            [*command, "--out", str(out), "--workers", "2"],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            start_new_session=True,
            # start the workers however quick the items (300 tiny ones would stay in one
            # process)
            env={**os.environ, "NAPARI_SYMBAC_CLUSTER_START_S": "0"},
        )
    finally:
        signal.signal(signal.SIGINT, previous)
    items = out / "manifest_items"

    def finished() -> int:
        """Items written: their entries, not the hidden temporaries of one in progress
        (counted, an interrupt that removed one left 3 where 4 had been seen)."""
        return sum(not name.startswith(".") for name in os.listdir(items))

    try:
        while not (items.is_dir() and finished() >= 4):
            assert process.poll() is None, process.communicate()
            time.sleep(0.05)
        os.killpg(process.pid, signal.SIGINT)
        _stdout, stderr = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
    assert process.returncode == 130, stderr
    lines = [line for line in stderr.splitlines() if line.strip()]
    # piped, the progress comes as lines ("napari-symbac export: 40 of 300 images")
    progress = re.compile(r"napari-symbac export: \d+ of 300 images")
    lines = [line for line in lines if not progress.fullmatch(line)]
    assert lines == [
        "napari-symbac export: interrupted; the items finished so far are kept (an export "
        "resumes when run again)"
    ]
    done = finished()
    assert 4 <= done < 300
    resumed = subprocess.run(
        [*command, "--out", str(out), "--workers", "1"], capture_output=True, text=True
    )
    assert resumed.returncode == 0, resumed.stderr
    assert "complete; 300 images" in resumed.stdout
    assert f"{300 - done} written, {done} already there" in resumed.stdout


# --------------------------------------------------------------------------------------
# render, demo, simulate
# --------------------------------------------------------------------------------------


def test_render_disk_full_leaves_no_partial_file(
    tmp_path, saved_simulation, monkeypatch, capsys
):
    monkeypatch.setattr(tifffile, "imwrite", _enospc)
    out = tmp_path / "rendered"
    code, err = _run(["render", str(saved_simulation), "--out", str(out)], capsys)
    assert code == 2
    assert "disk is full" in err
    assert str(out / "images.tif") in err
    assert not out.exists()  # nor an empty --out it made (found as a user)
    # render starts over: no export's resume advice (found as a user)
    assert "finished items" not in err
    assert err.rstrip().endswith("then run it again")


def test_render_out_is_a_file(tmp_path, saved_simulation, capsys):
    out = tmp_path / "rendered"
    out.write_text("x")
    code, err = _run(["render", str(saved_simulation), "--out", str(out)], capsys)
    assert code == 2
    assert "--out" in err
    assert "is a file, not a folder" in err


def test_demo_disk_full_leaves_no_folder(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(tifffile, "imwrite", _enospc)
    out = tmp_path / "demo"
    code, err = _run(["demo", "--out", str(out), "--frames", "2"], capsys)
    assert code == 2
    assert "disk is full" in err
    assert "dataset" in err
    assert not out.exists()
    # said as it is (found as a user: "the export keeps its finished items and
    # completes the rest" of a folder that was removed)
    assert "completes the rest" not in err
    assert f"the demo's folder {out} was removed; run the demo again" in err


@pytest.mark.parametrize("command", ["demo", "simulate"])
def test_frames_below_one(tmp_path, command, capsys):
    code, err = _run([command, "--out", str(tmp_path / "x"), "--frames", "0"], capsys)
    assert code == 2
    assert "--frames: must be at least 1, got 0" in err


def test_simulate_huge_run_asks_for_yes(tmp_path, capsys):
    out = tmp_path / "simulation"
    code, err = _run(["simulate", "--frames", "10000000", "--out", str(out)], capsys)
    assert code == 2
    assert "10,000,000" in err
    assert "add --yes" in err
    assert not out.exists()


def test_yes_starts_a_large_run(tmp_path, monkeypatch, capsys):
    from napari_symbac import cli

    monkeypatch.setattr(cli, "LARGE_RUN_FRAMES", 2)
    out = tmp_path / "simulation"
    code, err = _run(["simulate", "--frames", "3", "--out", str(out)], capsys)
    assert code == 2
    assert "add --yes" in err
    assert main(["simulate", "--frames", "3", "--out", str(out), "--yes"]) == 0
    assert (out / "simulation.json").is_file()


def test_simulate_huge_config_asks_for_yes(tmp_path, capsys):
    config = tmp_path / "simulation.yaml"
    config.write_text("n_frames: 10000000\n")
    code, err = _run(["simulate", "--config", str(config), "--out", str(tmp_path / "s")], capsys)
    assert code == 2
    assert "add --yes" in err


@pytest.mark.parametrize("text", ["", "\n", "# only a comment\n"])
def test_empty_config_is_an_error(tmp_path, text, capsys):
    config = tmp_path / "simulation.yaml"
    config.write_text(text)
    out = tmp_path / "simulation"
    code, err = _run(["simulate", "--config", str(config), "--out", str(out)], capsys)
    assert code == 2
    assert f"settings file {config} is empty" in err
    assert "napari-symbac defaults" in err
    assert not out.exists()


def test_config_that_is_a_folder(tmp_path, capsys):
    code, err = _run(["simulate", "--config", str(tmp_path), "--out", "x"], capsys)
    assert code == 2
    assert f"settings file {tmp_path} is a folder" in err


def test_unwritable_output_names_path_and_fix(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    out = blocker / "demo"  # a folder inside a file cannot be made
    code, err = _run(["demo", "--out", str(out), "--frames", "2"], capsys)
    assert code == 2
    assert str(out) in err
    assert "check that the path is right" in err
    assert blocker.read_text() == "x"


def test_missing_config_names_file(tmp_path, capsys):
    config = tmp_path / "nope.yaml"
    code, err = _run(["export", "--config", str(config), "--out", str(tmp_path / "d")], capsys)
    assert code == 2
    assert f"settings file {config} does not exist" in err


def test_config_with_wrong_type_for_nested_settings(tmp_path, capsys):
    config = tmp_path / "simulation.yaml"
    config.write_text("trench: 5\n")
    code, err = _run(["simulate", "--config", str(config), "--out", str(tmp_path / "s")], capsys)
    assert code == 2
    assert "SimulationSettings.trench must be a mapping of TrenchGeometry fields, got 5" in err


# --------------------------------------------------------------------------------------
# Files
# --------------------------------------------------------------------------------------


@pytest.fixture
def truncated_tiff(tmp_path) -> Path:
    path = tmp_path / "movie.tif"
    tifffile.imwrite(path, np.zeros((4, 32, 32), np.uint16), imagej=True)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    return path


def test_truncated_tiff_names_the_file(truncated_tiff):
    from napari_symbac.io import read_recording

    with pytest.raises(ValueError, match="is truncated") as info:
        read_recording(truncated_tiff)
    assert str(truncated_tiff) in str(info.value)
    assert "copy or download it again" in str(info.value)


def test_truncated_tiff_through_the_reader(truncated_tiff):
    from napari_symbac.io import napari_get_reader

    reader = napari_get_reader(str(truncated_tiff))
    with pytest.raises(ValueError, match=str(truncated_tiff).replace("\\", "\\\\")):
        reader(str(truncated_tiff))


def test_not_a_tiff_names_the_file(tmp_path):
    from napari_symbac.io import read_recording

    path = tmp_path / "notes.tif"
    path.write_text("hello")
    with pytest.raises(ValueError, match="is not a readable TIFF") as info:
        read_recording(path)
    assert str(path) in str(info.value)


# --------------------------------------------------------------------------------------
# API types
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (
            lambda: SimulationSettings(trench={"width_um": 2.0}),
            r"SimulationSettings\.trench must be a TrenchGeometry, got dict",
        ),
        (
            lambda: PipelineSettings(simulation={"n_frames": 5}),
            r"PipelineSettings\.simulation must be a SimulationSettings",
        ),
        (
            lambda: ExportSettings(pipeline={"simulation": {}}),
            r"ExportSettings\.pipeline must be a PipelineSettings",
        ),
    ],
)
def test_nested_settings_given_as_mappings(make, message):
    with pytest.raises(TypeError, match=message) as info:
        make()
    assert "from_dict" in str(info.value)


def test_nested_settings_from_dict_still_work():
    from napari_symbac.settings import from_dict

    settings = from_dict(SimulationSettings, {"trench": {"width_um": 2.0}})
    assert settings.trench == TrenchGeometry(width_um=2.0)


def test_simulate_with_an_int_rng():
    from napari_symbac.sim import simulate

    with pytest.raises(TypeError, match=r"numpy\.random\.Generator, got int 5") as info:
        simulate(SimulationSettings(n_frames=2), rng=5)
    assert "default_rng(5)" in str(info.value)
    with pytest.raises(TypeError, match=r"got RandomState: pass numpy\.random\.default_rng\(seed"):
        simulate(SimulationSettings(n_frames=2), rng=np.random.RandomState(0))


def test_export_dataset_of_a_pipelines_settings_names_export_of(tmp_path):
    """Found as an API user: ``export_dataset(PipelineSettings(), out)`` raised
    "AttributeError: 'PipelineSettings' object has no attribute 'formats'"."""
    from napari_symbac.export import export_dataset

    with pytest.raises(TypeError, match=r"got PipelineSettings: pass export_of\(pipeline\)"):
        export_dataset(PipelineSettings(), tmp_path / "ds")
    assert not (tmp_path / "ds").exists()


def test_a_simulation_is_shown_in_one_line():
    """Found as an API user: a notebook cell ending in a 200-frame simulation printed
    135 KB of arrays."""
    from napari_symbac.sim import simulate

    simulation = simulate(SimulationSettings(n_frames=20))
    said = repr(simulation)
    assert said.startswith("Simulation(trench, 20 frames, ")
    assert f"{len(simulation.lineage)} cells over the run" in said
    assert "\n" not in said


def test_simulate_with_settings_of_the_wrong_type():
    from napari_symbac.sim import simulate

    with pytest.raises(TypeError, match="simulate\\(\\) needs SimulationSettings, got dict"):
        simulate({"n_frames": 2})


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ((None, PipelineSettings()), "render needs a Simulation, got NoneType"),
        (("sim", PipelineSettings()), "render needs a Simulation, got str"),
    ],
)
def test_render_simulation_with_wrong_types(args, message):
    from napari_symbac.pipeline import render_simulation

    with pytest.raises(TypeError, match=message):
        render_simulation(*args)


def test_render_simulation_with_wrong_settings_and_rng():
    from napari_symbac.pipeline import render_simulation
    from napari_symbac.sim import simulate

    simulation = simulate(SimulationSettings(n_frames=1))
    with pytest.raises(TypeError, match="render needs PipelineSettings, got dict"):
        render_simulation(simulation, {})
    with pytest.raises(TypeError, match=r"rng must be a numpy\.random\.Generator, got int"):
        render_simulation(simulation, PipelineSettings(), rng=3)


def test_render_simulation_draws_the_simulations_own_trench():
    """Found as an API user: settings of a 10 um trench rendered a 16 um trench's
    simulation in frames 166 px tall instead of 258, its lower cells cut off. The
    simulation's own settings draw it (as ``napari-symbac render`` does), the same bit
    for bit whichever simulation section the pipeline settings hold."""
    from napari_symbac.pipeline import render_simulation
    from napari_symbac.settings import TrenchGeometry
    from napari_symbac.sim import simulate

    simulation = simulate(SimulationSettings(n_frames=3))
    own = render_simulation(simulation, PipelineSettings(simulation=simulation.settings))
    short = SimulationSettings(n_frames=3, seed=5, trench=TrenchGeometry(length_um=10.0))
    other = render_simulation(simulation, PipelineSettings(simulation=short))
    assert other.images.shape == own.images.shape
    assert own.images.shape[1] > 16.0 / PipelineSettings().microscope.pixel_size_um
    np.testing.assert_array_equal(other.images, own.images)
    np.testing.assert_array_equal(other.labels, own.labels)
    assert short.seed != simulation.settings.seed  # the noise follows the simulation's seed


# --------------------------------------------------------------------------------------
# fit, calibrate, diagnose: inputs and --out checked before the work
# --------------------------------------------------------------------------------------


@pytest.fixture
def fit_inputs(tmp_path) -> tuple[Path, Path]:
    """A noisy 64 x 32 frame of camera counts and a microscope file of one key."""
    image = tmp_path / "frame.tif"
    tifffile.imwrite(image, np.random.default_rng(0).poisson(500, (64, 32)).astype(np.uint16))
    microscope = tmp_path / "m65.yaml"
    microscope.write_text("pixel_size_um: 0.065\n")
    return image, microscope


FIT_COMMANDS = ["fit", "calibrate", "diagnose"]


@pytest.mark.parametrize("command", FIT_COMMANDS)
def test_fit_out_that_is_a_file_is_refused_before_the_fit(
    tmp_path, fit_inputs, command, capsys
):
    image, microscope = fit_inputs
    out = tmp_path / "afile"
    out.write_text("x")
    code, err = _run([command, str(image), "--microscope", str(microscope), "--out", str(out)],
                     capsys)  # fmt: skip
    assert code == 2
    # refused up front: the fit of this noise would have stopped on its own refusal
    assert f"--out {out} is a file, not a folder: give the path of a folder" in err
    assert "no cells" not in err
    assert "File exists" not in err
    assert out.read_text() == "x"


@pytest.mark.parametrize("command", FIT_COMMANDS)
def test_fit_out_inside_a_file_is_refused_before_the_fit(tmp_path, fit_inputs, command, capsys):
    image, microscope = fit_inputs
    blocker = tmp_path / "afile"
    blocker.write_text("x")
    out = blocker / "result"
    code, err = _run([command, str(image), "--microscope", str(microscope), "--out", str(out)],
                     capsys)  # fmt: skip
    assert code == 2
    assert f"--out {out} cannot be created: {blocker} is a file, not a folder" in err
    assert ".partial-" not in err


@pytest.mark.parametrize(
    ("command", "code", "fix"),
    [
        ("fit", errno.EACCES, "give yourself write permission on it"),
        ("calibrate", errno.EACCES, "give yourself write permission on it"),
        ("diagnose", errno.EROFS, "give a folder on a writable disk"),
        ("render", errno.EACCES, "give yourself write permission on it"),
        ("render", errno.ENOENT, "give a folder on a writable disk"),  # /proc: no files there
    ],
)
def test_out_in_a_read_only_folder_is_refused_up_front(
    tmp_path, fit_inputs, saved_simulation, monkeypatch, capsys, command, code, fix
):
    """A read-only folder (injected: the tests run as root, whom permissions do not stop)
    is named with the --out it blocks, not as a hidden temporary name after the work."""
    import tempfile

    image, microscope = fit_inputs
    read_only = tmp_path / "ro"
    read_only.mkdir()
    temporary_file = tempfile.TemporaryFile

    def refuse(*args, **kwargs):
        # only there: numba's cache, set up when a command first imports the raster
        # module, probes its own folder with a temporary file too
        if Path(kwargs.get("dir") or ".").resolve().is_relative_to(read_only.resolve()):
            raise OSError(code, os.strerror(code))
        return temporary_file(*args, **kwargs)

    out = read_only / "x"
    monkeypatch.setattr(tempfile, "TemporaryFile", refuse)
    inputs = [str(saved_simulation)] if command == "render" else [
        str(image), "--microscope", str(microscope)
    ]  # fmt: skip
    exit_code, err = _run([command, *inputs, "--out", str(out)], capsys)
    assert exit_code == 2
    assert f"--out {out} cannot be created: {read_only} is not writable" in err
    assert fix in err
    assert ("chmod" in err) == (code == errno.EACCES)  # permissions only when they are the cause
    assert "partial" not in err
    assert "finished items" not in err  # render, fit: no resume
    assert err.count("\n") == 1
    assert _files(read_only) == []


@pytest.mark.parametrize(
    ("command", "option"),
    [("fit", None), ("fit", "--masks"), ("calibrate", None), ("diagnose", "--labels")],
)
def test_image_that_is_a_folder(tmp_path, fit_inputs, capsys, command, option):
    image, microscope = fit_inputs
    folder = tmp_path / "images"
    folder.mkdir()
    args = [command, str(folder if option is None else image), "--microscope", str(microscope)]
    if option is not None:
        args += [option, str(folder)]
    code, err = _run([*args, "--out", str(tmp_path / "o")], capsys)
    assert code == 2
    what = "IMAGE" if option is None else option
    assert f"{what} {folder} is a folder: give the path of an image file (TIFF or PNG)" in err
    assert "does not exist" not in err


def test_diagnose_fills_the_microscope_file_as_fit_does(tmp_path, fit_inputs, capsys):
    """A microscope file of pixel_size_um only: the other keys take the defaults (the
    negative image is then refused, after the microscope file was read, and, as diagnose
    has no --camera, the refusal says where its camera goes)."""
    _, microscope = fit_inputs
    image = tmp_path / "negative.tif"
    tifffile.imwrite(image, np.random.default_rng(0).normal(0, 5, (64, 32)).astype(np.float32))
    code, err = _run(["diagnose", str(image), "--microscope", str(microscope),
                      "--out", str(tmp_path / "o")], capsys)  # fmt: skip
    assert code == 2
    assert "lacks the required key" not in err
    assert "negative values" in err
    assert "baseline_adu in the microscope file's camera section (camera: {" in err
    assert "--camera" not in err


def test_diagnose_names_an_unknown_microscope_key(tmp_path, fit_inputs, capsys):
    image, _ = fit_inputs
    microscope = tmp_path / "typo.yaml"
    microscope.write_text("pxel_size_um: 0.065\n")
    code, err = _run(["diagnose", str(image), "--microscope", str(microscope),
                      "--out", str(tmp_path / "o")], capsys)  # fmt: skip
    assert code == 2
    assert "unknown field(s) pxel_size_um in Microscope" in err
    assert "pixel_size_um" in err.split("valid fields are:")[1]
    # found as a user: the name meant was not singled out of the valid ones
    assert "(did you mean pxel_size_um -> pixel_size_um?)" in err


def test_diagnose_checks_the_image_before_the_microscope_file(tmp_path, capsys):
    image = tmp_path / "missing.tif"
    code, err = _run(["diagnose", str(image), "--microscope", str(tmp_path / "nope.yaml"),
                      "--out", str(tmp_path / "o")], capsys)  # fmt: skip
    assert code == 2
    assert f"IMAGE {image} does not exist" in err


def test_diagnose_microscope_file_of_microscope_fields_with_a_camera(tmp_path):
    from napari_symbac.diagnose.config import load_microscope_file
    from napari_symbac.settings import Microscope

    path = tmp_path / "m.yaml"
    path.write_text(
        "pixel_size_um: 0.08\ncondenser: Ph2\n"
        "camera: {baseline_adu: 100, sensitivity_adu_per_e: 2.9, dark_noise_e: 8}\n"
        "trench_width_um: 1.4\n"
    )
    config = load_microscope_file(path)
    assert config.microscope == Microscope(pixel_size_um=0.08, condenser="Ph2")
    assert config.camera.baseline_adu == 100
    assert config.camera.sensitivity_adu_per_e == 2.9
    assert config.trench_width_um == 1.4


def test_without_a_microscope_file_the_note_names_the_condenser_for_phase_only():
    """Found as a user: a fluorescence fit without --microscope was told of a Ph3
    condenser, which a fluorescence image never passes through."""
    from napari_symbac.diagnose.config import load_microscope_file

    defaulted = load_microscope_file(None)
    (phase,) = defaulted.notes_for("phase")
    (fluorescence,) = defaulted.notes_for("fluorescence")
    assert "default optics (NA 1.45" in phase
    assert "condenser Ph3" in phase
    assert "default optics (NA 1.45" in fluorescence
    assert "condenser" not in fluorescence

def test_a_microscope_file_given_adds_no_default_optics_note(tmp_path):
    from napari_symbac.diagnose.config import load_microscope_file

    path = tmp_path / "m.yaml"
    path.write_text("pixel_size_um: 0.08\n")
    assert load_microscope_file(path).notes_for("phase") == ()


def test_fit_negative_values_still_point_to_camera_option():
    from napari_symbac.fit.preflight import check_fit_image

    with pytest.raises(ValueError, match="give that constant as baseline_adu with --camera"):
        check_fit_image(np.kron([[-1.0, 2.0]], np.ones((8, 8))), "frame.tif")


@pytest.mark.parametrize("option", ["--microscope", "--config"])
def test_settings_file_that_is_binary(tmp_path, fit_inputs, capsys, option):
    image, microscope = fit_inputs
    settings = {"--microscope": str(microscope), option: str(image)}  # the TIFF as settings
    args = [arg for pair in settings.items() for arg in pair]
    code, err = _run(["fit", str(image), *args, "--out", str(tmp_path / "o")], capsys)
    assert code == 2
    assert f"settings file {image} is not a YAML/JSON text file" in err
    assert "codec" not in err


def test_diagnose_microscope_file_that_is_binary(tmp_path, fit_inputs, capsys):
    image, _ = fit_inputs
    code, err = _run(["diagnose", str(image), "--microscope", str(image),
                      "--out", str(tmp_path / "o")], capsys)  # fmt: skip
    assert code == 2
    assert f"settings file {image} is not a YAML/JSON text file" in err


def test_calibrate_cell_width_below_zero_names_the_option(tmp_path, fit_inputs, capsys):
    image, microscope = fit_inputs
    code, err = _run(["calibrate", str(image), "--microscope", str(microscope),
                      "--out", str(tmp_path / "o"), "--cell-width-um", "-1"], capsys)  # fmt: skip
    assert code == 2
    assert "--cell-width-um must be positive, got -1.0" in err
    assert "cell_width_um" not in err
    # found as a user: 1000 (nm) went on to "cells not brighter than the background"
    code, err = _run(["calibrate", str(image), "--microscope", str(microscope),
                      "--out", str(tmp_path / "o"), "--cell-width-um", "1000"], capsys)  # fmt: skip
    assert code == 2
    assert "--cell-width-um 1000 is outside 0.2-5 um" in err


def test_calibrate_masks_of_the_wrong_shape_named_as_fit_names_them(
    tmp_path, fit_inputs, capsys
):
    image, microscope = fit_inputs
    wrong = tmp_path / "wrong.tif"
    masks = np.zeros((60, 32), np.uint16)
    masks[10:20, 10:20] = 1
    tifffile.imwrite(wrong, masks)
    code, err = _run(["calibrate", str(image), "--microscope", str(microscope),
                      "--out", str(tmp_path / "o"), "--masks", str(wrong)], capsys)  # fmt: skip
    assert code == 2
    assert "--masks wrong.tif has shape (60, 32) but the image frame has shape (64, 32)" in err


@pytest.mark.parametrize("command", ["fit", "calibrate"])
def test_the_recording_given_as_its_masks_is_refused(tmp_path, fit_inputs, capsys, command):
    """Found as a user: a fluorescence crop passed as its own --masks was fitted as 929
    cells for over 5 min (fit) or refused after 100 s for masks that "cover the image"
    (calibrate). Refused before any fit, naming what masks are."""
    image, microscope = fit_inputs
    out = tmp_path / "o"
    code, err = _run([command, str(image), "--microscope", str(microscope), "--out", str(out),
                      "--masks", str(image)], capsys)  # fmt: skip
    assert code == 2
    assert f"--masks {image.name} does not look like instance masks" in err
    assert "separate patches" in err
    assert "fitting frame" not in err  # refused before the fit began
    assert not out.exists()


def test_fit_scene_refuses_an_image_as_masks_and_takes_real_masks(real_data_dir):
    """The API refuses as the commands do; the real instance masks here (Omnipose's,
    ColiCoords') pass the check: one patch per id."""
    from napari_symbac.fit import fit_scene
    from napari_symbac.fit.preflight import refuse_image_as_masks
    from napari_symbac.settings import Microscope, RenderSettings

    image = tifffile.imread(real_data_dir / "colicoords/test_data/ds1/fluorescence/00001.tif")
    crop = image[100:210, 100:360]
    with pytest.raises(ValueError, match="does not look like instance masks"):
        fit_scene(crop, Microscope(pixel_size_um=0.08, modality="fluorescence"),
                  RenderSettings(), masks=crop)  # fmt: skip
    for path in sorted((real_data_dir / "omnipose").glob("*_cp_masks.tif")):
        refuse_image_as_masks(tifffile.imread(path), path.name)
    masks = real_data_dir / "colicoords/test_data/ds1/binary/00001_Probabilities_filtered.tif"
    refuse_image_as_masks(tifffile.imread(masks), masks.name)


def test_the_api_refuses_what_the_command_line_refuses_before_a_fit(real_data_dir):
    """Found as an API user: fit_scene and calibrate skipped the commands' checks. A
    camera offset of 3000 ADU fitted 2 cells of 4 (reduced chi-square 3350), the trench
    on its side was "4 trenches side by side", 65 um (for 65 nm) gave "5329 cells 909 um
    wide", and calibrate made agar-pad settings of the trench without a word; a stack
    was "masks of another shape" and ``microscope=None`` an AttributeError."""
    from napari_symbac.calibrate import calibrate
    from napari_symbac.fit import fit_scene
    from napari_symbac.settings import Camera, Microscope, RenderSettings

    trench = tifffile.imread(real_data_dir / "ecoli_100x_oil_exponential.tiff")
    scope = Microscope(pixel_size_um=0.065)
    with pytest.raises(ValueError, match=r"fit_scene\(camera=\.\.\.\): its offset 3000 ADU"):
        fit_scene(trench, scope, RenderSettings(), Camera(baseline_adu=3000))
    with pytest.raises(ValueError, match=r"real_image is 46 x 256 px .* rotate it by 90"):
        fit_scene(np.rot90(trench), scope, RenderSettings())
    with pytest.raises(ValueError, match=r"in nm\? 65 nm is 0\.065 um"):
        fit_scene(trench, Microscope(pixel_size_um=65), RenderSettings())
    with pytest.raises(ValueError, match="a mother-machine trench; calibrate lays out fields"):
        calibrate(trench, microscope=scope)
    with pytest.raises(ValueError, match=r"calibrate\(image=\.\.\.\) takes one 2D frame"):
        calibrate(np.stack([trench, trench]), microscope=scope)
    with pytest.raises(TypeError, match=r"calibrate\(microscope=\.\.\.\) needs Microscope"):
        calibrate(trench, microscope=None)
    # DeLTA's normalised trench (floats, some below 0): as_counts named first
    delta = tifffile.imread(real_data_dir / "ecoli_delta_phase_normalised.tiff")
    with pytest.raises(ValueError, match="has negative values") as refused:
        fit_scene(delta, scope, RenderSettings())
    said = str(refused.value)
    assert said.index("napari_symbac.io.as_counts") < said.index("add a constant")


def test_masks_are_told_from_recordings(real_data_dir):
    """looks_like_masks, which keeps a masks file opened as an image out of the docks'
    recordings: every masks file here is masks, every recording (8 and 16 bit, with the
    background-subtraction zeros of ColiCoords' fluorescence) is not."""
    from napari_symbac.fit.preflight import looks_like_masks
    from napari_symbac.io import read_image

    masks = [*(real_data_dir / "omnipose").glob("*_cp_masks.tif"),
             *(real_data_dir / "colicoords" / "test_data").glob("*/binary*")]  # fmt: skip
    for path in masks:
        paths = sorted(path.glob("*.tif")) if path.is_dir() else [path]
        assert all(looks_like_masks(tifffile.imread(p)) for p in paths), path
    recordings = [*(real_data_dir / "omnipose").glob("Sample*[0-9].png"),
                  *(real_data_dir / "colicoords" / "test_data").glob("*/fluorescence/*.tif"),
                  *(real_data_dir / "colicoords" / "test_data").glob("*/brightfield/*.tif"),
                  real_data_dir / "ecoli_100x_oil_exponential.tiff"]  # fmt: skip
    assert len(recordings) > 10
    for path in recordings:
        assert not looks_like_masks(read_image(path).data), path


@pytest.mark.parametrize("command", ["calibrate", "diagnose"])
def test_a_constant_image_names_the_file(tmp_path, fit_inputs, capsys, command):
    """Found as a user: diagnose said "real_image is constant", an internal name."""
    import imageio.v3 as iio

    _, microscope = fit_inputs
    blank = tmp_path / "blank.png"
    iio.imwrite(blank, np.zeros((64, 32), np.uint8))
    out = tmp_path / "o"
    code, err = _run([command, str(blank), "--microscope", str(microscope),
                      "--out", str(out)], capsys)  # fmt: skip
    assert code == 2
    assert "IMAGE blank.png is constant (every pixel is 0)" in err
    assert "real_image" not in err
    assert not out.exists()


@pytest.mark.parametrize("command", ["simulate", "render", "fit", "calibrate", "diagnose"])
def test_ctrl_c_of_a_command_that_starts_over_promises_no_resume(command):
    """Found as a user: Ctrl-C of any command (simulate and demo until this round) said
    "an export resumes when run again"."""
    from napari_symbac.cli import interrupted_text

    text = interrupted_text(command)
    assert f"run the same {command} again (it starts over" in text
    assert "the items finished so far are kept" not in text
    assert "resumes when run again" in interrupted_text("export")
    assert "run the same demo again" in interrupted_text("demo")


@pytest.mark.parametrize("command", FIT_COMMANDS)
def test_a_pixel_size_given_nowhere_is_refused(tmp_path, fit_inputs, capsys, command):
    """Found as a user: an image and a microscope file that both lack the pixel size
    were fitted (and calibrated into a dataset) at the default 0.065 um, said to come
    "from --microscope", cells 0.5 um wide."""
    image, _ = fit_inputs
    microscope = tmp_path / "phase.yaml"
    microscope.write_text("wavelength_um: 0.65\nmodality: phase\n")
    out = tmp_path / "o"
    code, err = _run([command, str(image), "--microscope", str(microscope), "--out", str(out)],
                     capsys)  # fmt: skip
    assert code == 2
    assert "neither the image nor --microscope gives the pixel size" in err
    assert "add pixel_size_um to the microscope file" in err
    # calibrate has another way, which its help shows for a colony PNG (found as a user)
    assert ("--cell-width-um W sets it from the masks' median cell width" in err) == (
        command == "calibrate"
    )
    assert "Traceback" not in err
    assert not out.exists()


def test_a_bad_value_in_a_settings_file_names_the_file(tmp_path, fit_inputs, capsys):
    image, _ = fit_inputs
    microscope = tmp_path / "scope.yaml"
    microscope.write_text("pixel_size_um: -0.065\n")
    code, err = _run(["fit", str(image), "--microscope", str(microscope),
                      "--out", str(tmp_path / "o")], capsys)  # fmt: skip
    assert code == 2
    assert f"settings file {microscope}: Microscope.pixel_size_um must be" in err
    config = tmp_path / "pipeline.yaml"
    config.write_text("microscope:\n  numerical_apperture: 1.4\n")
    microscope.write_text("pixel_size_um: 0.065\n")
    code, err = _run(["fit", str(image), "--microscope", str(microscope), "--config",
                      str(config), "--out", str(tmp_path / "o")], capsys)  # fmt: skip
    assert code == 2
    assert f"settings file {config}: unknown field(s) numerical_apperture" in err


def test_diagnose_refuses_a_folder_of_another_commands_files(tmp_path, fit_inputs, capsys):
    """Found as a user: `diagnose` into a fit's folder mixed the two, and a second
    diagnosis kept the first one's effect figures."""
    from napari_symbac.cli import _diagnose_writes
    from napari_symbac.export.atomic import earlier_run

    image, microscope = fit_inputs
    out = tmp_path / "fitted"
    out.mkdir()
    (out / "cells.json").write_text("{}")
    code, err = _run(["diagnose", str(image), "--microscope", str(microscope),
                      "--out", str(out)], capsys)  # fmt: skip
    assert code == 2
    assert "holds files napari-symbac diagnose does not write (cells.json)" in err
    assert [p.name for p in out.iterdir()] == ["cells.json"]
    # an earlier diagnosis' files are all its own: found, to be replaced
    (out / "cells.json").unlink()
    for name in ("diagnosis.json", "report.txt", "effect_halo.png", ".hidden"):
        (out / name).write_text("")
    found = earlier_run(out, "diagnose", _diagnose_writes)
    assert sorted(p.name for p in found) == ["diagnosis.json", "effect_halo.png", "report.txt"]


def test_export_to_folder_of_another_export_names_what_differs(tmp_path, export_config, capsys):
    """Found as a user: re-running `export --config calibrated/export_settings.yaml --out
    calibrated/dataset` with another --n-items said only "different settings or formats";
    the user had to compare two JSON files to find it was the number of items."""
    out = tmp_path / "dataset"
    args = ["export", "--config", str(export_config), "--out", str(out), "--workers", "1"]
    assert _run([*args, "--n-items", "2"], capsys)[0] == 0
    before = _files(out)
    code, err = _run([*args, "--n-items", "3"], capsys)
    assert code == 2
    assert "different settings or formats (n_items: 2 there, 3 here); to resume" in err
    assert _files(out) == before


def test_a_dxf_outline_without_ezdxf_is_one_line_naming_the_extra(tmp_path, capsys, monkeypatch):
    """Found as a user: simulating a DXF outline without the [dxf] extra ended in a
    traceback. ezdxf made unimportable (the fault injected)."""
    from napari_symbac.settings import OutlineGeometry

    monkeypatch.setitem(sys.modules, "ezdxf", None)
    config = tmp_path / "outline.yaml"
    outline = OutlineGeometry(dxf_path=str(tmp_path / "walls.dxf"))
    simulation = SimulationSettings(n_frames=2, geometry="outline", outline=outline)
    save_settings(PipelineSettings(simulation=simulation), config)
    code, err = _run(["simulate", "--config", str(config), "--out", str(tmp_path / "sim")], capsys)
    assert code == 2
    assert "error: reading a DXF device outline needs ezdxf: pip install" in err
    assert "napari-symbac[dxf]" in err


def test_running_out_of_memory_and_a_full_disk_are_said_with_what_to_do(
    tmp_path, capsys, monkeypatch
):
    """Found as a user: a fit of a huge image ended in numpy's _ArrayMemoryError
    traceback, and a full disk was "check that the path is right". Both faults
    injected into `defaults`, the lightest command."""
    import napari_symbac.cli as cli

    def out_of_memory(_args):
        raise MemoryError("Unable to allocate 1.07 GiB for an array")

    def disk_full(_args):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(tmp_path / "x.tif"))

    for fault, words in (
        (out_of_memory, "error: out of memory (Unable to allocate 1.07 GiB for an array): "),
        (disk_full, f"error: the disk is full writing {tmp_path / 'x.tif'}: free some space"),
    ):
        monkeypatch.setattr(cli, "_cmd_defaults", fault)
        code, err = _run(["defaults", "microscope"], capsys)
        assert code == 2
        assert words in err
    assert "a crop of the image" in cli.OUT_OF_MEMORY_ADVICE


def test_an_image_larger_than_a_fit_takes_is_refused_before_it_starts():
    """Found as a user: a 12000 x 12000 frame ran out of memory in the fit's start (a
    traceback), a 6000 x 6000 one grew to 3.7 GB without a word."""
    from napari_symbac.fit.preflight import MAX_FIT_PIXELS, check_fit_image

    side = int(MAX_FIT_PIXELS**0.5)
    check_fit_image(np.ones((side, side), np.uint8) * 100)  # the largest taken
    with pytest.raises(ValueError, match=r"big is 4097 x 4096 px \(17 Mpx\), more than a fit"):
        check_fit_image(np.ones((side + 1, side), np.uint8), "big")


def test_calibrate_of_a_huge_dataset_needs_yes_before_the_fit(tmp_path, capsys, real_data_dir):
    """Found as a user: `calibrate --n-items 1000000` fitted, then started days of
    export without a word; it is refused up front as export's is, and leaves nothing."""
    out = tmp_path / "calibrated"
    microscope = tmp_path / "microscope.yaml"
    save_settings(Microscope(), microscope)
    code, err = _run(
        [
            "calibrate", str(real_data_dir / "omnipose" / "Sample000033.png"),
            "--microscope", str(microscope),
            "--masks", str(real_data_dir / "omnipose" / "Sample000033_cp_masks.tif"),
            "--cell-width-um", "1", "--n-items", str(LARGE_RUN_FRAMES + 1), "--out", str(out),
        ],
        capsys,
    )  # fmt: skip
    assert code == 2
    assert f"a dataset of {LARGE_RUN_FRAMES + 1:,} items is roughly" in err
    assert "add --yes to start it anyway" in err
    assert not out.exists()


def test_a_scene_too_large_to_draw_names_its_size_and_settings():
    """Found as a user: a 100000 um trench said "render image of (4615522, 238) pixels
    is too large: reduce upsample or size", naming no setting."""
    from napari_symbac.scene import draw_scene
    from napari_symbac.settings import RenderSettings
    from napari_symbac.sim import FrameCells

    with pytest.raises(ValueError, match=r"^the trench \(100000 x 1\.4 um\) is drawn as ") as no:
        draw_scene(FrameCells.empty(), TrenchGeometry(length_um=100_000.0), Microscope(),
                   RenderSettings())  # fmt: skip
    assert "make it smaller, or lower upsample or psf_radius_px" in str(no.value)


def test_a_setting_given_twice_in_a_file_is_refused(tmp_path, capsys):
    """Found as a user: `pixel_size_um: 0.065` and, further down, `pixel_size_um: 0.65`
    were read as 0.65 without a word (YAML keeps the last key), and the fit then said
    "cells 9 um wide". A key given twice in one mapping is refused, in YAML and JSON."""
    from napari_symbac.settings import load_settings

    twice = tmp_path / "microscope.yaml"
    twice.write_text("pixel_size_um: 0.065\nnumerical_aperture: 1.45\npixel_size_um: 0.65\n")
    with pytest.raises(ValueError, match="found 'pixel_size_um' a second time: give each"):
        load_settings(twice, Microscope)
    nested = tmp_path / "render.json"
    nested.write_text('{"simulation": {"n_frames": 3, "n_frames": 4}}')
    with pytest.raises(ValueError, match="found 'n_frames' a second time in one object"):
        load_settings(nested, PipelineSettings)
    once = tmp_path / "once.yaml"
    once.write_text("pixel_size_um: 0.065\nnumerical_aperture: 1.45\n")
    assert load_settings(once, Microscope).pixel_size_um == 0.065
    code, err = _run(["simulate", "--config", str(twice), "--out", str(tmp_path / "s")], capsys)
    assert code == 2
    assert "a second time" in err


def test_masks_of_another_number_of_frames_say_so(tmp_path, capsys, real_data_dir):
    """Found as a user: 3 frames of masks with `--frames 0-3` of a 4-frame image were
    "--masks has shape (3, 256, 46) but the image frame has shape (256, 46)"."""
    trench = tifffile.imread(real_data_dir / "ecoli_100x_oil_exponential.tiff")
    image = tmp_path / "four.tif"
    tifffile.imwrite(image, np.stack([trench] * 4))
    masks = tmp_path / "three_masks.tif"
    one = np.zeros(trench.shape, np.uint16)
    one[40:80, 15:30] = 1
    tifffile.imwrite(masks, np.stack([one] * 3))
    microscope = tmp_path / "microscope.yaml"
    save_settings(Microscope(pixel_size_um=0.065), microscope)
    code, err = _run(
        ["fit", str(image), "--microscope", str(microscope), "--masks", str(masks),
         "--frames", "0-3", "--out", str(tmp_path / "fitted")],
        capsys,
    )  # fmt: skip
    assert code == 2
    assert "--masks three_masks.tif holds 3 frames of the image's size, but not one" in err
    assert not (tmp_path / "fitted").exists()


def test_a_bad_range_of_the_randomisation_is_named():
    """Found as a user: `noise_scale: {low: 2, high: 1}` said only "Range low=2.0 must
    not exceed high=1.0", not which of the seven ranges."""
    from napari_symbac.export.dataset import Randomisation

    with pytest.raises(ValueError, match=r"^Randomisation\.noise_scale: Range low=2 must not"):
        Randomisation(noise_scale={"low": 2, "high": 1})
    with pytest.raises(ValueError, match=r"^Randomisation\.exposure_scale: .*'hi'"):
        Randomisation(exposure_scale={"low": 1, "hi": 2})


def test_a_diagnosis_window_too_small_and_a_settings_file_that_is_a_folder_are_named(
    tmp_path, capsys, real_data_dir
):
    """Found as a user: `diagnose --region 0:4,0:4` said "real_image of shape (4, 4) is
    too small" (an inner name), and `defaults microscope --out X.yaml` of a folder asked
    for --force, which then failed with "Is a directory"."""
    microscope = tmp_path / "microscope.yaml"
    save_settings(Microscope(pixel_size_um=0.065), microscope)
    code, err = _run(
        ["diagnose", str(real_data_dir / "ecoli_100x_oil_exponential.tiff"), "--microscope",
         str(microscope), "--region", "0:4,0:4", "--out", str(tmp_path / "diagnosed")],
        capsys,
    )  # fmt: skip
    assert code == 2
    assert "--region '0:4,0:4' is 4 x 4 px: a window needs at least 8 x 8 px" in err
    folder = tmp_path / "X.yaml"
    folder.mkdir()
    for force in ([], ["--force"]):
        code, err = _run(["defaults", "microscope", "--out", str(folder), *force], capsys)
        assert code == 2
        assert f"--out {folder} is a folder: give a file name (e.g. microscope.yaml)" in err


def test_fit_refuses_a_camera_that_cannot_have_recorded_the_image(
    tmp_path, capsys, real_data_dir
):
    """Found as a user (the docks, then here): an 8-bit camera for the 16-bit trench
    failed with "every pixel of the image is clipped", naming no camera; an offset of
    3000 ADU, above most of its pixels, fitted to a reduced chi-square of 1e5."""
    from napari_symbac.settings import Camera

    microscope = tmp_path / "microscope.yaml"
    save_settings(Microscope(pixel_size_um=0.065), microscope)
    for name, camera, words in (
        ("eight_bit.yaml", Camera(baseline_adu=100.0, bit_depth=8),
         "the recording reaches 7507 ADU, above this camera's full scale (255 ADU"),
        ("offset.yaml", Camera(baseline_adu=3000.0),
         "its offset 3000 ADU lies above 8"),
    ):  # fmt: skip
        save_settings(camera, tmp_path / name)
        out = tmp_path / name.removesuffix(".yaml")
        code, err = _run(
            ["fit", str(real_data_dir / "ecoli_100x_oil_exponential.tiff"), "--microscope",
             str(microscope), "--camera", str(tmp_path / name), "--out", str(out)],
            capsys,
        )  # fmt: skip
        assert code == 2
        assert f"--camera {tmp_path / name}: {words}" in err
        assert not out.exists()
