"""`napari-symbac fit`: outputs reusable by render/export, honest reports, clear refusals."""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import re

import imageio.v3 as iio
import numpy as np
import pytest
import tifffile
import yaml
from scipy import ndimage

from napari_symbac.calibrate.compaction import PAD_PHYS_ITERS
from napari_symbac.cli import main
from napari_symbac.fit import scene_classes
from napari_symbac.fit.preflight import BRIGHT_FIELD_NOTE
from napari_symbac.io import read_recording
from napari_symbac.settings import (
    Camera,
    Microscope,
    PipelineSettings,
    load_settings,
    save_settings,
)

OUTPUTS = {"settings.yaml", "cells.json", "residual.tif", "before_after.png", "report.txt"}


@pytest.fixture
def inputs(tmp_path, truth):
    """The rendered truth trench as a TIFF, its painted classes and its microscope."""
    image = tmp_path / "real.tif"
    labels = tmp_path / "labels.tif"
    tifffile.imwrite(image, truth.image)
    tifffile.imwrite(labels, scene_classes(truth.scene).astype(np.uint8))
    microscope = save_settings(truth.microscope, tmp_path / "microscope.yaml")
    return image, labels, microscope


def _fit(*args) -> int:
    return main(["fit", *map(str, args)])


def _fact(report: str, key: str) -> str:
    """The value of one ``key  value`` line at the top of report.txt."""
    for line in report.splitlines():
        if line.startswith(key + "  "):
            return line[len(key) :].strip()
    raise AssertionError(f"report.txt has no line {key!r}:\n{report}")


# --------------------------------------------------------------------------------------
# Outputs
# --------------------------------------------------------------------------------------


def test_a_pixel_size_slip_is_said_before_the_fit_and_refused_at_the_start(
    tmp_path, truth, inputs, capsys
):
    """Found as a user: ``pixel_size_um: 0.65`` (a 10x slip) for the 100x objective gave
    35 cells at their bounds, and stdout said only "fitted 35 cells". The slip is a 65
    um camera pixel, said before the fit; its cells are then ~10 um wide, wider than any
    rod, and the fit stops at its start naming the pixel size, with nothing written."""
    image, labels, _ = inputs
    slip = dataclasses.replace(truth.microscope, pixel_size_um=10 * truth.microscope.pixel_size_um)
    microscope = save_settings(slip, tmp_path / "slip.yaml")
    out = tmp_path / "fit"
    assert _fit(image, "--labels", labels, "--microscope", microscope, "--out", out) == 2
    captured = capsys.readouterr()
    camera_pixel = f"{10 * truth.microscope.pixel_size_um * slip.magnification:.3g} um camera pixel"
    warned = captured.err.index(f"napari-symbac fit: warning: pixel size {slip.pixel_size_um:g}")
    assert camera_pixel in captured.err[warned:].splitlines()[0]
    error = captured.err[captured.err.index("napari-symbac fit: error: ") :].splitlines()[0]
    assert "wider than any rod-shaped bacterium" in error
    assert f"the pixel size ({slip.pixel_size_um:g} um) is too large" in error
    assert not out.exists()
    assert captured.out == ""


def test_a_pixel_size_slip_with_masks_is_refused_at_the_start(tmp_path, truth, inputs, capsys):
    """The same slip with the cells' masks: the masks' cells, ~10x too wide, were fitted
    at their bounds (calibrate refused them; fit did not)."""
    image = inputs[0]
    masks = tmp_path / "masks.tif"
    tifffile.imwrite(masks, truth.scene.camera_labels().astype(np.uint16))
    slip = dataclasses.replace(truth.microscope, pixel_size_um=10 * truth.microscope.pixel_size_um)
    microscope = save_settings(slip, tmp_path / "slip.yaml")
    out = tmp_path / "fit"
    assert _fit(image, "--masks", masks, "--microscope", microscope, "--out", out) == 2
    captured = capsys.readouterr()
    error = captured.err[captured.err.index("napari-symbac fit: error: ") :].splitlines()[0]
    assert "the masks' cells are " in error
    assert "wider than any rod-shaped bacterium" in error
    assert f"(pixel size {slip.pixel_size_um:g} um)" in error
    assert "Check pixel_size_um" in error
    assert not out.exists()


def test_every_problem_of_the_report_is_said_and_counted(tmp_path, truth, inputs, capsys):
    """A magnification that makes a 650 um camera pixel (the pixel size itself right)
    is said before the fit and listed in report.txt with the iteration limit's problems;
    every problem of report.txt is said on stderr and counted on stdout."""
    image, labels, _ = inputs
    slip = dataclasses.replace(truth.microscope, magnification=10 * truth.microscope.magnification)
    microscope = save_settings(slip, tmp_path / "slip.yaml")
    out = tmp_path / "fit"
    assert _fit(image, "--labels", labels, "--microscope", microscope, "--out", out,
                "--max-iterations", 2) == 0  # fmt: skip
    captured = capsys.readouterr()
    camera_pixel = f"{truth.microscope.pixel_size_um * slip.magnification:.3g} um camera pixel"
    warned = captured.err.index(f"napari-symbac fit: warning: pixel size {slip.pixel_size_um:g}")
    assert camera_pixel in captured.err[warned:].splitlines()[0]
    assert warned < captured.err.index("napari-symbac fit: fitting frame 0")
    problems = (out / "report.txt").read_text().split("PROBLEMS\n")[1].split("\n\n")[0]
    listed = [line[2:] for line in problems.splitlines()]
    assert any(camera_pixel in p for p in listed)
    said = [line for line in captured.err.splitlines() if ": frame 0: problem: " in line]
    assert len(said) == len(listed) >= 2  # the camera pixel, and the iteration limit
    n = len(listed)
    assert captured.out.splitlines()[0].endswith(f"; {n} problems, see report.txt")


def test_the_camera_pixel_check_passes_real_cameras():
    from napari_symbac.fit.preflight import camera_pixel_problem

    for pixel_um, magnification in ((0.065, 100), (0.108, 60), (0.13, 100), (0.16, 100),
                                    (0.325, 20), (0.043, 150)):  # fmt: skip
        scope = Microscope(pixel_size_um=pixel_um, magnification=magnification)
        assert camera_pixel_problem(scope) is None, (pixel_um, magnification)
    for pixel_um, magnification in ((0.65, 100), (0.005, 100), (0.325, 150)):
        scope = Microscope(pixel_size_um=pixel_um, magnification=magnification)
        assert "check pixel_size_um and magnification" in camera_pixel_problem(scope)




def test_fit_writes_settings_cells_residual_figure_and_report(tmp_path, truth, inputs, capsys):
    image, labels, microscope = inputs
    out = tmp_path / "fit"
    assert _fit(image, "--labels", labels, "--microscope", microscope, "--out", out) == 0
    captured = capsys.readouterr()
    assert "pixel chi2" in captured.out
    # piped (not a terminal): one line per stage instead of a bar
    assert "napari-symbac fit: fitting frame 0" in captured.err
    assert "napari-symbac fit: writing outputs" in captured.err
    assert {p.name for p in out.iterdir()} == OUTPUTS

    settings = load_settings(out / "settings.yaml", PipelineSettings)
    assert settings.render.media_intensity == pytest.approx(2600, rel=0.03)
    assert settings.simulation.trench.width_um == pytest.approx(1.5, abs=0.03)
    assert settings.microscope == truth.microscope

    table = json.loads((out / "cells.json").read_text())
    assert len(table["cells"]) == 3
    for cell in table["cells"]:
        assert {"id", "x_um", "y_um", "length_um", "width_um", "angle_rad", "curvature_um"} <= set(
            cell
        )
    lengths = sorted(c["length_um"] for c in table["cells"])
    assert lengths == pytest.approx(sorted(truth.cells.length_um), abs=0.15)
    assert "pixel" in table["terms"]

    residual = tifffile.imread(out / "residual.tif")
    assert residual.shape == truth.image.shape
    assert residual.dtype == np.float32
    scaled = read_recording(out / "residual.tif")  # at the recording's scale, as Fiji reads it
    assert scaled.pixel_size_um == pytest.approx(truth.microscope.pixel_size_um, rel=1e-6)
    assert abs(float(residual.mean())) < 0.1 * float(residual.std())

    figure = iio.imread(out / "before_after.png")
    assert figure.ndim == 3
    assert figure.shape[2] == 3
    assert figure.shape[0] >= 4 * truth.image.shape[0]  # upscaled panels plus titles

    report = (out / "report.txt").read_text()
    assert "cells fitted: 3" in report
    assert _fact(report, "start") == "painted labels"
    assert "PROBLEMS" in report
    assert "ADU/e-" in _fact(report, "camera used")
    assert "read noise is too small to measure" not in report  # the truth's 8 e- is measured


def test_fit_settings_are_reusable_by_render(tmp_path, inputs):
    image, labels, microscope = inputs
    out = tmp_path / "fit"
    assert _fit(image, "--labels", labels, "--microscope", microscope, "--out", out,
                "--max-iterations", 2) == 0  # fmt: skip
    simulation = tmp_path / "sim"
    assert main(["simulate", "--out", str(simulation), "--frames", "2", "--seed", "1"]) == 0
    rendered = tmp_path / "rendered"
    assert main(["render", str(simulation), "--config", str(out / "settings.yaml"),
                 "--out", str(rendered)]) == 0  # fmt: skip
    assert tifffile.imread(rendered / "images.tif").shape[0] == 2


def test_a_trench_fit_renders_frames_of_the_recordings_size(tmp_path, truth):
    """Found as a user: the real trench (256 x 46 px, its walls 0.69 and 0.88 um from
    the edges) fitted, then rendered with the fit's settings.yaml, gave 256 x 43 px
    frames (equal margins from the left wall): a dataset of another size than the
    recording. Here the truth trench cut asymmetrically (3 columns off its right)."""
    image, labels = tmp_path / "real.tif", tmp_path / "labels.tif"
    recording = truth.image[:, :-3]
    tifffile.imwrite(image, recording)
    tifffile.imwrite(labels, scene_classes(truth.scene)[:, :-3].astype(np.uint8))
    microscope = save_settings(truth.microscope, tmp_path / "microscope.yaml")
    out = tmp_path / "fit"
    assert _fit(image, "--labels", labels, "--microscope", microscope, "--out", out,
                "--max-iterations", 2) == 0  # fmt: skip
    simulation = tmp_path / "sim"
    assert main(["simulate", "--config", str(out / "settings.yaml"), "--out", str(simulation),
                 "--frames", "2", "--seed", "1"]) == 0  # fmt: skip
    rendered = tmp_path / "rendered"
    assert main(["render", str(simulation), "--config", str(out / "settings.yaml"),
                 "--out", str(rendered)]) == 0  # fmt: skip
    assert tifffile.imread(rendered / "images.tif").shape[1:] == recording.shape


def test_camera_file_and_dark_frames_are_used(tmp_path, truth, inputs):
    image, labels, microscope = inputs
    camera = Camera(baseline_adu=100.0, sensitivity_adu_per_e=2.9)
    camera = save_settings(camera, tmp_path / "c.yaml")
    out = tmp_path / "with-camera"
    assert _fit(image, "--labels", labels, "--microscope", microscope, "--out", out,
                "--camera", camera, "--max-iterations", 3) == 0  # fmt: skip
    assert _fact((out / "report.txt").read_text(), "camera") == f"from --camera {camera}"
    settings = load_settings(out / "settings.yaml", PipelineSettings)
    assert settings.camera.sensitivity_adu_per_e == pytest.approx(2.9, rel=0.05)

    from napari_symbac.optics.camera import apply_camera_noise

    dark = tmp_path / "dark.tif"
    tifffile.imwrite(dark, apply_camera_noise(np.zeros((3, 64, 64)), truth.camera,
                                              np.random.default_rng(0)))  # fmt: skip
    out = tmp_path / "with-dark"
    assert _fit(image, "--labels", labels, "--microscope", microscope, "--out", out,
                "--dark", dark, "--max-iterations", 3) == 0  # fmt: skip
    report = (out / "report.txt").read_text()
    assert "(dark frames)" in report
    assert "64 x 64 px frames, another region" in report
    # the dark frames' mean: 100 ADU, standard error 2.9 * 8 / sqrt(3 * 64 * 64) = 0.21
    baseline = re.search(r"baseline ([0-9.]+) ADU", report)
    assert baseline is not None
    assert float(baseline.group(1)) == pytest.approx(100.0, abs=0.65)


def test_config_camera_is_honoured(tmp_path, inputs):
    image, labels, microscope = inputs
    config = tmp_path / "config.yaml"
    config.write_text(yaml.safe_dump({"camera": {"sensitivity_adu_per_e": 3.1}}))
    out = tmp_path / "fit"
    assert _fit(image, "--labels", labels, "--microscope", microscope, "--out", out,
                "--config", config, "--max-iterations", 1) == 0  # fmt: skip
    assert _fact((out / "report.txt").read_text(), "camera") == f"from --config {config}"


def test_the_recording_s_frame_interval_times_the_settings(
    tmp_path, truth, inputs, capsys
):
    """Found as a user: ``frame_interval_s`` of the microscope file was read and ignored
    (settings.yaml drew its series 3 min apart), and ``trench_width_um`` was read and
    used by nothing, both unsaid."""
    image, labels, _ = inputs
    microscope = tmp_path / "timed.yaml"
    fields = yaml.safe_load(save_settings(truth.microscope, tmp_path / "m.yaml").read_text())
    microscope.write_text(yaml.safe_dump(
        {**fields, "frame_interval_s": 120, "trench_width_um": 1.4}
    ))  # fmt: skip
    args = [image, "--microscope", microscope, "--labels", labels, "--max-iterations", 1]
    assert _fit(*args, "--out", tmp_path / "timed") == 0
    err = capsys.readouterr().err
    assert "fit: note: trench_width_um is not used: the trench's width is fitted" in err
    settings = load_settings(tmp_path / "timed" / "settings.yaml", PipelineSettings)
    assert settings.simulation.frame_interval_min == 2.0
    config = tmp_path / "config.yaml"  # the config's own interval wins
    config.write_text("simulation: {frame_interval_min: 5.0}\n")
    assert _fit(*args, "--config", config, "--out", tmp_path / "configured") == 0
    settings = load_settings(tmp_path / "configured" / "settings.yaml", PipelineSettings)
    assert settings.simulation.frame_interval_min == 5.0
    # without either, the image file's own (ImageJ's finterval: 45 s)
    timed = tmp_path / "timed.tif"
    tifffile.imwrite(timed, truth.image, imagej=True, metadata={"finterval": 45.0})
    assert _fit(timed, "--microscope", tmp_path / "m.yaml", "--labels", labels,
                "--max-iterations", 1, "--out", tmp_path / "from_tiff") == 0  # fmt: skip
    settings = load_settings(tmp_path / "from_tiff" / "settings.yaml", PipelineSettings)
    assert settings.simulation.frame_interval_min == 0.75


def test_a_tiff_disagreeing_with_the_microscope_is_settled_by_the_flag(
    tmp_path, truth, inputs, capsys
):
    _, labels, _ = inputs
    image = tmp_path / "real.tif"
    tifffile.imwrite(image, truth.image, imagej=True, resolution=(1 / 0.07, 1 / 0.07),
                     metadata={"unit": "um"})  # fmt: skip
    microscope = save_settings(truth.microscope, tmp_path / "microscope.yaml")  # 0.065 um
    out = tmp_path / "fit"
    args = [image, "--microscope", microscope, "--labels", labels, "--out", out]
    assert _fit(*args, "--max-iterations", 3) == 2
    assert capsys.readouterr().err.splitlines()[-1:] == [
        "napari-symbac fit: error: the image file records a pixel size of 0.07 um and "
        "--microscope 0.065 um: say which is right with --pixel-size-um 0.065 (or 0.07), or "
        "correct the file that is wrong"
    ]
    assert not out.exists()
    assert _fit(*args, "--max-iterations", 3, "--pixel-size-um", 0.07) == 0
    assert load_settings(out / "settings.yaml", PipelineSettings).microscope.pixel_size_um == (
        pytest.approx(0.07, rel=1e-6)
    )
    assert "pixel size 0.07 um from --pixel-size-um" in (out / "report.txt").read_text()


def test_a_series_of_frames_with_gaps_says_so_beside_its_tracks(tmp_path, truth, inputs, capsys):
    """Found as a user: frames 0 and 3 of a trench were linked wrongly across a division
    (a daughter "born" of no mother mid-trench); the note on gapped frames and the joint
    fit's warnings were only inside series.json. They are printed with the tracks."""
    _, labels, microscope = inputs
    image = tmp_path / "series.tif"
    tifffile.imwrite(image, np.stack([truth.image, truth.image[:, ::-1], truth.image]))
    out = tmp_path / "fit"
    capsys.readouterr()
    assert _fit(image, "--microscope", microscope, "--labels", labels, "--out", out,
                "--frames", "0,2", "--max-iterations", 3) == 0  # fmt: skip
    printed = capsys.readouterr().out
    series = json.loads((out / "series.json").read_text())
    assert "frames are not consecutive" in series["lineage"]["note"]
    assert f"NOTE (tracks): {series['lineage']['note']}" in printed
    for warning in series["warnings"]:
        assert f"PROBLEM (joint fit): {warning}" in printed
    # each frame's report names the shared optics' joint value and error (found as a
    # user: its PARAMETERS' error for them matched nothing in series.json)
    report = (out / "frame_0002" / "report.txt").read_text()
    assert series["shared"]
    for name, shared in series["shared"].items():
        assert f"{name} is shared by the frames and fitted jointly: {shared['value']:.4g}" in report


def test_frames_of_a_series_are_fitted_jointly_each_into_its_folder(
    tmp_path, truth, inputs, capsys
):
    _, labels, microscope = inputs  # one 2D label image serves every frame
    image = tmp_path / "series.tif"
    tifffile.imwrite(image, np.stack([truth.image, truth.image[:, ::-1]]))
    out = tmp_path / "fit"
    assert _fit(image, "--microscope", microscope, "--labels", labels, "--out", out,
                "--frames", "0-1", "--max-iterations", 3) == 0  # fmt: skip
    assert {p.name for p in out.iterdir()} == {
        "frame_0000", "frame_0001", "series.json", "ctc", "settings.yaml"
    }  # fmt: skip
    for folder in (out / "frame_0000", out / "frame_0001"):
        assert {p.name for p in folder.iterdir()} == OUTPUTS
    # `export --config OUT/settings.yaml` works for a series too (frame 0's settings), and
    # the command says where each file is (found as a user: it named settings.yaml and
    # cells.json as if they were in OUT)
    settings = (out / "settings.yaml").read_bytes()
    assert settings == (out / "frame_0000" / "settings.yaml").read_bytes()
    series = json.loads((out / "series.json").read_text())
    assert series["frames"] == [0, 1]
    # --max-iterations bounds the joint refinement too (found as a user: its limit was 15)
    assert 1 <= series["joint_iterations"] <= 3
    assert series["counts_mapping"] is None  # counts, not a normalised image
    assert "read as counts" not in (out / "frame_0000" / "report.txt").read_text()
    assert series["started_from_previous_frame"]["0"] is False  # frame 1: either start
    assert isinstance(series["started_from_previous_frame"]["1"], bool)
    correlation = series["correlation_with_previous_frame"]
    assert correlation["0"] is None
    assert 0.6 <= correlation["1"] <= 1.0  # a trench mirrored: the same field
    assert all(shift is not None for shift in series["lineage"]["drift_um"])  # linked
    # the second frame is the first mirrored left-right: the same three cells, same rows
    lineage = series["lineage"]
    assert lineage["tracks"] == [
        {"track": k, "first_frame": 0, "last_frame": 1, "parent": 0, "missing_frames": []}
        for k in (1, 2, 3)
    ]
    rows = {}
    for frame in ("0", "1"):
        cells = json.loads((out / f"frame_000{frame}" / "cells.json").read_text())["cells"]
        assert [c["track"] for c in cells] == lineage["track_ids"][frame]
        rows[frame] = {c["track"]: c["y_um"] for c in cells}
    for track in (1, 2, 3):  # a track is one cell: the same row in both frames
        assert rows["0"][track] == pytest.approx(rows["1"][track], abs=0.1)
    # the same tracks as a Cell Tracking Challenge result, read as the export's GT is
    res = out / "ctc" / "01_RES"
    assert {p.name for p in res.iterdir()} == {"mask000.tif", "mask001.tif", "res_track.txt"}
    table = np.loadtxt(res / "res_track.txt", dtype=int, ndmin=2)
    assert table.tolist() == [[1, 0, 1, 0], [2, 0, 1, 0], [3, 0, 1, 0]]
    for t in (0, 1):
        mask = tifffile.imread(res / f"mask{t:03d}.tif")
        assert mask.dtype == np.uint16
        assert set(np.unique(mask).tolist()) == {0, 1, 2, 3}
    from ctc_metrics import validate_sequence

    with contextlib.redirect_stdout(io.StringIO()):
        assert validate_sequence(str(res), threads=1)["Valid"] == 1
    assert set(series["shared"]) == {"apodisation_sigma_um", "defocus_sigma_um", "psf_offset"}
    for name, shared in series["shared"].items():
        # both frames measure the shared optics: the joint error is the smaller
        assert shared["se"] < min(f["se"] for f in shared["frame_by_frame"]), name
        fitted = json.loads((out / "frame_0001" / "cells.json").read_text())["parameters"]
        assert {p["name"]: p["value"] for p in fitted}[name] == pytest.approx(shared["value"])
    printed = capsys.readouterr().out
    assert "frame 1: fitted" in printed
    assert "(joint)" in printed
    assert "wrote ctc/, frame_0000/, frame_0001/, series.json, settings.yaml to" in printed
    assert "each frame_NNNN/ holds before_after.png, cells.json" in printed


@pytest.mark.slow
def test_real_trench_closed_end_chosen_by_the_fit_or_the_config(tmp_path, real_data_dir):
    """The SyMBac trench: its moulded round end is found by the fit (issue 10: "round
    closed end found from the CLI"); `closed_end` of the config is used as given."""
    microscope = save_settings(Microscope(pixel_size_um=0.065), tmp_path / "microscope.yaml")
    image = real_data_dir / "ecoli_100x_oil_exponential.tiff"
    chosen = tmp_path / "chosen"
    assert _fit(image, "--microscope", microscope, "--out", chosen, "--max-iterations", 4) == 0
    report = (chosen / "report.txt").read_text()
    assert _fact(report, "geometry") == "trench (closed end: round, chosen by the fit)"
    # dark cells with bright halos, said as what phase contrast shows, not as a doubt
    assert _fact(report, "modality") == (
        "phase (image polarity: both darker and brighter than its background, as phase "
        "contrast's halos are)"
    )
    assert "closed end: round, which fits better" in report
    settings = load_settings(chosen / "settings.yaml", PipelineSettings)
    assert settings.simulation.trench.closed_end == "round"
    config = tmp_path / "config.yaml"
    config.write_text(yaml.safe_dump({"simulation": {"trench": {"closed_end": "square"}}}))
    out = tmp_path / "fit"
    assert _fit(image, "--microscope", microscope, "--config", config, "--out", out,
                "--max-iterations", 2) == 0  # fmt: skip
    report = (out / "report.txt").read_text()
    assert _fact(report, "geometry") == "trench (closed end: square, from --config)"
    assert "used default render start, trench closed end" in _fact(report, "config")
    assert "which fits better" not in report
    settings = load_settings(out / "settings.yaml", PipelineSettings)
    assert settings.simulation.trench.closed_end == "square"
    table = json.loads((out / "cells.json").read_text())
    assert 3 <= len(table["cells"]) <= 8
    assert table["trench"]["closed_end"] == "square"
    # this recording's noise at the baseline is all shot noise: no read noise to measure,
    # and the report says so instead of giving 0 e- as a measurement
    assert "dark noise 0 e-" in _fact(report, "camera used")
    assert "the read noise is too small to measure from this image" in report


def test_a_normalised_trench_is_read_as_counts_and_exports_phase_contrast(
    tmp_path, real_data_dir, capsys
):
    """DeLTA's normalised trench (float32, -0.03..1.01): refused for its negative values,
    then, shifted by hand, fitted and exported as a dataset of the integers 0 and 1
    (found as a user). Read as counts it fits, and its dataset shows the trench."""
    from napari_symbac.export import export_of
    from napari_symbac.export.dataset import PipelineSource

    microscope = save_settings(Microscope(pixel_size_um=0.065), tmp_path / "microscope.yaml")
    out = tmp_path / "fit"
    image = real_data_dir / "ecoli_delta_phase_normalised.tiff"
    assert _fit(image, "--microscope", microscope, "--out", out, "--max-iterations", 2) == 0
    said = capsys.readouterr().err
    assert "normalised values (-0.02847..1.007, not camera counts): read as (value + " in said
    # its cells are darker than the linear kernel draws them: the limit is said
    report = (out / "report.txt").read_text()
    assert "at a bound: cell_intensity is 0 ADU, the least the model allows" in report
    # found as a user: report.txt's camera (0.015 ADU/e-, 531 e-) read as a real camera's
    from napari_symbac.io import NORMALISED_ADU_PER_UNIT

    read_as = f"(value + 0.02847) x {NORMALISED_ADU_PER_UNIT:g} ADU"
    assert _fact(report, "image values").startswith("normalised values (-0.02847..1.007")
    for key in ("camera used", "camera (model-free)"):
        assert _fact(report, key).endswith(
            f"[normalised image read as counts, {read_as}: not a real camera's units]"
        )
    every = "- every ADU and e- in this report is of the normalised image read as counts"
    assert f"{every}, {read_as}" in report
    settings = load_settings(out / "settings.yaml", PipelineSettings)
    item = PipelineSource(export_of(settings, n_items=1)).make_unit(0)[0]
    assert item.image.shape == (256, 32)
    cells, rest = item.image[item.labels > 0], item.image[item.labels == 0]
    assert np.unique(item.image).size > 500  # grey levels, not 0 and 1
    assert len(np.unique(item.labels)) >= 4  # three cells or more
    # dark cells against the bright media between them, as in the recording
    assert np.median(cells) < np.percentile(rest, 90) - 1000


def test_a_trench_beyond_16_bits_is_fitted_divided_and_its_dataset_is_not_clipped(
    tmp_path, real_data_dir, capsys
):
    """Found as a user: the trench times 20 (float32, maximum 150140, as a sum
    projection) was fitted with a 16-bit camera and exported with 20 % of its pixels at
    65535, exit 0, nothing said. It is read divided into 16 bits, said, and a camera
    given for the file's values is divided with it."""
    from napari_symbac.export import export_of
    from napari_symbac.export.dataset import PipelineSource

    trench = tifffile.imread(real_data_dir / "ecoli_100x_oil_exponential.tiff")[:128]
    image = tmp_path / "sum20.tif"
    tifffile.imwrite(image, trench.astype(np.float32) * 20)
    microscope = save_settings(Microscope(pixel_size_um=0.065), tmp_path / "microscope.yaml")
    camera = save_settings(
        Camera(baseline_adu=2000.0, sensitivity_adu_per_e=40.0, dark_noise_e=2.0),
        tmp_path / "camera.yaml",
    )
    out = tmp_path / "fit"
    args = ("--microscope", microscope, "--max-iterations", 2, "--out", out)
    assert _fit(image, *args, "--camera", camera) == 0
    said = capsys.readouterr().err
    assert "beyond the 16 bits (65535) of a synthetic camera: read as value / 4 ADU" in said
    report = (out / "report.txt").read_text()
    assert _fact(report, "camera used").startswith(
        "sensitivity 10 ADU/e-, baseline 500.0 ADU, dark noise 2 e-"
    )
    assert "[image beyond 16 bits read divided, value / 4 ADU" in _fact(report, "camera used")
    settings = load_settings(out / "settings.yaml", PipelineSettings)
    item = PipelineSource(export_of(settings, n_items=1)).make_unit(0)[0]
    assert item.image.max() < 65535
    assert np.mean(item.image >= 50_000) == 0  # within the divided range, with room
    assert len(np.unique(item.labels)) >= 2


def test_a_trench_fitted_as_a_field_is_said(tmp_path, real_data_dir, capsys):
    """Found as a user: DeLTA's trench with --geometry field ended with 2 rods laid along
    its walls, exit 0, and nothing said of the geometry. The fit keeps few of its start's
    rods there, and is refused naming the geometry and its fix (a trench-shaped frame
    whose fit holds is fitted with the problem said: test_the_trench_shaped_...). The
    same trench fitted as a trench is fitted, with no such problem."""
    microscope = save_settings(Microscope(pixel_size_um=0.065), tmp_path / "microscope.yaml")
    image = real_data_dir / "ecoli_delta_phase_normalised.tiff"
    said = "narrow and tall as a mother-machine trench, and was fitted as an open field"
    args = ("--microscope", microscope, "--max-iterations", 2)
    error = _refused(capsys, tmp_path / "field", image, *args, "--geometry", "field")
    assert "cells its automatic start found" in error
    assert said in error
    assert "leave --geometry out (or pass --geometry trench)" in error
    out = tmp_path / "trench"
    assert _fit(image, *args, "--out", out, "--geometry", "trench") == 0
    assert said not in (out / "report.txt").read_text()
    assert said not in capsys.readouterr().err


def test_the_trench_shaped_field_fitted_as_a_field_is_said(tmp_path, truth, capsys):
    """A trench-shaped frame fitted as a field whose fit holds (the rendered truth trench,
    its cells kept) is fitted, with the geometry named as a problem in report.txt."""
    microscope = save_settings(truth.microscope, tmp_path / "microscope.yaml")
    image = tmp_path / "trench.tif"
    tifffile.imwrite(image, truth.image)
    out = tmp_path / "field"
    args = ("--microscope", microscope, "--out", out, "--max-iterations", 2)
    assert _fit(image, *args, "--geometry", "field") == 0
    said = "narrow and tall as a mother-machine trench, and was fitted as an open field"
    assert said in (out / "report.txt").read_text()
    assert said in capsys.readouterr().err


def test_a_phase_trench_fitted_as_fluorescence_names_the_modality(
    tmp_path, real_data_dir, capsys
):
    """Found as a user: DeLTA's phase trench with --modality fluorescence (its look does
    not settle the modality) was refused for finding no cells with only masks or labels
    as the way out; the refusal names dark cells, phase contrast and bright field."""
    microscope = save_settings(Microscope(pixel_size_um=0.065), tmp_path / "microscope.yaml")
    image = real_data_dir / "ecoli_delta_phase_normalised.tiff"
    error = _refused(capsys, tmp_path / "o", image, "--microscope", microscope,
                     "--modality", "fluorescence")  # fmt: skip
    assert "the start found no cells" in error
    assert "cells darker than their background, as phase contrast and bright field" in error


def test_a_normalised_series_marks_its_camera_as_a_single_frame_does(
    tmp_path, real_data_dir, capsys
):
    """A (T, Y, X) stack of DeLTA's normalised trench (its top half, and the same mirrored)
    fitted jointly: each frame's report.txt marks its camera as a single frame's does,
    and series.json, which holds the shared camera, carries the map as numbers."""
    from napari_symbac.io import CountsMapping

    trench = tifffile.imread(real_data_dir / "ecoli_delta_phase_normalised.tiff")[:128]
    image = tmp_path / "normalised_series.tif"
    tifffile.imwrite(image, np.stack([trench, trench[:, ::-1]]))
    microscope = save_settings(Microscope(pixel_size_um=0.065), tmp_path / "microscope.yaml")
    out = tmp_path / "fit"
    assert _fit(image, "--microscope", microscope, "--out", out, "--frames", "0-1",
                "--max-iterations", 1) == 0  # fmt: skip
    read_as = "(value + 0.02847) x 10000 ADU"
    every = "- every ADU and e- in this report is of the normalised image read as counts"
    assert f"read as {read_as}" in capsys.readouterr().err
    for folder in ("frame_0000", "frame_0001"):
        report = (out / folder / "report.txt").read_text()
        assert _fact(report, "image values").startswith("normalised values (-0.02847..1.007")
        assert _fact(report, "camera used").endswith(
            f"[normalised image read as counts, {read_as}: not a real camera's units]"
        )
        assert f"{every}, {read_as}" in report
    series = json.loads((out / "series.json").read_text())
    record = series["counts_mapping"]
    assert record["read_as"] == read_as
    assert record["note"].startswith("every ADU and e- in this file is of the normalised")
    assert series["camera"]["sensitivity_adu_per_e"] > 0
    # the numbers are the map: series.json's record maps the counts back to the file
    mapping = CountsMapping(**{k: record[k] for k in ("shift", "adu_per_unit",
                                                      "value_min", "value_max")})  # fmt: skip
    counts = mapping.counts_adu(trench)
    assert counts.min() == 0
    np.testing.assert_allclose(mapping.values(counts), trench, atol=1e-6)


def test_a_phase_colony_with_its_masks_is_fitted_with_its_halo(tmp_path, real_data_dir):
    """Found as a user: `fit` on an Omnipose colony with its masks (a grey PNG) drew the
    cells through the linear kernel, a grey copy without the colony's halo, dropped
    cells and took minutes. Now the masks' scene is fitted with the partially coherent
    model: every measurable mask a cell, the halo beside the colony reproduced."""
    root = real_data_dir / "omnipose"
    crop = (slice(80, 176), slice(336, 432))  # half cells, half pad beside the colony
    grey = iio.imread(root / "Sample000193.png")[..., 0][crop]
    masks = tifffile.imread(root / "Sample000193_cp_masks.tif")[crop]
    image, mask_file = tmp_path / "colony.png", tmp_path / "masks.tif"
    iio.imwrite(image, grey)
    tifffile.imwrite(mask_file, masks)
    microscope = save_settings(Microscope(pixel_size_um=0.0745), tmp_path / "microscope.yaml")
    out = tmp_path / "fit"
    assert _fit(image, "--microscope", microscope, "--geometry", "field", "--masks", mask_file,
                "--out", out) == 0  # fmt: skip
    report = (out / "report.txt").read_text()
    assert "dense colony: the cells are the masks'" in report[report.index("NOTES") :]
    assert _fact(report, "camera").startswith("not fitted: Gaussian noise, ")
    before, after = map(float, re.search(r"pixel: (\S+) -> (\S+)", report).groups())
    assert after < 0.8 * before
    settings = load_settings(out / "settings.yaml", PipelineSettings)
    assert settings.render.phase_model == "partially_coherent"
    assert settings.render.noise_model == "gaussian"
    assert settings.simulation.geometry == "agar_pad"
    # a pad of the recording's size (it was the default 40 um: 537 px frames for 96)
    pad = settings.simulation.agar_pad
    assert (pad.field_height_um, pad.field_width_um) == pytest.approx((96 * 0.0745,) * 2)
    table = json.loads((out / "cells.json").read_text())
    sizes = np.bincount(masks.ravel())[1:]
    assert len(table["cells"]) == int(np.count_nonzero(sizes * 0.0745**2 >= 0.25))
    phase = next(p for p in table["parameters"] if p["name"] == "cell_phase_rad")
    assert 0 < phase["se"] < 0.05 * phase["value"]
    # each cell's own optical path: in cells.json, said in the report, drawn by settings
    gains = [cell["optical_path_gain"] for cell in table["cells"]]
    assert all(0 < g < 3 for g in gains)
    assert np.std(gains) > 0.01
    assert "each cell's own optical path fitted after the optics" in report
    assert settings.render.cell_brightness_cv > 0
    # drawn as recorded: the fitted optical path per unit of the pad's drawn material (the
    # fit's is per unit of the masks' scene: chord / width), and colonies packed as the
    # recording's by simulated gravity (found as a user: loose colonies at the masks'
    # phase, exported cells far darker than the recording's)
    simulation = settings.simulation
    drawn_phase = phase["value"] * simulation.trench.depth_um / simulation.cell_width_um
    assert settings.render.cell_phase_rad == pytest.approx(drawn_phase, rel=1e-4)
    assert simulation.phys_iters == PAD_PHYS_ITERS
    assert f"gravity {simulation.gravity:g} um/min towards each colony's centre" in report
    # the halo: the pad within 4 px of the colony is brighter than the pad beyond 12 px,
    # in the real image and, by at least half as much, in the fitted one
    fitted = grey - tifffile.imread(out / "residual.tif")
    distance = ndimage.distance_transform_edt(masks == 0)
    near, far = (distance > 0) & (distance <= 4), distance > 12
    real_halo = np.median(grey[near]) - np.median(grey[far])
    fitted_halo = np.median(fitted[near]) - np.median(fitted[far])
    assert real_halo > 5
    assert fitted_halo > 0.5 * real_halo


def test_a_phase_colony_time_lapse_shares_its_optics_and_tracks_the_masks(
    tmp_path, real_data_dir
):
    """Found as a user: `fit --frames` on a colony's time-lapse with its masks went
    through the linear series fit (no halo). Now the optics are fitted once, on the frame
    whose masks cover most, and shared; each frame's cells are its masks' (ids = the
    masks' labels) linked into tracks, written as a CTC result. Two windows of a real
    colony 3 px apart stand for a drifting stage."""
    root = real_data_dir / "omnipose"
    grey = iio.imread(root / "Sample000193.png")[..., 0]
    full = tifffile.imread(root / "Sample000193_cp_masks.tif")
    windows = [(slice(80, 176), slice(336, 432)), (slice(77, 173), slice(338, 434))]
    image, mask_file = tmp_path / "series.tif", tmp_path / "masks.tif"
    tifffile.imwrite(image, np.stack([grey[w] for w in windows]))
    masks = np.stack([full[w] for w in windows])
    tifffile.imwrite(mask_file, masks)
    microscope = save_settings(Microscope(pixel_size_um=0.0745), tmp_path / "microscope.yaml")
    out = tmp_path / "fit"
    assert _fit(image, "--microscope", microscope, "--geometry", "field", "--masks", mask_file,
                "--frames", "0-1", "--out", out) == 0  # fmt: skip
    series = json.loads((out / "series.json").read_text())
    reference = series["optics_started_on_frame"]
    assert reference in (0, 1)
    assert 0 < series["shared"]["cell_phase_rad"]["se"] < 0.05
    assert series["joint_chi2"]["end"] <= series["joint_chi2"]["start"]
    for t in (0, 1):
        report = (out / f"frame_{t:04d}" / "report.txt").read_text()
        notes = report[report.index("NOTES") :]
        assert "dense colony: the cells are the masks'" in notes
        assert "the optics are fitted on all frames jointly" in " ".join(notes.split())
        before, after = map(float, re.search(r"pixel: (\S+) -> (\S+)", report).groups())
        assert after < 0.8 * before
        settings = load_settings(out / f"frame_{t:04d}" / "settings.yaml", PipelineSettings)
        assert settings.render.phase_model == "partially_coherent"
    # cells.json ids are the masks' labels; a cell whole in both windows keeps its track
    tracks = []
    for t in (0, 1):
        cells = json.loads((out / f"frame_{t:04d}" / "cells.json").read_text())["cells"]
        assert {c["id"] for c in cells} <= set(np.unique(masks[t]).tolist()) - {0}
        tracks.append({c["id"]: c["track"] for c in cells})
    inner = masks[:, 1:-1, 1:-1]
    whole = [
        k for k in set(tracks[0]) & set(tracks[1])
        if all((inner[t] == k).sum() == (masks[t] == k).sum() for t in (0, 1))
    ]
    assert len(whole) >= 5
    assert all(tracks[0][k] == tracks[1][k] for k in whole)
    ctc = tifffile.imread(out / "ctc" / "01_RES" / "mask001.tif")
    for k in whole:
        assert set(np.unique(ctc[masks[1] == k]).tolist()) == {tracks[1][k]}


def test_a_phase_field_of_separate_cells_keeps_the_scene_fit(tmp_path, capsys):
    """Masks of cells that do not touch are no colony: the scene fit (linear kernel)
    fits their geometry, and the report says what it cannot do."""
    from _fit_synthetic import TRUTH, make_cells

    from napari_symbac.optics import ForwardModel
    from napari_symbac.scene import Field, draw_scene
    from napari_symbac.settings import TrenchGeometry

    scope = Microscope(pixel_size_um=0.08)
    cells = make_cells(y_um=[1.8, 5.4], x_um=[1.6, 5.6], angle_rad=[0.3, 1.2])
    scene = draw_scene(cells, TrenchGeometry(), scope, TRUTH, field=Field(7.68, 7.68))
    frame = ForwardModel(scope, TRUTH, Camera()).render(scene, np.random.default_rng(3))
    image, mask_file = tmp_path / "field.tif", tmp_path / "masks.tif"
    tifffile.imwrite(image, frame)
    tifffile.imwrite(mask_file, scene.camera_labels().astype(np.uint16))
    microscope = save_settings(scope, tmp_path / "m.yaml")
    out = tmp_path / "fit"
    assert _fit(image, "--microscope", microscope, "--geometry", "field", "--masks", mask_file,
                "--out", out, "--max-iterations", 2) == 0  # fmt: skip
    notes = (out / "report.txt").read_text().split("NOTES")[1]
    assert "linear (weak-phase) kernel" in notes
    assert "napari-symbac fit IMAGE --masks M" in notes
    assert "dense colony" not in notes
    # said before the fit too (found as a user: a colony without masks fitted for
    # minutes in silence, the advice only in the report at the end)
    err = capsys.readouterr().err
    note = err.index("napari-symbac fit: note: phase contrast is fitted here with the linear")
    assert note < err.index("fitting frame 0")
    # its faint halos read as bright field's: said as a note, first, not a refusal
    assert err.index(f"napari-symbac fit: note: {BRIGHT_FIELD_NOTE}") < err.index("fitting frame 0")


@pytest.mark.slow
def test_real_colicoords_fluorescence_field_with_masks(tmp_path, real_data_dir):
    """A crop of ColiCoords ds1 field 1 (4 whole cells), background-subtracted."""
    root = real_data_dir / "colicoords" / "test_data" / "ds1"
    flu = tifffile.imread(root / "fluorescence" / "00001.tif")[90:200, 60:320]
    masks = tifffile.imread(root / "binary" / "00001_Probabilities_filtered.tif")[90:200, 60:320]
    image, mask_file = tmp_path / "flu.tif", tmp_path / "masks.tif"
    tifffile.imwrite(image, flu)
    tifffile.imwrite(mask_file, masks)
    microscope = save_settings(Microscope(pixel_size_um=0.08), tmp_path / "microscope.yaml")
    out = tmp_path / "fit"
    assert _fit(image, "--microscope", microscope, "--modality", "fluorescence",
                "--geometry", "field", "--masks", mask_file, "--out", out,
                "--max-iterations", 3) == 0  # fmt: skip
    report = (out / "report.txt").read_text()
    assert _fact(report, "modality") == "fluorescence (image polarity: bright cells)"
    zeros = int((flu == 0).sum())
    assert _fact(report, "censored pixels").startswith(f"{zeros} (")  # background-subtracted
    assert load_settings(out / "settings.yaml", PipelineSettings).microscope.modality == (
        "fluorescence"
    )
    n_masks = ndimage.label(masks > 0)[1]
    cells = json.loads((out / "cells.json").read_text())["cells"]
    # every mask holds the centre of a fitted cell
    rows = [round(c["y_um"] / 0.08) for c in cells]
    cols = [round(c["x_um"] / 0.08) for c in cells]
    inside = {int(masks[r, c]) for r, c in zip(rows, cols, strict=True)
              if 0 <= r < masks.shape[0] and 0 <= c < masks.shape[1]}  # fmt: skip
    assert set(np.unique(masks[masks > 0]).tolist()) <= inside
    # and each fitted cell names the label of the masks it lies on: every label is named
    assert {c["mask_label"] for c in cells} - {None} == set(np.unique(masks[masks > 0]).tolist())
    for cell, r, c in zip(cells, rows, cols, strict=True):
        if cell["mask_label"] is not None and masks[r, c]:
            assert masks[r, c] == cell["mask_label"]
    # a count that differs from the masks' is said plainly in report.txt
    if len(cells) != n_masks:
        assert f"the fit ended with {len(cells)} cells from the {n_masks} of --masks" in report
    # a field fit re-renders as an agar pad with the fitted cell width
    simulation = load_settings(out / "settings.yaml", PipelineSettings).simulation
    assert simulation.geometry == "agar_pad"
    widths = [c["width_um"] for c in json.loads((out / "cells.json").read_text())["cells"]]
    assert simulation.cell_width_um == pytest.approx(float(np.median(widths)))
    # and dividing at the length that makes the fitted lengths' median a population's (it
    # kept the default 3.5 um where the real trench's cells are 4.6-5.3 um long)
    lengths = [c["length_um"] for c in cells]
    assert simulation.cell_max_length_um == pytest.approx(
        max(1.5 * np.median(lengths), 1.3 * simulation.cell_width_um)
    )
    # on a pad of the recording's size
    pad = simulation.agar_pad
    assert (pad.field_height_um, pad.field_width_um) == pytest.approx(
        (masks.shape[0] * 0.08, masks.shape[1] * 0.08)
    )
    # drawn with the spread of the fitted cells' own intensities, not every cell alike
    intensities = np.array([c["intensity_adu"] for c in cells])
    render = load_settings(out / "settings.yaml", PipelineSettings).render
    assert render.cell_brightness_cv == pytest.approx(
        np.std(intensities, ddof=1) / np.mean(intensities)
    )
    assert render.cell_brightness_cv > 0.1
    # none brighter than the brightest fitted cell (a few cells' spread has a long tail)
    assert render.cell_brightness_max_gain == pytest.approx(
        intensities.max() / intensities.mean()
    )
    # and with the background's clip: 0 ADU, as in the recording
    stages = load_settings(out / "settings.yaml", PipelineSettings).extra_stages
    assert [(s.name, s.parameters["clip_level_adu"]) for s in stages] == [("saturation", 0.0)]

    # a binary mask (0/1) of the same cells: its connected regions are the cells; no
    # --geometry: fluorescence shows no walls, so the default is the open field
    binary = tmp_path / "binary.tif"
    tifffile.imwrite(binary, (masks > 0).astype(np.uint8))
    out = tmp_path / "fit-binary"
    assert _fit(image, "--microscope", microscope, "--modality", "fluorescence",
                "--masks", binary, "--out", out, "--max-iterations", 3) == 0  # fmt: skip
    report = (out / "report.txt").read_text()
    assert f"its {n_masks} connected regions are the cells" in report
    assert _fact(report, "geometry") == "field"


# --------------------------------------------------------------------------------------
# Refusals: message, exit code 2, nothing written
# --------------------------------------------------------------------------------------


def _refused(capsys, out, *args) -> str:
    code = _fit(*args, "--out", out)
    assert code == 2
    assert not out.exists()
    assert not list(out.parent.glob(f".{out.name}.partial-*"))
    error = capsys.readouterr().err
    assert "Traceback" not in error
    return error


def test_refuses_negative_values(tmp_path, truth, inputs, capsys):
    _, _, microscope = inputs
    image = tmp_path / "negative.tif"
    tifffile.imwrite(image, truth.image.astype(np.float32) - 2000.0)
    error = _refused(capsys, tmp_path / "o", image, "--microscope", microscope)
    assert "negative values" in error
    assert "--camera" in error


@pytest.mark.parametrize("geometry", ["trench", "field"])
def test_refuses_a_frame_of_noise_alone(tmp_path, inputs, capsys, geometry):
    """Found as a user: a 256 x 256 frame of pure noise was fitted as a field with "1 cell"
    0.3 um wide, exit 0, and told it held "2 trenches side by side" as a trench."""
    _, _, microscope = inputs
    image = tmp_path / "noise.tif"
    shape = (256, 46) if geometry == "trench" else (256, 256)
    tifffile.imwrite(image, np.random.default_rng(5).poisson(1000, shape).astype(np.uint16))
    error = _refused(capsys, tmp_path / "o", image, "--microscope", microscope,
                     "--geometry", geometry)  # fmt: skip
    (refusal,) = [line for line in error.splitlines() if "found no cells" in line]
    assert "blank or dark frame" in refusal


def test_a_normalised_image_is_fitted_as_counts(tmp_path, truth, inputs, capsys):
    """A recording divided by its maximum (float 0..1) was fitted as camera counts, exit 0,
    a camera of 0.011 ADU/e-, and datasets drawn from the fit held only 0 and 1 (found
    by trying the CLI as a user); then refused. It is read as counts, x 10000: a linear
    map, so the photon-transfer line gives the camera's gain times the same factor."""
    from napari_symbac.io import NORMALISED_ADU_PER_UNIT

    raw, _, microscope = inputs
    image = tmp_path / "normalised.tif"
    top = float(truth.image.max())
    tifffile.imwrite(image, (truth.image / top).astype(np.float32))
    gains, reports = [], []
    for path in (raw, image):
        out = tmp_path / path.stem
        assert _fit(path, "--microscope", microscope, "--out", out, "--max-iterations", 2) == 0
        camera = load_settings(out / "settings.yaml", PipelineSettings).camera
        gains.append(camera.sensitivity_adu_per_e)
        reports.append((out / "report.txt").read_text())
    # report.txt says the gain is of the image read as counts, not a camera's; the raw
    # recording's report does not
    marked = "[normalised image read as counts, (value) x 10000 ADU: not a real camera's units]"
    assert _fact(reports[1], "camera used").endswith(marked)
    assert "read as counts" not in reports[0]
    assert "not camera counts): read as (value) x 10000 ADU" in capsys.readouterr().err
    assert gains[1] == pytest.approx(gains[0] * NORMALISED_ADU_PER_UNIT / top, rel=1e-3)
    assert gains[0] == pytest.approx(truth.camera.sensitivity_adu_per_e, rel=0.2)


def test_refuses_a_fluorescence_field_fitted_as_phase(tmp_path, real_data_dir, capsys):
    image = real_data_dir / "colicoords" / "test_data" / "ds1" / "fluorescence" / "00001.tif"
    microscope = save_settings(Microscope(pixel_size_um=0.08), tmp_path / "microscope.yaml")
    error = _refused(capsys, tmp_path / "o", image, "--microscope", microscope,
                     "--geometry", "field")  # fmt: skip
    assert "does not look like phase" in error
    assert "--modality fluorescence" in error


def test_a_bright_field_image_refused_as_fluorescence_is_told_of_brightfield(
    tmp_path, real_data_dir, capsys
):
    """Found as a user: ColiCoords' bright field fitted as fluorescence was refused with
    "Pass --modality phase" only; bright field is a modality of its own."""
    image = tmp_path / "bf.tif"
    field = tifffile.imread(real_data_dir / "colicoords/test_data/ds1/brightfield/00001.tif")
    tifffile.imwrite(image, field[80:240, 60:320])
    microscope = save_settings(Microscope(pixel_size_um=0.08), tmp_path / "microscope.yaml")
    error = _refused(capsys, tmp_path / "o", image, "--microscope", microscope,
                     "--modality", "fluorescence")  # fmt: skip
    assert "does not look like fluorescence" in error
    assert "Pass --modality phase, or brightfield for bright field" in error


def test_refuses_a_fluorescence_trench_it_cannot_place(tmp_path, real_data_dir, capsys):
    """Found as a user: the Python API's words (``trench=TrenchPlacement(...)``) reached
    the command line; the CLI now says which flag to pass."""
    image = real_data_dir / "colicoords" / "test_data" / "ds1" / "fluorescence" / "00001.tif"
    microscope = save_settings(Microscope(pixel_size_um=0.08), tmp_path / "microscope.yaml")
    error = _refused(capsys, tmp_path / "o", image, "--microscope", microscope,
                     "--modality", "fluorescence", "--geometry", "trench")  # fmt: skip
    assert "no trench walls" in error
    assert "--geometry field" in error


@pytest.mark.parametrize(
    ("configured", "shape_px", "modality", "expected"),
    [
        (None, (256, 46), "phase", "trench"),
        (None, (3, 256, 32), "phase", "trench"),
        (None, (512, 512), "phase", "field"),
        (None, (57, 61), "phase", "field"),  # a crop around one cell on a pad
        (None, (91, 46), "phase", "field"),
        (None, (256, 46), "fluorescence", "field"),
        ("agar_pad", (256, 46), "phase", "field"),
        ("trench", (512, 512), "phase", "trench"),
        ("chamber", (512, 512), "phase", "trench"),
        ("trench", (256, 46), "fluorescence", "field"),
    ],
)
def test_default_geometry(configured, shape_px, modality, expected):
    from napari_symbac.fit.preflight import default_geometry

    assert default_geometry(shape_px, modality, configured) == expected


def test_keep_cells_fits_the_masks_cells_and_no_others(tmp_path, real_data_dir):
    """Found as a user: `fit --masks` added cells the masks leave out (ds2 00066: 6
    masked cells fitted as 10), with no way to keep the annotated set. Of ColiCoords ds1
    field 1's crop with one cell's mask erased, the moves add it back; --keep-cells
    fits the masks' three."""
    root = real_data_dir / "colicoords" / "test_data" / "ds1"
    flu = tifffile.imread(root / "fluorescence" / "00001.tif")[90:200, 60:320]
    masks = tifffile.imread(root / "binary" / "00001_Probabilities_filtered.tif")[90:200, 60:320]
    regions, n = ndimage.label(masks > 0)
    assert n == 4
    masks = np.where(regions == 4, 0, regions).astype(np.uint16)
    image, mask_file = tmp_path / "flu.tif", tmp_path / "masks.tif"
    tifffile.imwrite(image, flu)
    tifffile.imwrite(mask_file, masks)
    microscope = save_settings(Microscope(pixel_size_um=0.08), tmp_path / "microscope.yaml")
    counts = {}
    for keep in (False, True):
        out = tmp_path / f"fit-{keep}"
        extra = ["--keep-cells"] if keep else []
        assert _fit(image, "--microscope", microscope, "--modality", "fluorescence",
                    "--masks", mask_file, "--out", out, "--max-iterations", 3,
                    *extra) == 0  # fmt: skip
        cells = json.loads((out / "cells.json").read_text())["cells"]
        counts[keep] = len(cells)
        report = (out / "report.txt").read_text()
        said = "cells from the 3 of --masks" in report
        assert said == (len(cells) != 3)
    assert counts == {False: 4, True: 3}


def test_refuses_masks_whose_cells_contradict_the_modality(tmp_path, real_data_dir, capsys):
    root = real_data_dir / "colicoords" / "test_data" / "ds1"
    microscope = save_settings(Microscope(pixel_size_um=0.08), tmp_path / "microscope.yaml")
    error = _refused(capsys, tmp_path / "o", root / "brightfield" / "00001.tif",
                     "--microscope", microscope, "--modality", "fluorescence",
                     "--masks", root / "binary" / "00001_Probabilities_filtered.tif")  # fmt: skip
    assert "masked cells are darker" in error
    assert "--modality phase" in error


def test_refuses_labels_without_media(tmp_path, inputs, capsys):
    image, labels, microscope = inputs
    painted = tifffile.imread(labels)
    painted[painted == 2] = 0
    no_media = tmp_path / "no_media.tif"
    tifffile.imwrite(no_media, painted)
    error = _refused(capsys, tmp_path / "o", image, "--microscope", microscope,
                     "--labels", no_media)  # fmt: skip
    assert "no media class (2)" in error


@pytest.mark.parametrize("option", ["--labels", "--masks"])
def test_refuses_labels_or_masks_of_the_wrong_shape(tmp_path, inputs, capsys, option):
    image, labels, microscope = inputs
    wrong = tmp_path / "wrong.tif"
    tifffile.imwrite(wrong, tifffile.imread(labels)[:-3])
    error = _refused(capsys, tmp_path / "o", image, "--microscope", microscope, option, wrong)
    assert "has shape (125, 46) but the image frame has shape (128, 46)" in error


def test_refuses_a_series_without_frames_and_frames_out_of_range(tmp_path, truth, capsys):
    image = tmp_path / "series.tif"
    tifffile.imwrite(image, np.stack([truth.image, truth.image]))
    microscope = save_settings(truth.microscope, tmp_path / "microscope.yaml")
    error = _refused(capsys, tmp_path / "o", image, "--microscope", microscope)
    assert "has 2 frames: pass --frames" in error
    error = _refused(capsys, tmp_path / "o", image, "--microscope", microscope, "--frames", "5")
    assert "frame(s) 5 do not exist: series.tif has 2 frames, numbered 0-1" in error
    error = _refused(capsys, tmp_path / "o", image, "--microscope", microscope, "--frames", "x")
    assert "not a frame list" in error


def test_refuses_a_series_with_a_frame_without_cells(tmp_path, truth, capsys):
    from _fit_synthetic import TRENCH

    from napari_symbac.optics import ForwardModel
    from napari_symbac.scene import draw_scene
    from napari_symbac.sim import FrameCells

    blank = ForwardModel(truth.microscope, truth.render, truth.camera).render(
        draw_scene(FrameCells.empty(), TRENCH, truth.microscope, truth.render),
        np.random.default_rng(3),
    )
    image = tmp_path / "series.tif"
    tifffile.imwrite(image, np.stack([truth.image, truth.image, blank]))
    microscope = save_settings(truth.microscope, tmp_path / "microscope.yaml")
    error = _refused(capsys, tmp_path / "o", image, "--microscope", microscope,
                     "--frames", "1-2", "--max-iterations", "2")  # fmt: skip
    # the recording's frame number (found as a user: named by its place in --frames)
    assert "frame 2 of the series: the start found no cells" in error
    assert "fit the frames before and after frame 2 as separate series" in error


def test_refuses_a_colour_image(tmp_path, truth, inputs, capsys):
    _, _, microscope = inputs
    image = tmp_path / "rgb.tif"
    colour = np.repeat(truth.image[..., None], 3, axis=-1)
    colour[..., 0] //= 2
    tifffile.imwrite(image, colour)
    error = _refused(capsys, tmp_path / "o", image, "--microscope", microscope)
    assert "rgb.tif is a colour image" in error
    assert "save one grey channel" in error


def test_fits_a_grey_png(tmp_path, truth, inputs, capsys):
    """Found as a user: `fit` refused the Omnipose sample PNGs ("not a TIFF file") that
    `calibrate` and the widgets read (grey saved as colour: tests/test_recording_io.py)."""
    _, labels, microscope = inputs
    image = tmp_path / "real.png"
    iio.imwrite(image, np.asarray(truth.image, np.uint16))
    out = tmp_path / "fit"
    assert _fit(image, "--labels", labels, "--microscope", microscope, "--out", out) == 0
    assert "image file records none" in (out / "report.txt").read_text()
    table = json.loads((out / "cells.json").read_text())
    assert len(table["cells"]) == 3


def test_labels_and_masks_together_are_a_usage_error(tmp_path, inputs):
    image, labels, microscope = inputs
    with pytest.raises(SystemExit) as exit_info:
        _fit(image, "--microscope", microscope, "--labels", labels, "--masks", labels,
             "--out", tmp_path / "o")  # fmt: skip
    assert exit_info.value.code == 2


def test_progress_is_a_bar_on_a_terminal_and_lines_when_piped():
    import io

    from napari_symbac._cli_fit import _Stages

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    piped, terminal = io.StringIO(), Terminal()
    for stream in (piped, terminal):
        stages = _Stages(stream)
        stages.stage("fitting frame 0")
        update, close = stages.bar("fit frame 0")
        update(3, 10)
        close()
    assert piped.getvalue() == (
        "napari-symbac fit: fitting frame 0\nnapari-symbac fit frame 0: 3 of at most 10 steps\n"
    )
    assert "fit frame 0" in terminal.getvalue()
    assert "3/10" in terminal.getvalue()  # the tqdm bar
    assert "napari-symbac fit: fitting" not in terminal.getvalue()


# --------------------------------------------------------------------------------------
# Optional terms of the scene model
# --------------------------------------------------------------------------------------


def test_model_options_reach_the_fit(tmp_path, inputs, capsys):
    """--cell-brightness, --width-sd-um and --illumination-order are fitted and reported."""
    image, labels, microscope = inputs
    out = tmp_path / "fit"
    code = _fit(
        image, "--labels", labels, "--microscope", microscope, "--out", out,
        "--cell-brightness", "per-cell", "--width-sd-um", "0.1", "--illumination-order", "2",
    )  # fmt: skip
    assert code == 0, capsys.readouterr().err
    table = json.loads((out / "cells.json").read_text())
    widths = {round(c["width_um"], 6) for c in table["cells"]}
    assert len(widths) == len(table["cells"])  # a width per cell, not one shared
    text = json.dumps(table) + (out / "report.txt").read_text()
    assert "illumination." in text
    report = (out / "report.txt").read_text()
    # the surface is drawn by render and export as fitted (it was left out: the fit's
    # intensities, found under it, drew the real trench's media 2x too light)
    assert "settings.yaml draws it (extra stage uneven_illumination)" in report
    settings = load_settings(out / "settings.yaml", PipelineSettings)
    [stage] = settings.extra_stages
    assert stage.name == "uneven_illumination"
    assert stage.parameters["order"] == 2
    fitted = {p["name"]: p["value"] for p in table["parameters"]}
    terms = ("x", "y", "x^2", "y^2", "xy")
    assert stage.parameters["coefficients"] == pytest.approx(
        [fitted[f"illumination.{t}"] for t in terms]
    )
    from napari_symbac.diagnose.stages import drawn_stages
    from napari_symbac.fit.illumination import illumination_basis

    ones = np.ones((40, 30), np.float32)
    basis = illumination_basis(ones.shape, 2)
    surface = 1 + np.tensordot(stage.parameters["coefficients"], basis, 1)
    np.testing.assert_allclose(drawn_stages(settings)[0].apply(ones, None), surface, rtol=1e-6)
    # a phase-contrast cell's fitted intensity is misfit, not its optical path: not drawn
    assert "--cell-brightness per-cell in phase: each cell's intensity is fitted" in report
    assert settings.render.cell_brightness_cv == 0.0


@pytest.mark.parametrize(
    ("option", "value", "message"),
    [
        ("--width-sd-um", "-0.1", "not a width s.d."),
        ("--width-sd-um", "nan", "not a width s.d."),
        ("--illumination-order", "7", "not a surface degree"),
    ],
)
def test_refuses_model_options_out_of_range(tmp_path, inputs, capsys, option, value, message):
    image, labels, microscope = inputs
    error = _refused(
        capsys, tmp_path / "o", image, "--labels", labels, "--microscope", microscope,
        option, value,
    )  # fmt: skip
    assert message in error


def test_refuses_an_illumination_surface_for_a_series(tmp_path, truth, capsys):
    image = tmp_path / "series.tif"
    tifffile.imwrite(image, np.stack([truth.image, truth.image]))
    microscope = save_settings(truth.microscope, tmp_path / "microscope.yaml")
    error = _refused(
        capsys, tmp_path / "o", image, "--microscope", microscope, "--frames", "0-1",
        "--illumination-order", "2",
    )  # fmt: skip
    assert "single frames only" in error


def test_fit_reads_the_diagnose_microscope_file(tmp_path, truth, inputs, capsys):
    """One microscope file for every command: diagnose's keys (NA) work for fit too."""
    image, labels, _ = inputs
    m = truth.microscope
    microscope = tmp_path / "diagnose_microscope.yaml"
    microscope.write_text(yaml.safe_dump({
        "modality": m.modality, "pixel_size_um": m.pixel_size_um, "NA": m.numerical_aperture,
        "refractive_index": m.refractive_index, "wavelength_um": m.wavelength_um,
        "condenser": m.condenser,
    }))  # fmt: skip
    out = tmp_path / "fit"
    assert _fit(image, "--labels", labels, "--microscope", microscope, "--out", out) == 0, (
        capsys.readouterr().err
    )
    settings = load_settings(out / "settings.yaml", PipelineSettings)
    assert settings.microscope.numerical_aperture == m.numerical_aperture
    assert settings.microscope.pixel_size_um == m.pixel_size_um


def test_refuses_dark_frames_without_noise(tmp_path, inputs, capsys):
    """Found as a user: constant 'dark frames' (no read noise: not a camera's raw dark
    frames) were taken, and the report gave 0 +- 0 e- of read noise."""
    image, labels, microscope = inputs
    dark = tmp_path / "dark.tif"
    tifffile.imwrite(dark, np.full((5, 10, 10), 100, np.uint16))
    error = _refused(capsys, tmp_path / "o", image, "--labels", labels,
                     "--microscope", microscope, "--dark", dark)  # fmt: skip
    assert "--dark dark.tif has no noise (every pixel is 100)" in error


def test_refuses_a_constant_image_naming_the_file(tmp_path, inputs, capsys):
    _, _, microscope = inputs
    blank = tmp_path / "blank.png"
    iio.imwrite(blank, np.zeros((64, 32), np.uint8))
    error = _refused(capsys, tmp_path / "o", blank, "--microscope", microscope)
    assert "IMAGE blank.png is constant (every pixel is 0): nothing to fit" in error
    assert "real_image" not in error


def test_refuses_max_iterations_below_one_naming_the_option(tmp_path, inputs, capsys):
    image, labels, microscope = inputs
    error = _refused(capsys, tmp_path / "o", image, "--labels", labels,
                     "--microscope", microscope, "--max-iterations", 0)  # fmt: skip
    assert "--max-iterations must be at least 1, got 0" in error
    assert "irls_rounds" not in error


@pytest.mark.parametrize(
    ("spec", "n_frames", "message"),
    [
        ("2-7", 3, "--frames '2-7': frame(s) 3-7 do not exist: stack.tif has 3 frames, "
                   "numbered 0-2"),
        ("0,4,6-8", 3, "frame(s) 4, 6-8 do not exist: stack.tif has 3 frames, numbered 0-2"),
        ("1", 1, "--frames '1': frame(s) 1 do not exist: stack.tif has 1 frame (frame 0)"),
        ("3-1", 3, "--frames '3-1' names no frame"),
    ],
)  # fmt: skip
def test_frames_that_do_not_exist_are_named_as_runs(spec, n_frames, message):
    from napari_symbac._cli_fit import parse_frames

    with pytest.raises(ValueError, match=re.escape(message)):
        parse_frames(spec, n_frames, "stack.tif")


def test_fit_replaces_an_earlier_fit_and_refuses_other_files(tmp_path, inputs, capsys):
    """Found as a user: `fit` into a folder kept an earlier run's files beside its own
    (a diagnosis there, another fit's frames), which then read as this run's."""
    image, labels, microscope = inputs
    out = tmp_path / "fit"
    (out / "frame_0003").mkdir(parents=True)  # an earlier fit of a series
    (out / "frame_0003" / "report.txt").write_text("earlier")
    (out / "report.txt").write_text("earlier")
    assert _fit(image, "--labels", labels, "--microscope", microscope, "--out", out,
                "--max-iterations", 1) == 0  # fmt: skip
    assert not (out / "frame_0003").exists()
    assert (out / "report.txt").read_text() != "earlier"
    assert {p.name for p in out.iterdir()} == {
        "settings.yaml", "cells.json", "residual.tif", "before_after.png", "report.txt"
    }  # fmt: skip
    capsys.readouterr()
    (out / "diagnosis.json").write_text("{}")  # another command's
    assert _fit(image, "--labels", labels, "--microscope", microscope, "--out", out) == 2
    error = capsys.readouterr().err
    assert "holds files napari-symbac fit does not write (diagnosis.json)" in error
    assert "give a new or empty folder" in error
    assert (out / "diagnosis.json").read_text() == "{}"


def test_a_camera_the_image_cannot_check_is_a_problem(real_data_dir):
    """Found as a user: the Omnipose colony Sample000033 (8-bit PNG, not camera counts)
    fitted without masks kept 8 cells beside its 116, with a camera of 0.001 ADU/e- and
    1360 e- read noise fitted to the misfit; the model-free check was 'not available' and
    PROBLEMS said nothing, so exit 0 looked like a fit."""
    from napari_symbac.fit.report import CLI_CAMERA_FIX, model_free_camera_check
    from napari_symbac.settings import Camera

    grey = iio.imread(real_data_dir / "omnipose" / "Sample000033.png")[..., 0]
    fitted = Camera(sensitivity_adu_per_e=0.001, dark_noise_e=1360.0, baseline_adu=4.0)
    check, problem = model_free_camera_check(grey.astype(np.float64), fitted, CLI_CAMERA_FIX)
    assert check.startswith("not available (the pixel variance does not grow with the mean")
    assert problem is not None
    # the placeholder gain said as the constant noise it draws (found as a user: "0.001
    # ADU/e-, read noise 2.77e+04 e-" read as a camera)
    assert problem.startswith("the fit's camera (no gain, a constant noise of 1.36 ADU s.d.)")
    from napari_symbac.fit.report import camera_text

    assert camera_text(fitted) == (
        "no gain measurable: a constant noise of 1.36 ADU s.d., baseline 4.0 ADU, 16 bits"
    )
    assert "a chi-square near 1 does not mean the model explains the image" in problem


@pytest.mark.parametrize("name", ["Sample000033", "Sample000193", "Sample000252"])
def test_a_phase_colony_without_masks_is_refused_at_its_start(
    tmp_path, real_data_dir, capsys, name
):
    """The three Omnipose colonies fitted without masks, at 1 um per median mask width:
    Sample000033 ran 101 s and ended with 12 cells for 116 and exit 0. The automatic
    start takes touching cells as wide regions (half of its cells or more wider than
    3 um), so the fit stops there, asking for the cells' instance masks."""
    masks = tifffile.imread(real_data_dir / "omnipose" / f"{name}_cp_masks.tif")
    widths_px = [2 * ndimage.distance_transform_edt(np.pad(masks[box] == i, 1)).max()
                 for i, box in enumerate(ndimage.find_objects(masks), start=1) if box]  # fmt: skip
    scope = Microscope(pixel_size_um=round(1 / float(np.median(widths_px)), 4))
    microscope = save_settings(scope, tmp_path / "microscope.yaml")
    image = real_data_dir / "omnipose" / f"{name}.png"
    error = _refused(capsys, tmp_path / "fit", image, "--microscope", microscope)
    line = error[error.index("napari-symbac fit: error: ") :].splitlines()[0]
    assert "cells the automatic start found are wider than any rod-shaped bacterium" in line
    assert line.endswith("is then fitted with its own model (--masks M)")


def test_envelope_stain_is_fitted_and_written_for_render(tmp_path, real_data_dir):
    """`fit --envelope-stain` on the ColiCoords ds2 cell that is brighter at its rim: the
    fraction is a fitted parameter in report.txt and settings.yaml draws it."""
    root = real_data_dir / "colicoords" / "test_data" / "ds2"
    image = tmp_path / "cell.tif"
    tifffile.imwrite(image, tifffile.imread(root / "fluorescence" / "00066.tif")[0:64, 224:288])
    microscope = save_settings(
        Microscope(pixel_size_um=0.08, modality="fluorescence"), tmp_path / "microscope.yaml"
    )
    out = tmp_path / "fitted"
    assert _fit(image, "--microscope", microscope, "--geometry", "field", "--envelope-stain",
                "--out", out) == 0  # fmt: skip
    report = (out / "report.txt").read_text()
    assert "envelope_stain_fraction:" in report
    settings = load_settings(out / "settings.yaml", PipelineSettings)
    assert settings.render.envelope_stain_fraction > 0.8


def test_refuses_an_envelope_stain_in_phase_contrast(tmp_path, inputs, capsys):
    image, _, microscope = inputs
    error = _refused(capsys, tmp_path / "o", image, "--microscope", microscope,
                     "--envelope-stain")  # fmt: skip
    assert "--envelope-stain fits where a fluorescence stain sits" in error
    assert "leave --envelope-stain out" in error


def test_depth_layers_are_fitted_and_written_for_render(tmp_path, real_data_dir):
    """`fit --envelope-stain --depth-layers 5` on the same ds2 cell: the focal plane is a
    fitted parameter, the fraction leaves its bound 1, and settings.yaml draws both."""
    root = real_data_dir / "colicoords" / "test_data" / "ds2"
    image = tmp_path / "cell.tif"
    tifffile.imwrite(image, tifffile.imread(root / "fluorescence" / "00066.tif")[0:64, 224:288])
    microscope = save_settings(
        Microscope(pixel_size_um=0.08, modality="fluorescence"), tmp_path / "microscope.yaml"
    )
    out = tmp_path / "fitted"
    assert _fit(image, "--microscope", microscope, "--geometry", "field", "--envelope-stain",
                "--depth-layers", 5, "--out", out) == 0  # fmt: skip
    assert "focus_offset_um:" in (out / "report.txt").read_text()
    settings = load_settings(out / "settings.yaml", PipelineSettings)
    assert settings.render.depth_layers == 5
    assert 0.1 < abs(settings.render.focus_offset_um) < 0.4
    assert 0.5 < settings.render.envelope_stain_fraction < 0.97


@pytest.mark.parametrize(
    ("modality", "layers", "said"),
    [("phase", 5, "leave --depth-layers out"), ("fluorescence", 40, "is not a number of slabs")],
)
def test_refuses_depth_layers_in_phase_contrast_or_out_of_range(
    tmp_path, inputs, capsys, modality, layers, said
):
    image, _, microscope = inputs
    error = _refused(capsys, tmp_path / "o", image, "--microscope", microscope,
                     "--modality", modality, "--depth-layers", layers)  # fmt: skip
    assert said in error


def test_a_crop_around_one_cell_asks_for_masks_or_labels(tmp_path, real_data_dir, capsys):
    """ColiCoords' single-cell crop ``01`` without masks: the automatic start finds no
    cell standing out of its glow, and says which two files would start it."""
    scope = Microscope(pixel_size_um=0.08, modality="fluorescence", wavelength_um=0.53)
    microscope = save_settings(scope, tmp_path / "microscope.yaml")
    image = real_data_dir / "colicoords" / "01" / "fluorescence.tif"
    error = _refused(capsys, tmp_path / "fit", image, "--microscope", microscope)
    line = error[error.index("napari-symbac fit: error: ") :].splitlines()[0]
    assert "no bright region stands 40 times the background's spread above it" in line
    assert line.endswith("instance masks or painted labels (--masks M or --labels L)")


def test_a_phase_trench_given_as_fluorescence_is_told_the_modality(
    tmp_path, real_data_dir, capsys
):
    """Found as a user: SyMBac's phase trench with --modality fluorescence was told its
    cells were "not fluorescence", and not what to set instead."""
    microscope = save_settings(Microscope(pixel_size_um=0.065), tmp_path / "microscope.yaml")
    image = real_data_dir / "ecoli_100x_oil_exponential.tiff"
    error = _refused(capsys, tmp_path / "fit", image, "--microscope", microscope,
                     "--modality", "fluorescence")  # fmt: skip
    assert "not fluorescence, set the modality to phase or brightfield" in error


def test_a_channel_of_a_hyperstack_is_fitted_as_its_own_file(
    tmp_path, real_data_dir, capsys, cell_hyperstack
):
    """Found as a user: a brightfield + fluorescence hyperstack (Fiji's composite, axes
    CYX) was read as 2 frames, and `fit` asked for --frames. It now asks for the
    channel, and --channel 1 fits the fluorescence as the fluorescence file alone."""
    folder = real_data_dir / "colicoords" / "01"
    stack, _ = cell_hyperstack
    scope = Microscope(pixel_size_um=0.08, modality="fluorescence", wavelength_um=0.53)
    microscope = save_settings(scope, tmp_path / "microscope.yaml")
    masks = folder / "binary.tif"
    error = _refused(capsys, tmp_path / "refused", stack, "--microscope", microscope)
    assert "two_channels.tif holds 2 channels (axes CYX" in error
    assert error.rstrip().endswith("a recording is one channel: choose it with --channel K (0..1)")
    two_masks = tmp_path / "two_masks.tif"  # --channel is the image's: masks are one
    tifffile.imwrite(
        two_masks, np.stack([tifffile.imread(folder / "binary.tif")] * 2), imagej=True,
        metadata={"axes": "CYX", "mode": "composite"},
    )  # fmt: skip
    error = _refused(capsys, tmp_path / "refused", stack, "--microscope", microscope,
                     "--channel", 1, "--masks", two_masks)  # fmt: skip
    assert error.rstrip().endswith(
        "two_masks.tif holds 2 channels (axes CYX, shape (2, 57, 61)): save the channel of "
        "--masks to use as its own TIFF"
    )
    fits = {}
    for name, image, extra in (
        ("stack", stack, ["--channel", 1]), ("file", folder / "fluorescence.tif", [])
    ):
        out = tmp_path / name
        assert _fit(image, "--microscope", microscope, "--masks", masks, *extra, "--out", out) == 0
        fits[name] = json.loads((out / "cells.json").read_text())["cells"]
    assert len(fits["stack"]) == 1
    assert fits["stack"] == fits["file"]


def test_the_microscope_files_camera_section_is_the_camera(tmp_path, truth, inputs, capsys):
    """Found as a user: the camera section `--microscope`'s help names was refused by fit
    and calibrate ("unknown field(s) camera in Microscope") while diagnose read it."""
    import yaml

    image, labels, microscope = inputs
    with_camera = yaml.safe_load(microscope.read_text())
    with_camera["camera"] = {"baseline_adu": 100, "sensitivity_adu_per_e": 2.5, "dark_noise_e": 6}
    path = tmp_path / "with_camera.yaml"
    path.write_text(yaml.safe_dump(with_camera))
    out = tmp_path / "fit"
    assert _fit(image, "--microscope", path, "--labels", labels, "--out", out,
                "--max-iterations", 2) == 0, capsys.readouterr().err  # fmt: skip
    report = (out / "report.txt").read_text()
    assert _fact(report, "camera") == f"from the camera section of --microscope {path}"
    assert "2.5 ADU/e-" in _fact(report, "camera used")


@pytest.fixture
def turned_trenches(real_data_dir, tmp_path):
    """The SyMBac trench as other chips and microscopes show it (ImageJ TIFFs at its
    0.065 um): on its side, upside down, four side by side, and with its closed end cut
    off."""
    trench = tifffile.imread(real_data_dir / "ecoli_100x_oil_exponential.tiff")
    pdms = np.full((trench.shape[0], 30), int(np.median(trench[:, :5])), trench.dtype)
    images = {
        "lying": np.rot90(trench),
        "upside_down": trench[::-1],
        "four": np.hstack([trench, pdms, trench[:, ::-1], pdms, trench, pdms, trench]),
        "no_closed_end": trench[60:],
    }
    paths = {}
    for name, image in images.items():
        paths[name] = tmp_path / f"{name}.tif"
        tifffile.imwrite(paths[name], np.ascontiguousarray(image), imagej=True,
                         resolution=(1 / 0.065, 1 / 0.065), metadata={"unit": "um"})  # fmt: skip
    return paths


def test_a_trench_on_its_side_upside_down_or_beside_others_is_refused_with_the_fix(
    turned_trenches, tmp_path, capsys
):
    """Found as a user: each was fitted, exit 0: the trench on its side as an open field
    of 1.7 um cells ("check the pixel size"), upside down with its closed end missing (5
    cells for 4), four side by side with the first fitted and three left in the residual
    (with no --geometry, refused as a colony: "give instance masks"). Each is refused
    before any fit, saying how to turn or crop it."""
    def last_line(*args) -> str:
        return _refused(capsys, tmp_path / "o", *args).strip().splitlines()[-1]

    lying = last_line(turned_trenches["lying"])
    assert "is 46 x 256 px (rows x columns), wide and short" in lying
    assert "rotate it by 90 degrees" in lying
    assert lying.endswith("or pass --geometry field for an open field")
    assert "rotate it" in last_line(turned_trenches["lying"], "--geometry", "trench")
    upside_down = last_line(turned_trenches["upside_down"])
    assert "the trench's closed end is at the bottom of the image" in upside_down
    assert "flip the image upside down" in upside_down
    for geometry in (["--geometry", "trench"], []):  # 274 px wide: a field by default
        four = last_line(turned_trenches["four"], *geometry)
        assert "holds 4 trenches side by side (columns 9-32, " in four
        assert "crop each trench" in four
    # cut below its closed end, the trench is fitted, and no closed end is claimed
    out = tmp_path / "cut"
    assert _fit(turned_trenches["no_closed_end"], "--out", out) == 0
    report = (out / "report.txt").read_text()
    assert "closed end: above the image" in report
    assert "chosen by the fit" not in report


def test_a_large_frame_is_announced_before_the_fit(tmp_path, capsys):
    """Found as a user: a 2048 x 2048 field ran past 15 minutes with nothing said of what
    to expect. A frame over twice 512 x 512 pixels is announced, with the way to a faster
    fit (here a field of noise, refused at its start, after the note)."""
    image = tmp_path / "big.tif"
    noise = np.random.default_rng(0).poisson(100, (1024, 1024)).astype(np.uint16)
    tifffile.imwrite(image, noise)
    code = _fit(image, "--pixel-size-um", 0.08, "--modality", "fluorescence", "--out",
                tmp_path / "o")  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2
    assert "note: a frame of 1024 x 1024 px, 4 times a 512 x 512 field" in err
    assert "a crop of the region of interest fits faster" in err
