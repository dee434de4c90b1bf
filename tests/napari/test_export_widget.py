"""Export three items from the GUI and check the files; cancel and resume."""

from __future__ import annotations

import numpy as np
import pytest
import tifffile

pytest.importorskip("napari", reason="the [gui] extra (napari + Qt) is not installed")

from napari_symbac._widgets.export import ExportWidget


@pytest.fixture
def widget(make_napari_viewer):
    viewer = make_napari_viewer()
    widget = ExportWidget(viewer)
    viewer.window.add_dock_widget(widget)
    return widget


def test_export_three_items(widget, qtbot, tmp_path):
    widget.n_items.value = 3
    widget.formats.value = ["tiff", "omnipose"]
    widget.val_fraction.value = 0.0
    widget.folder.value = tmp_path / "dataset"
    widget.export_button.native.click()
    qtbot.waitUntil(lambda: widget.report is not None, timeout=120_000)
    qtbot.waitUntil(lambda: widget.worker is None, timeout=10_000)
    assert widget.report.complete
    images = sorted((tmp_path / "dataset" / "tiff" / "train" / "images").glob("*.tif"))
    masks = sorted((tmp_path / "dataset" / "omnipose" / "train").glob("*_masks.tif"))
    assert len(images) == len(masks) == 3
    for path in images:
        assert tifffile.imread(path).ndim == 2
    assert (tmp_path / "dataset" / "manifest.json").is_file()
    assert "complete" in widget.status.value
    # no rendered layer: the dataset is the defaults', said when it is done (found as a
    # user: said only while exporting)
    assert widget.status.value.endswith(
        "(settings: the built-in defaults, not matched to any recording: simulate or fit first)"
    )


def test_no_folder_is_reported(widget):
    widget.export_button.native.click()
    assert widget.status.value == "Choose an output folder"
    assert widget.worker is None


def test_refusals_are_said_in_the_docks_words(widget, tmp_path):
    """Found as a user: "set ExportSettings.kind to 'timeseries' (`napari-symbac export
    --kind timeseries`)" and "napari-symbac export --n-frames N" in the Export dock,
    whose fields are "items" and which has no frames."""
    import dataclasses

    from napari_symbac._widgets.simulate import SYMBAC_METADATA_KEY
    from napari_symbac.settings import PipelineSettings, SimulationSettings

    widget.folder.value = tmp_path / "dataset"
    widget.formats.value = ["tiff", "ctc"]
    widget.export_button.native.click()
    assert widget.status.value == (
        "Invalid settings: ctc hold tracking ground truth: choose items 'timeseries'"
    )
    one_frame = dataclasses.replace(
        PipelineSettings(), simulation=SimulationSettings(n_frames=1, geometry="agar_pad")
    )
    widget.viewer.add_image(np.zeros((32, 32), np.uint16), name="fitted field",
                            metadata={SYMBAC_METADATA_KEY: {"settings": one_frame}})  # fmt: skip
    widget.source.reset_choices()
    widget.source.value = widget.viewer.layers["fitted field"]
    widget.kind.value = "timeseries"
    widget.export_button.native.click()
    status = widget.status.value
    assert "a time series needs a simulation of at least 2 frames" in status
    assert "is 1 frame" in status
    assert "napari-symbac" not in status
    assert widget.worker is None
    assert not (tmp_path / "dataset").exists()


def test_frames_per_series_sets_the_length_of_each_series(widget, qtbot, tmp_path):
    """Found as a user: a series was as long as the source layer's simulation (60 frames
    beside a 6-frame recording); only the CLI's --n-frames could change it."""
    import json

    widget.kind.value = "timeseries"
    widget.formats.value = ["tiff", "ctc"]
    widget.n_items.value = 1
    widget.val_fraction.value = 0.0
    widget.n_frames.value = 5
    widget.folder.value = tmp_path / "series"
    widget.export_button.native.click()
    qtbot.waitUntil(lambda: widget.worker is None and widget.report is not None, timeout=120_000)
    assert widget.report.complete, widget.status.value
    manifest = json.loads((tmp_path / "series" / "manifest.json").read_text())
    assert manifest["settings"]["pipeline"]["simulation"]["n_frames"] == 5
    assert len(list((tmp_path / "series" / "tiff" / "train" / "images").glob("s0000_*.tif"))) == 5
    assert len(list((tmp_path / "series" / "ctc" / "train" / "01").glob("t*.tif"))) == 5


def test_cancel_then_resume(widget, qtbot, tmp_path):
    widget.n_items.value = 40
    widget.folder.value = tmp_path / "big"
    widget.export_button.native.click()
    qtbot.waitUntil(lambda: "Exported" in widget.status.value, timeout=120_000)
    widget.cancel_button.native.click()
    qtbot.waitUntil(lambda: widget.worker is None, timeout=120_000)
    first = widget.report
    assert first.cancelled
    assert 0 < first.n_written < 40
    widget.export_button.native.click()
    qtbot.waitUntil(lambda: widget.worker is None and widget.report is not first, timeout=180_000)
    assert widget.report.complete
    assert widget.report.n_skipped == first.n_written


def test_tuned_settings_travel_into_the_manifest(widget, qtbot, tmp_path):
    import dataclasses
    import json

    from napari_symbac._widgets.simulate import SYMBAC_METADATA_KEY
    from napari_symbac.settings import PipelineSettings

    base = PipelineSettings()
    tuned = dataclasses.replace(
        base, render=dataclasses.replace(base.render, cell_intensity=1234.5)
    )
    widget.viewer.add_image(
        np.zeros((2, 8, 8), np.uint16),
        name="synthetic",
        metadata={SYMBAC_METADATA_KEY: {"simulation": None, "settings": tuned}},
    )
    # defect 7: the newest rendered layer is chosen without picking it by hand
    assert widget.source.value is widget.viewer.layers["synthetic"]
    settings = widget.settings()
    assert settings.pipeline.render.cell_intensity == 1234.5
    widget.n_items.value = 1
    widget.folder.value = tmp_path / "ds"
    widget.export_button.native.click()
    qtbot.waitUntil(lambda: widget.report is not None, timeout=120_000)
    manifest = json.loads((tmp_path / "ds" / "manifest.json").read_text())
    assert manifest["settings"]["pipeline"]["render"]["cell_intensity"] == 1234.5


def test_an_unwritable_folder_is_refused_before_the_export(widget, tmp_path):
    """As the CLI: a folder that cannot be made is refused at once, naming the fix (the
    worker's write error said "No such file or directory; fix the cause")."""
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("a file where the dataset folder should go")
    widget.folder.value = blocker / "dataset"
    widget.export_button.native.click()
    assert widget.worker is None
    assert widget.status.value == (
        f"Not exported: the output folder {blocker / 'dataset'} cannot be created: {blocker} "
        "is a file, not a folder: check that the path is right, or move the file away"
    )
    assert not (tmp_path / "dataset").exists()


def test_a_folder_of_other_files_is_refused_before_the_export(widget, tmp_path):
    """A folder picked in the dialog that holds the user's own files: refused at once,
    the files left as they were (the dataset's folders would be written among them)."""
    (tmp_path / "notes.txt").write_text("mine")
    widget.folder.value = tmp_path
    widget.export_button.native.click()
    assert widget.worker is None
    assert widget.status.value.startswith("Not exported: ")
    assert "holds other files (notes.txt)" in widget.status.value
    assert "empty or new folder" in widget.status.value
    assert [p.name for p in tmp_path.iterdir()] == ["notes.txt"]


def test_a_folder_of_another_export_is_refused_before_the_export(widget, qtbot, tmp_path):
    """Found as a user: a folder holding an export made with other settings was refused
    only by the job, as an error notification. Now at once on the status line, the
    export left as it was; the same settings (a resume) still run there."""
    import json

    folder = tmp_path / "dataset"
    widget.n_items.value = 1
    widget.val_fraction.value = 0.0
    widget.folder.value = folder
    widget.export_button.native.click()
    qtbot.waitUntil(lambda: widget.worker is None and widget.report is not None, timeout=120_000)
    first = widget.report
    assert first.complete
    before = {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()}
    widget.seed.value = 1
    widget.export_button.native.click()
    assert widget.worker is None
    assert widget.status.value.startswith(
        f"Not exported: {folder} already holds an export made with different settings"
    )
    assert "; seed: 0 there, 1 here)" in widget.status.value
    assert "export to a new folder" in widget.status.value
    assert "choose the settings it was made with" in widget.status.value
    assert "napari-symbac export" not in widget.status.value  # the dock's words
    assert widget.export_button.enabled
    assert {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()} == before
    # the same settings: the finished export is resumed (nothing left to write)
    widget.seed.value = 0
    widget.export_button.native.click()
    assert widget.worker is not None
    qtbot.waitUntil(lambda: widget.worker is None and widget.report is not first, timeout=120_000)
    assert widget.report.complete
    assert widget.report.n_skipped == 1
    assert json.loads((folder / "manifest.json").read_text())["status"] == "complete"


def test_export_error_is_reported_and_the_widget_stays_usable(
    widget, qtbot, tmp_path, monkeypatch
):
    """Defect 7: an ExportError (a RuntimeError) froze the widget: superqt treats a
    RuntimeError in a generator worker as an aborted thread (no error, no finish). The
    disk fails while writing (injected)."""
    import errno

    from napari.utils.notifications import notification_manager

    def failing_disk(*_args, **_kwargs):
        raise OSError(errno.EIO, "Input/output error")

    monkeypatch.setattr(tifffile, "imwrite", failing_disk)
    seen = []
    notification_manager.notification_ready.connect(seen.append)
    widget.n_items.value = 1
    widget.folder.value = tmp_path / "dataset"
    widget.export_button.native.click()
    qtbot.waitUntil(lambda: widget.worker is None, timeout=120_000)
    assert widget.status.value.startswith("Export failed")
    assert widget.report is None
    assert any("Export failed" in str(n.message) for n in seen)
    assert widget.export_button.enabled
    assert not widget.cancel_button.enabled


def test_backend_choice_renders_on_torch(widget, qtbot, tmp_path):
    import json

    assert widget.backend.choices[:2] == ("scipy", "torch")  # torch is installed in CI
    assert widget.backend.value == "scipy"
    widget.backend.value = "torch"
    widget.n_items.value = 2
    widget.val_fraction.value = 0.0
    widget.folder.value = tmp_path / "dataset"
    widget.export_button.native.click()
    qtbot.waitUntil(lambda: widget.report is not None, timeout=120_000)
    qtbot.waitUntil(lambda: widget.worker is None, timeout=10_000)
    assert widget.report.complete
    manifest = json.loads((tmp_path / "dataset" / "manifest.json").read_text())
    assert manifest["render_backend"].startswith("torch:")
    images = sorted((tmp_path / "dataset" / "tiff" / "train" / "images").glob("*.tif"))
    assert len(images) == 2
    assert all(tifffile.imread(path).std() > 0 for path in images)


def test_export_on_a_dask_scheduler(widget, qtbot, tmp_path):
    """Found as a user: the CLI's --scheduler had no place in the dock. The dataset is
    written by the scheduler's workers, the same bytes as in this process; a scheduler
    that does not answer is an error in the status line, the widget usable after it."""
    from napari_symbac.export.cluster import local_cluster

    widget.n_items.value = 4
    widget.val_fraction.value = 0.0
    widget.folder.value = tmp_path / "here"
    widget.export_button.native.click()
    qtbot.waitUntil(lambda: widget.worker is None and widget.report is not None, timeout=120_000)
    here = widget.report
    assert here.workers == 1
    with local_cluster(1) as cluster:
        widget.scheduler.value = cluster.scheduler_address
        widget.folder.value = tmp_path / "cluster"
        widget.export_button.native.click()
        assert f"on the dask scheduler at {cluster.scheduler_address}" in widget.status.value
        qtbot.waitUntil(
            lambda: widget.worker is None and widget.report is not here, timeout=120_000
        )
    assert widget.report.complete
    for path in sorted((tmp_path / "here" / "tiff").rglob("*.tif")):
        twin = tmp_path / "cluster" / path.relative_to(tmp_path / "here")
        assert twin.read_bytes() == path.read_bytes()
    # a malformed address is said on the status line before any work (as a folder that
    # cannot be written; found as a user: an error notification from the job)
    widget.scheduler.value = "nohost"
    widget.folder.value = tmp_path / "refused"
    widget.export_button.native.click()
    assert widget.worker is None
    assert widget.status.value.startswith("Not exported: the scheduler address 'nohost'")
    assert not (tmp_path / "refused").exists()
    assert widget.export_button.enabled
