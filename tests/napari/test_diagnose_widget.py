"""The Diagnose dock widget on a crop of the real SyMBac trench (GPL-2 test data)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from napari_symbac._widgets.diagnose import (
    DIAGNOSIS_RESIDUAL_LAYER,
    FAINT_START_FIX,
    WIDE_START_FIX,
    DiagnoseWidget,
)
from napari_symbac._widgets.simulate import SYMBAC_METADATA_KEY

CANDIDATES = ("uneven_illumination", "camera_noise")


@pytest.fixture
def diagnose_widget(make_napari_viewer, real_data_dir):
    import tifffile

    viewer = make_napari_viewer()
    real = tifffile.imread(real_data_dir / "ecoli_100x_oil_exponential.tiff")  # 256 x 46
    viewer.add_image(
        real,
        name="real",
        scale=(0.065, 0.065),
        metadata={"pixel_size_um": 0.065, "modality": "phase"},
    )
    # a window of 96 rows, as a large field gets one of 256 x 256 px: the centre one
    widget = DiagnoseWidget(viewer, candidates=CANDIDATES, n_bootstrap=5, max_pixels=96 * 46)
    widget.window.value = "centre"
    return viewer, widget, real


def test_diagnose_adds_layers_report_and_settings(diagnose_widget, qtbot):
    from napari_symbac._widgets.export import ExportWidget
    from napari_symbac.settings import PipelineSettings, SimulationSettings
    from napari_symbac.sim import simulate

    viewer, widget, _ = diagnose_widget
    assert widget.reference.value is viewer.layers["real"]  # the newest recording
    # Export docked beside it from the start, as in the workflow dock, with a simulation
    # already chosen as its source (its settings, as after Auto-fit: cells 0.9 um wide)
    fitted = SimulationSettings(n_frames=2, cell_width_um=0.9)
    simulated = viewer.add_image(
        np.zeros((2, 8, 8), np.uint16),
        name="synthetic",
        metadata={
            SYMBAC_METADATA_KEY: {
                "simulation": simulate(SimulationSettings(n_frames=2)),
                "settings": PipelineSettings(simulation=fitted),
            }
        },
    )
    export = ExportWidget(viewer)
    assert export.source.value is simulated
    said = []  # the status line after each progress message (a Label emits no signal)
    shown = widget._on_progress
    widget._on_progress = lambda message: (shown(message), said.append(widget.status.value))
    widget.run_button.clicked.emit()
    assert not widget.run_button.enabled
    qtbot.waitUntil(lambda: widget.worker is None, timeout=120_000)
    assert widget.run_button.enabled
    # the scene fit counts its renders (found as a user: minutes of "Fitting the
    # scene..." with no count), then the held-out checks are counted
    counted = [s for s in said if re.match(r"Fitting the scene: \d+ of at most \d+ renders", s)]
    assert counted, said
    assert said.index(counted[-1]) < max(
        i for i, s in enumerate(said) if s.startswith("Diagnosing: ")
    )
    assert not widget.cancel_button.enabled
    assert widget.result is not None, widget.status.value
    assert "the centre 96 x 46 px of the 256 x 46 frame" in widget.status.value
    residual = viewer.layers[DIAGNOSIS_RESIDUAL_LAYER]
    assert residual.data.shape == (96, 46)  # rows 80:176, over them on the canvas
    assert tuple(residual.translate) == pytest.approx((80 * 0.065, 0.0))
    assert np.isfinite(residual.data).all()
    assert residual.data.std() > 0
    assert tuple(residual.scale) == (0.065, 0.065)
    # white at 0 and a colour bar (found as a user: no legend said which colour is
    # "image brighter"); before and after on one scale, compared by eye
    low, high = residual.contrast_limits
    assert low == -high
    assert high >= 3.0
    assert residual.colorbar.visible
    after = viewer.layers["diagnosis residual after"]
    assert tuple(after.contrast_limits) == (low, high)
    assert after.colorbar.visible
    assert "diagnosis residual after" in viewer.layers
    for effect in widget.result.accepted:
        if effect.effect_map is not None:
            assert f"diagnosis effect: {effect.name}" in viewer.layers
    # what Export will draw of them is said
    from napari_symbac.diagnose.stages import drawn_by_export

    accepted = [effect.name for effect in widget.result.accepted]
    assert accepted, widget.status.value  # the real trench's misfit names some effect
    said = _said(widget)
    assert drawn_by_export(accepted) in said
    assert "unusual for bacteria" not in said  # the right pixel size
    # the status keeps to the outcome, what changed leads the report (found as a user:
    # 17 lines of status left the report 2 lines of the dock at 1366 x 768)
    outcome = f"Accepted: {', '.join(accepted)}{widget._window_note}. "
    assert widget.status.value.startswith(outcome)
    assert re.fullmatch(
        r"(\d+ cautions?, what|What) Export draws and the camera are said at the top of "
        r"the report below\.",
        widget.status.value.removeprefix(outcome),
    ), widget.status.value
    text = widget.report.value
    assert text.startswith("Export now takes the updated settings")
    preamble, report = text.split("\n\nDiagnosis of the mismatch")
    assert max(len(line) for line in preamble.split("\n")) <= 64  # the box's width
    assert "red where the image is brighter than the model, blue where darker." in said
    assert report.startswith(" between the fitted model and the recording\n")
    for name in CANDIDATES:
        assert name in text
    settings = residual.metadata[SYMBAC_METADATA_KEY]["settings"]
    assert isinstance(settings, PipelineSettings)
    assert settings.microscope.pixel_size_um == 0.065
    # Export after the diagnosis simulates the cells and trench its fit found (as the
    # CLI's settings.yaml), on the Simulate tab's other choices: not the 0.9 um cells of
    # the layer before it, nor the defaults' 3.5 um-wide trench; the trench as long as
    # the recording, not the 96-row window (too short for the fitted cells to divide in)
    simulation = settings.simulation
    assert "the cells and layout fitted, sized as the recording" in said
    assert simulation.n_frames == fitted.n_frames
    assert simulation.geometry == "trench"
    assert 0.95 <= simulation.cell_width_um <= 1.3, simulation
    trench = simulation.trench
    assert trench.width_um + 2 * trench.margin_um == pytest.approx(46 * 0.065, abs=1e-9)
    assert trench.length_um + trench.shown_top_um == pytest.approx(256 * 0.065, abs=1e-9)
    # the camera is measured from the recording (2.0 ADU/e- on the whole trench, 1.8 on
    # this window), not assumed (2.9 ADU/e- by default)
    pattern = r"camera measured from the recording: ([0-9.]+) ADU/e-"
    measured = re.search(pattern.replace("camera", "Camera"), said)
    assert measured is not None, said
    assert float(measured.group(1)) == pytest.approx(2.0, rel=0.2)
    # and the residual's excess over it (reduced chi-square 43 before the diagnosis) is
    # misfit of the mean, not camera noise: camera_noise, judged on the high-pass residual,
    # at most refines the gain measured on this window (1.82 -> 2.0, the whole trench's)
    # where the plain residual had made it 13x
    assert settings.camera.sensitivity_adu_per_e == pytest.approx(2.0, rel=0.2)
    # Export takes the diagnosis' settings, the newest, without picking them by hand
    # (found as a user: the workflow's Export kept the first simulation's)
    assert export.source.value is residual
    assert export.settings().pipeline.render == settings.render
    assert export.settings().pipeline.extra_stages == settings.extra_stages  # drawn
    # the button works again: a second run with the same seed gives the same report
    widget.run_button.clicked.emit()
    qtbot.waitUntil(lambda: widget.worker is None, timeout=120_000)
    assert widget.report.value == text
    # the most effects accepted is the dock's choice, as diagnose --max-effects
    from napari_symbac.cli import DIAGNOSE_MAX_EFFECTS

    assert widget.max_effects.value == DIAGNOSE_MAX_EFFECTS
    widget.max_effects.value = 1
    widget.run_button.clicked.emit()
    qtbot.waitUntil(lambda: widget.worker is None, timeout=120_000)
    assert widget.result.max_steps == 1
    assert len(widget.result.accepted) == 1


def test_cancel_adds_nothing(diagnose_widget, qtbot):
    viewer, widget, _ = diagnose_widget
    widget.run_button.clicked.emit()
    widget.cancel_button.clicked.emit()
    qtbot.waitUntil(lambda: widget.worker is None, timeout=120_000)
    assert DIAGNOSIS_RESIDUAL_LAYER not in viewer.layers
    assert "cancelled" in widget.status.value
    assert widget.report.value == ""
    assert widget.run_button.enabled
    assert not widget.cancel_button.enabled


def test_removing_the_recording_during_a_run_cancels_it(diagnose_widget, qtbot):
    """Found as a user: with its recording removed mid-run, Diagnose ran on for 112 s and
    added its layers without a word. It stops, says why and adds nothing."""
    viewer, widget, _ = diagnose_widget
    widget.run_button.clicked.emit()
    job = widget.worker
    viewer.layers.remove("real")
    assert job.cancelled.is_set()
    qtbot.waitUntil(lambda: widget.worker is None, timeout=120_000)
    assert widget.status.value == (
        "Diagnosis cancelled (its layer 'real' was removed): nothing added"
    )
    assert DIAGNOSIS_RESIDUAL_LAYER not in viewer.layers
    assert widget.run_button.enabled


def test_no_recording_is_a_notification(make_napari_viewer, qtbot, monkeypatch):
    shown = []
    monkeypatch.setattr(
        "napari_symbac._widgets.diagnose.notify_warning", lambda message: shown.append(message)
    )
    viewer = make_napari_viewer()
    viewer.add_image(np.zeros((20, 20)), name="no pixel size")
    widget = DiagnoseWidget(viewer)
    assert widget.reference.value is None
    widget.run_button.clicked.emit()
    assert widget.worker is None
    assert shown
    assert "pixel size" in shown[0]
    assert widget.run_button.enabled


def test_a_normalised_recording_is_refused_as_the_fit_refuses_it(
    make_napari_viewer, monkeypatch, real_data_dir
):
    """The DeLTA trench (normalised, values down to -0.03) with its pixel size set."""
    import tifffile

    shown = []
    monkeypatch.setattr(
        "napari_symbac._widgets.diagnose.notify_warning", lambda message: shown.append(message)
    )
    viewer = make_napari_viewer()
    data = tifffile.imread(real_data_dir / "ecoli_delta_phase_normalised.tiff")
    viewer.add_image(data, name="delta", metadata={"pixel_size_um": 0.065, "modality": "phase"})
    widget = DiagnoseWidget(viewer)
    assert widget.reference.value is viewer.layers["delta"]
    widget.run_button.clicked.emit()
    assert widget.worker is None
    assert "delta has negative values" in shown[0]
    assert "negative values" in widget.status.value
    assert [layer.name for layer in viewer.layers] == ["delta"]


def test_a_modality_the_image_contradicts_is_refused_as_the_fit_refuses_it(
    make_napari_viewer, monkeypatch, real_data_dir
):
    """ColiCoords' fluorescence field marked phase: refused before any fit, naming the
    modality to set and where (found as a user through the CLI, which ran on to advice
    about wide cells)."""
    import tifffile

    monkeypatch.setattr("napari_symbac._widgets.diagnose.notify_warning", lambda message: None)
    viewer = make_napari_viewer()
    path = real_data_dir / "colicoords" / "test_data" / "ds1" / "fluorescence" / "00001.tif"
    metadata = {"pixel_size_um": 0.08, "modality": "phase"}
    viewer.add_image(tifffile.imread(path), name="field", metadata=metadata)
    widget = DiagnoseWidget(viewer)
    widget.run_button.clicked.emit()
    assert widget.worker is None
    assert "the image does not look like phase" in widget.status.value
    assert "Set its modality to fluorescence in the 1 Recording tab" in widget.status.value
    assert [layer.name for layer in viewer.layers] == ["field"]


def test_error_in_the_worker_is_a_notification(diagnose_widget, qtbot, monkeypatch):
    shown = []
    monkeypatch.setattr(
        "napari_symbac._widgets._jobs.notify_error", lambda message: shown.append(message)
    )
    viewer, widget, _ = diagnose_widget
    widget.candidates = ("no_such_effect",)
    widget.run_button.clicked.emit()
    qtbot.waitUntil(lambda: widget.worker is None, timeout=120_000)
    assert shown
    assert "unknown effects" in shown[0]
    assert "Diagnosis failed" in widget.status.value
    assert DIAGNOSIS_RESIDUAL_LAYER not in viewer.layers
    assert widget.run_button.enabled


def test_diagnose_docks_from_the_manifest(make_napari_viewer):
    viewer = make_napari_viewer()
    _dock, widget = viewer.window.add_plugin_dock_widget(
        "napari-symbac", "Diagnose model mismatch"
    )
    assert isinstance(widget, DiagnoseWidget)
    assert widget.run_button.enabled


def test_closing_the_viewer_during_a_run_is_clean(diagnose_widget, qtbot):
    """The worker is told to quit and adds nothing to the closed viewer (pytest-qt fails
    the test on any exception raised in the event loop)."""
    viewer, widget, _ = diagnose_widget
    viewer.window.add_dock_widget(widget)
    widget.run_button.clicked.emit()
    job = widget.worker
    viewer.close()
    qtbot.waitUntil(lambda: job.cancelled.is_set(), timeout=10_000)
    qtbot.waitUntil(lambda: not job.worker.is_running, timeout=60_000)


def test_diagnose_names_the_image_that_waits_for_its_pixel_size(
    make_napari_viewer, real_data_dir
):
    """Found as a user: the real trench opened (it records no pixel size) and Diagnose
    clicked before entering it said "No recording: open your image and set its pixel size
    in Real image and classes": the image was open, and the workflow names that step
    *1 Recording*. Now the image is named, with the tab to enter its pixel size in."""
    import tifffile

    viewer = make_napari_viewer()
    widget = DiagnoseWidget(viewer, candidates=CANDIDATES, n_bootstrap=5)
    widget.run_button.clicked.emit()
    assert widget.status.value.startswith("No recording: open your image in the 1 Recording")
    real = tifffile.imread(real_data_dir / "ecoli_100x_oil_exponential.tiff")
    layer = viewer.add_image(real, name="my trench", metadata={"pixel_size_um": 0.0})
    waiting = (
        "my trench has no pixel size yet: enter it in the 1 Recording tab (or "
        "the Real image and classes dock), then choose it here"
    )
    # said as soon as the image is opened (found as a user: nothing until clicked)
    assert widget.status.value == waiting
    widget.run_button.clicked.emit()
    assert widget.worker is None
    assert widget.status.value == waiting
    # entered: the image is chosen and the advice taken back (found as a user: it stayed)
    layer.metadata = {**layer.metadata, "pixel_size_um": 0.065}
    assert widget.reference.value is layer
    assert widget.status.value == ""


def test_diagnose_says_the_centre_window_holds_no_cells(make_napari_viewer, qtbot):
    """Found as a user: a 300 x 300 px fluorescence field whose only cell lies in a
    corner, outside the centre 256 x 256 px that the dock diagnoses, said "Diagnosis
    failed: the start found no cells in the image", of an image with a cell in it. Now the
    window and the way out (the dock's window field) are said."""
    rng = np.random.default_rng(0)
    frame = rng.poisson(200, (300, 300)).astype(np.float64) + 100
    frame[3:12, 3:40] += 3000
    # and a cell too faint for the start in the window (a frame of noise alone is refused
    # as blank before the start: test_scene_engine)
    frame[140:149, 130:167] += 40
    viewer = make_napari_viewer()
    viewer.add_image(
        frame.astype(np.uint16),
        name="field",
        scale=(0.08, 0.08),
        metadata={"pixel_size_um": 0.08, "modality": "fluorescence"},
    )
    widget = DiagnoseWidget(viewer, candidates=CANDIDATES, n_bootstrap=5)
    widget.window.value = "centre"  # by default the window holding the cell is diagnosed
    widget.run_button.clicked.emit()
    qtbot.waitUntil(lambda: widget.worker is None, timeout=60_000)
    status = widget.status.value
    assert status.startswith("Diagnosis failed: the start found no cells")
    where = "the centre 256 x 256 px of the 300 x 300 frame, rows 22:278 and columns 22:278"
    assert where in status
    assert "enter one with cells in 'window (rows, columns)'" in status  # the dock's own
    # and, as the window may hold a cell too faint for the start (found as a user: one
    # standing 25 times the background's spread, an error notification), the strokes
    assert status.endswith(f"; {FAINT_START_FIX}")
    assert "--region" not in status
    assert DIAGNOSIS_RESIDUAL_LAYER not in viewer.layers


def test_diagnose_of_a_colony_names_the_docks_own_fixes(
    make_napari_viewer, qtbot, real_data_dir
):
    """The Omnipose colony Sample000033 (touching cells, 0.118 um/px): the automatic
    start takes them as wide regions; the dock says so with its own fixes (its cell
    masks and window fields), not the CLI's flags."""
    from napari_symbac.io import read_image

    viewer = make_napari_viewer()
    viewer.add_image(
        read_image(real_data_dir / "omnipose" / "Sample000033.png").data,
        name="colony",
        scale=(0.118, 0.118),
        metadata={"pixel_size_um": 0.118, "modality": "phase"},
    )
    widget = DiagnoseWidget(viewer, candidates=CANDIDATES, n_bootstrap=5)
    widget.run_button.clicked.emit()
    qtbot.waitUntil(lambda: widget.worker is None, timeout=60_000)
    status = widget.status.value
    assert status.startswith("Diagnosis failed: ")
    assert "wider than any rod-shaped bacterium" in status
    assert status.endswith(f"; {WIDE_START_FIX}")
    assert "'cell masks'" in status
    assert "enter a window of separate cells in 'window (rows, columns)'" in status
    assert "--masks" not in status
    assert widget.run_button.enabled
    assert DIAGNOSIS_RESIDUAL_LAYER not in viewer.layers
    # with the colony's masks: Diagnose's separate rods cannot draw it, Auto-fit can
    import tifffile

    masks = tifffile.imread(real_data_dir / "omnipose" / "Sample000033_cp_masks.tif")
    viewer.add_labels(masks.astype(np.int32), name="masks", scale=(0.118, 0.118))
    assert widget.masks.value is viewer.layers["masks"]
    widget.run_button.clicked.emit()
    assert widget.worker is None
    assert widget.status.value.startswith(
        "'cell masks' masks hold a dense colony of touching cells in the window"
    )
    assert "Tune's Auto-fit" in widget.status.value


def _said(widget) -> str:
    """The dock's status and report as one text, its lines joined (the report's own
    lines are wrapped to the box's width)."""
    return " ".join(f"{widget.status.value} {widget.report.value}".split())


def _dock_beside(viewer, path, pixel_um: float, modality: str):
    """The viewer with the recording at ``path`` (its pixel size entered) and a Diagnose
    dock of the test's candidates."""
    import tifffile

    viewer.add_image(
        tifffile.imread(path),
        name=path.stem,
        scale=(pixel_um, pixel_um),
        metadata={"pixel_size_um": pixel_um, "modality": modality},
    )
    return viewer, DiagnoseWidget(viewer, candidates=CANDIDATES, n_bootstrap=5)


def test_a_pixel_size_slip_is_cautioned_in_the_status(make_napari_viewer, qtbot, real_data_dir):
    """Found as a user (the command, and the dock alike): the real trench at 0.13 um/px,
    twice its pixel size, was diagnosed without a word of its cells 1.81 um wide, which
    Auto-fit and `fit` say. The base fit's problems lead the dock's cautions."""
    image = real_data_dir / "ecoli_100x_oil_exponential.tiff"
    _viewer, widget = _dock_beside(make_napari_viewer(), image, 0.13, "phase")
    widget.run_button.clicked.emit()
    qtbot.waitUntil(lambda: widget.worker is None, timeout=120_000)
    assert widget.result is not None, widget.status.value
    assert re.search(r"\. \d+ cautions?, what Export draws and the camera are said at the "
                     r"top of the report below\.$", widget.status.value)  # fmt: skip
    said = _said(widget)
    assert "CAUTION: base fit: the cells' median width, 1.8" in said
    assert "is unusual for bacteria (0.4-1.6 um): check the pixel size" in said


def test_diagnose_starts_from_the_cell_masks_opened(make_napari_viewer, qtbot, real_data_dir):
    """ColiCoords' single-cell crop ``01``: the automatic start finds no cell (its glow
    is most of the crop). Found as a user: the dock took no masks, so the lab's own mask
    could not start it; the binary mask opened as a Labels layer is chosen in *cell
    masks* and the base fit starts from its cell. A mask that holds no cell in the
    window is refused in one line."""
    import tifffile

    folder = real_data_dir / "colicoords" / "01"
    image = folder / "fluorescence.tif"
    viewer, widget = _dock_beside(make_napari_viewer(), image, 0.08, "fluorescence")
    assert widget.masks.value is None
    masks = viewer.add_labels(tifffile.imread(folder / "binary.tif").astype(np.uint8),
                              name="binary", scale=(0.08, 0.08))  # fmt: skip
    assert widget.masks.value is masks  # opened after the recording: chosen
    widget.window.value = "0:10,0:10"
    widget.run_button.clicked.emit()
    assert widget.status.value.startswith("'cell masks' binary hold no cell in rows 0:10")
    assert widget.worker is None
    widget.window.value = "centre"
    widget.run_button.clicked.emit()
    qtbot.waitUntil(lambda: widget.worker is None, timeout=120_000)
    assert widget.result is not None, widget.status.value
    assert widget.status.value.startswith("Accepted: "), widget.status.value
    assert DIAGNOSIS_RESIDUAL_LAYER in viewer.layers


@pytest.fixture
def ds3_widget(make_napari_viewer, real_data_dir):
    """ColiCoords ds3 (4 frames of 512 x 512 px, fluorescence, 80 nm), frame 1 on
    screen: no cell in its centre 256 x 256 px, one at rows 113:167, columns 66:86."""
    import tifffile

    data = tifffile.imread(real_data_dir / "colicoords" / "test_data" / "ds3" / "flu.tif")
    viewer = make_napari_viewer()
    viewer.add_image(
        data,
        name="ds3",
        scale=(0.08, 0.08),
        metadata={"pixel_size_um": 0.08, "modality": "fluorescence"},
    )
    viewer.dims.set_current_step(0, 1)
    return viewer, DiagnoseWidget(viewer, candidates=CANDIDATES, n_bootstrap=5)


def test_the_window_chosen_is_the_one_diagnosed(ds3_widget, qtbot):
    """Found as a user: Diagnose of ColiCoords ds3's frame 1 found no cells in the centre
    window, the only one the dock could diagnose; the status sent the user to the CLI's
    --region. The dock's window field takes the same forms, read by the same parser."""
    viewer, widget = ds3_widget
    # by default the window that holds the most whole cells: frame 1's one cell
    assert widget.window.value == "cells"
    y0, y1, x0, x1 = widget._input()[-1]
    assert (y1 - y0, x1 - x0) == (256, 256)
    assert y0 <= 113
    assert y1 >= 167
    assert x0 <= 66
    assert x1 >= 86
    widget.window.value = "centre"
    widget.run_button.clicked.emit()
    qtbot.waitUntil(lambda: widget.worker is None, timeout=120_000)
    assert "the centre 256 x 256 px of the 512 x 512 frame" in widget.status.value
    assert "enter one with cells in 'window (rows, columns)'" in widget.status.value
    assert DIAGNOSIS_RESIDUAL_LAYER not in viewer.layers
    widget.window.value = " 96:192, 48:112 "  # around the cell; spaces as the CLI takes
    widget.run_button.clicked.emit()
    qtbot.waitUntil(lambda: widget.worker is None, timeout=180_000)
    assert widget.result is not None, widget.status.value
    assert widget.status.value.startswith("Accepted: ")
    assert "in the chosen 96 x 64 px of the 512 x 512 frame, rows 96:192 and columns 48:112" in (
        widget.status.value
    )
    assert " (frame 1 of 4)" in widget.status.value  # which frame of the time-lapse
    for name in [n for n in viewer.layers if n.name.startswith("diagnosis ")]:
        assert name.data.shape == (96, 64)  # the window, over it on the canvas
        assert tuple(name.translate) == pytest.approx((96 * 0.08, 48 * 0.08))
        assert tuple(name.scale) == (0.08, 0.08)
    # Export, which takes the diagnosis' settings, says its images are the window's
    from napari_symbac._widgets.export import ExportWidget

    export = ExportWidget(viewer)
    assert export.source.value is viewer.layers[DIAGNOSIS_RESIDUAL_LAYER]
    label = export.source.native.currentText()
    assert label.endswith("(images of the diagnosed window, 96 x 64 px)")


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ("middle", "window 'middle' is not of the form Y0:Y1,X0:X1"),
        ("", "window '' is not of the form Y0:Y1,X0:X1"),
        ("96:192", "window '96:192' is not of the form Y0:Y1,X0:X1"),
        ("0:600,0:64", "window '0:600,0:64' is not all inside the 512 x 512 frame (rows 0:512"),
        ("192:96,0:64", "window '192:96,0:64' is empty (each end after its start)"),
    ],
)
def test_a_bad_window_is_refused_in_one_line(ds3_widget, monkeypatch, text, problem):
    shown = []
    monkeypatch.setattr(
        "napari_symbac._widgets.diagnose.notify_warning", lambda message: shown.append(message)
    )
    viewer, widget = ds3_widget
    widget.window.value = text
    widget.run_button.clicked.emit()
    assert widget.worker is None  # nothing started, the button still works
    assert widget.run_button.enabled
    status = widget.status.value
    assert status.startswith(problem)
    assert "give Y0:Y1,X0:X1 (rows and columns in pixels" in status
    assert "full (the whole frame), cells (the window of at most 256 x 256 px" in status
    assert "or centre (its centre window" in status
    assert "\n" not in status
    assert shown == [status]
    assert [layer.name for layer in viewer.layers] == ["ds3"]


def test_a_small_window_around_a_cell_is_said_to_be_small(ds3_widget, qtbot):
    """Found as a user: 60 x 100 px drawn tightly around a bright cell of ds3 were told to
    "enter one with cells"; the CLI said the window may be too small for the start. The
    dock says so too (frame 1's cell, rows 113:167, columns 66:86, in 70 x 40 px), and an
    earlier run's report is not left under the failure."""
    viewer, widget = ds3_widget
    widget.window.value = "105:175,56:96"
    widget.report.value = "Diagnosis of the mismatch ... (an earlier run's)"
    widget.run_button.clicked.emit()
    qtbot.waitUntil(lambda: widget.worker is None, timeout=60_000)
    status = widget.status.value
    assert status.startswith("Diagnosis failed: the start found no cells"), status
    assert "the 70 x 40 px window may be too small for the start to tell the cells" in status
    assert "of at least 64 x 64 px around them" in status
    assert DIAGNOSIS_RESIDUAL_LAYER not in viewer.layers
    assert widget.report.value == ""  # found as a user: the earlier run's report stayed


def test_a_full_frame_above_the_cap_is_diagnosed_with_a_warning(ds3_widget, qtbot):
    """As the CLI's --region full: the whole 512 x 512 frame is the user's choice, run,
    with the status saying it may take long (and Cancel stopping it)."""
    viewer, widget = ds3_widget
    widget.window.value = "FULL"
    widget.run_button.clicked.emit()
    assert widget.worker is not None
    assert widget.status.value == (
        "Fitting the scene... (frame 1 of 4) (262,144 pixels, more than the 65,536 of 'cells': a "
        "diagnosis's time and memory grow faster than its pixels, so this one may take "
        "long and much memory; Cancel stops it)"
    )
    widget.cancel_button.clicked.emit()
    qtbot.waitUntil(lambda: widget.worker is None, timeout=120_000)
    assert "cancelled" in widget.status.value
    assert [layer.name for layer in viewer.layers] == ["ds3"]


def test_a_bright_field_recording_is_diagnosed_with_its_lens_term(make_napari_viewer, qtbot):
    """Bright field (the sample's ColiCoords field, flattened, its pad mottled) was
    refused (the design had no lens term); now the lens amplitude is re-fitted with the
    intensities, and the settings Export takes carry it."""
    viewer = make_napari_viewer()
    viewer.open_sample("napari-symbac", "colicoords")
    widget = DiagnoseWidget(viewer, candidates=("background_texture",), n_bootstrap=5)
    widget.reference.value = viewer.layers["ColiCoords brightfield"]
    widget.run_button.clicked.emit()
    qtbot.waitUntil(lambda: widget.worker is None, timeout=120_000)
    assert widget.result is not None, widget.status.value
    assert [e.name for e in widget.result.accepted] == ["background_texture"]
    # its "camera" is the residual's variance, and the status says why (flattened)
    assert "the image's own photon transfer: the pixel variance does not grow" in _said(widget)
    residual = viewer.layers[DIAGNOSIS_RESIDUAL_LAYER]
    settings = residual.metadata[SYMBAC_METADATA_KEY]["settings"]  # what Export takes
    assert settings.microscope.modality == "brightfield"
    render = settings.render
    beta = widget.result.final_model.beta  # the intensities, then kappa I_m
    assert render.defocus_contrast_um2 == pytest.approx(beta[3] / beta[1])
    assert render.defocus_contrast_um2 != 0.0
    assert render.cell_intensity < render.media_intensity  # the cells absorb
    assert render.texture_amplitude > 0  # the accepted texture, drawn
