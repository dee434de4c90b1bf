"""``napari-symbac diagnose``: bad input is a clear error; a recording gives the issue's files."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import tifffile

from napari_symbac.cli import main
from napari_symbac.diagnose.concealed import make_case
from napari_symbac.settings import PipelineSettings, load_settings

PHASE_100X = {"modality": "phase", "pixel_size_um": 0.065, "NA": 1.45,
              "refractive_index": 1.518, "wavelength_um": 0.65}  # fmt: skip


def _microscope_file(tmp_path, **keys):
    """A diagnose microscope file (JSON) of the 100x phase microscope, keys replaced."""
    path = tmp_path / "mic.json"
    path.write_text(json.dumps({**PHASE_100X, **keys}))
    return path



def test_missing_microscope_key_is_a_clear_error(tmp_path, capsys):
    """A file in diagnose's own keys (NA, ...) needs them all, as for `fit`; a file of
    Microscope fields may give some (tests/test_bad_input.py)."""
    image = tmp_path / "image.tif"
    tifffile.imwrite(image, np.full((32, 32), 500, np.uint16))
    mic = tmp_path / "mic.json"
    mic.write_text(json.dumps({"NA": 1.45, "pixel_size_um": 0.065}))
    code = main(["diagnose", str(image), "--microscope", str(mic), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2
    assert "lacks the required key(s) modality" in err
    assert "Traceback" not in err


@pytest.mark.parametrize("region", ["0:300,0:32", "10:5,0:32", "0:32", "a:b,c:d"])
def test_a_bad_region_is_a_clear_error(tmp_path, capsys, region):
    image = tmp_path / "image.tif"  # not constant: a blank image is refused first
    tifffile.imwrite(image, np.arange(64 * 32, dtype=np.uint16).reshape(64, 32) + 500)
    mic = _microscope_file(tmp_path)
    out = tmp_path / "o"
    code = main(
        ["diagnose", str(image), "--microscope", str(mic), "--out", str(out), "--region", region]
    )
    err = capsys.readouterr().err
    assert code == 2
    assert f"--region {region!r} is" in err
    assert "give Y0:Y1,X0:X1" in err
    assert "Traceback" not in err
    assert not out.exists()


@pytest.mark.slow
def test_diagnose_command_writes_the_issue_outputs(tmp_path, capsys):
    case = make_case("fixed_pattern_noise", fraction_of_sd=0.9, seed=7)
    image = tmp_path / "trench.tif"
    tifffile.imwrite(image, case.images[0])  # 256 x 46: diagnosed on its first 96 rows
    mic = tmp_path / "mic.json"
    mic.write_text(
        json.dumps(
            {
                "modality": "phase",
                "pixel_size_um": 0.065,
                "NA": 1.45,
                "refractive_index": 1.518,
                "wavelength_um": 0.65,
                "condenser": "Ph3",
                "camera": {"baseline_adu": 100, "sensitivity_adu_per_e": 2.9, "dark_noise_e": 8},
            }
        )
    )
    out = tmp_path / "out"
    out.mkdir()  # an earlier diagnosis' figure of an effect this one does not accept
    (out / "effect_stray_light.png").write_bytes(b"earlier")
    args = ["diagnose", str(image), "--microscope", str(mic), "--out", str(out)]
    assert main([*args, "--region", "0:96,0:46"]) == 0
    said = capsys.readouterr().out
    # a trench diagnosed on a window of its rows is simulated as long as the recording
    assert "settings.yaml simulates the diagnosed" not in said
    trench = load_settings(out / "settings.yaml", PipelineSettings).simulation.trench
    assert trench.length_um + trench.shown_top_um == pytest.approx(256 * 0.065, abs=1e-9)
    doc = json.loads((out / "diagnosis.json").read_text())
    assert doc["region"] == {"rows": [0, 96], "columns": [0, 46]}
    assert doc["counts_mapping"] is None  # camera counts: nothing to mark
    report = (out / "report.txt").read_text()
    assert "read as counts" not in report
    # what was diagnosed, first (found as a user: the window only on the terminal)
    assert report.startswith(
        "recording: trench.tif, rows 0:96, columns 0:46 of the 256 x 46 px frame\n"
        "pixel size 0.065 um from --microscope (the image file records none); modality: phase\n"
        "camera: sensitivity 2.9 ADU/e-, baseline 100.0 ADU, dark noise 8 e-, 16 bits\n"
        "base fit: started from automatic segmentation; cells fitted per frame: "
    )
    assert doc["start"]["from"] == "automatic segmentation"
    assert "BASE FIT PROBLEMS" not in report
    assert doc["base_fit_problems"] == []
    assert set(doc) >= {"base_fit", "mismatches", "effects", "final_fit"}
    assert {"metric", "value", "held_out"} <= set(doc["base_fit"])
    for effect in doc["effects"]:
        assert {"name", "explanation", "evidence", "accepted", "params"} <= set(effect)
    evidence = [e["evidence"] for e in doc["effects"] if not e["accepted"]]
    assert evidence == sorted(evidence, reverse=True)
    for name in ("report.txt", "residuals.png", "settings.yaml", "extra_stages.yaml"):
        assert (out / name).is_file()
    accepted = {f"effect_{e['name']}.png" for e in doc["effects"] if e["accepted"]}
    assert {p.name for p in out.glob("effect_*.png")} <= accepted
    earlier = out / "effect_stray_light.png"
    assert not earlier.exists() or earlier.read_bytes() != b"earlier"  # gone or this run's


@pytest.mark.slow
def test_a_pixel_size_slip_is_said_as_fit_says_it(tmp_path, capsys, real_data_dir):
    """Found as a user: the real trench at 0.13 um/px (a 2x slip) was diagnosed with exit
    0 and cells 1.81 um wide in settings.yaml, and ColiCoords at 0.8 um/px (10x) drew its
    cells at 0 ADU, without a word; `fit` says both. The base fit's problems are now
    warnings and a section of report.txt; the 10x slip's camera pixel is said first."""
    image = real_data_dir / "ecoli_100x_oil_exponential.tiff"
    mic = tmp_path / "mic.yaml"
    mic.write_text("pixel_size_um: 0.13\nmodality: phase\n")
    out = tmp_path / "out"
    args = ["diagnose", str(image), "--microscope", str(mic), "--max-effects", "1"]
    assert main([*args, "--out", str(out)]) == 0
    err = capsys.readouterr().err
    width = "the cells' median width, 1.81 um, is unusual for bacteria (0.4-1.6 um)"
    assert f"napari-symbac diagnose: warning: base fit: {width}" in err
    report = (out / "report.txt").read_text()
    section = report.split("BASE FIT PROBLEMS")[1].split("Diagnosis of the mismatch")[0]
    assert width in section
    assert "misses structure" not in section  # diagnose is there for that
    doc = json.loads((out / "diagnosis.json").read_text())
    assert any(width in p for p in doc["base_fit_problems"])
    mic.write_text("pixel_size_um: 0.65\nmodality: phase\n")
    assert main([*args, "--out", str(tmp_path / "ten")]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    slip = "napari-symbac diagnose: warning: pixel size 0.65 um at 100x magnification is a 65"
    assert any(line.startswith(slip) for line in lines[:-1])  # before the start's refusal
    assert lines[-1].startswith("napari-symbac diagnose: error: ")


def test_diagnose_measures_the_camera_and_reads_a_png(tmp_path, capsys):
    """A grey PNG and the microscope file of `napari-symbac defaults microscope`, no
    camera: the camera is measured from the recording (the recording's 2.9 ADU/e- here),
    not assumed, so that `camera_noise` looks past it."""
    import imageio.v3 as iio

    case = make_case("fixed_pattern_noise", fraction_of_sd=0.9, seed=7)
    image = tmp_path / "trench.png"
    iio.imwrite(image, np.asarray(case.images[0][:96], np.uint16))
    assert main(["defaults", "microscope", "--out", str(tmp_path / "mic.yaml")]) == 0
    out = tmp_path / "out"
    args = ["diagnose", str(image), "--microscope", str(tmp_path / "mic.yaml"), "--out", str(out)]
    assert main(args) == 0
    err = capsys.readouterr().err
    assert "camera measured from the recording" in err
    assert "correlated between neighbours" not in err  # the rendered noise is white
    doc = json.loads((out / "diagnosis.json").read_text())
    measured = doc["camera"]["sensitivity_adu_per_e"]
    assert measured == pytest.approx(2.9, rel=0.1)  # 96 x 46 pixels: 2.68 ADU/e-
    accepted = {e["name"]: e["params"] for e in doc["effects"] if e["accepted"]}
    assert "fixed_pattern_noise" in accepted
    # camera_noise may refine the measured gain; what the diagnosis ends with is near it
    final = measured * accepted.get("camera_noise", {}).get("gain_ratio", 1.0)
    assert final == pytest.approx(2.9, rel=0.1)
    assert "8-bit" not in err  # 16-bit counts: a camera's


def test_an_8_bit_export_is_said_not_to_be_a_cameras_counts(tmp_path, capsys, real_data_dir):
    """Found as a user: the real trench saved as an 8-bit grey PNG was "measured" at
    0.0689 ADU/e-, read noise 15.9 e-, as if a camera's; the note now says what such a
    gain is of."""
    import imageio.v3 as iio

    real = tifffile.imread(real_data_dir / "ecoli_100x_oil_exponential.tiff").astype(float)
    scaled = np.rint(255 * (real - real.min()) / np.ptp(real)).astype(np.uint8)
    image = tmp_path / "trench8.png"
    iio.imwrite(image, scaled)
    mic = tmp_path / "mic.yaml"
    mic.write_text("pixel_size_um: 0.065\nmodality: phase\n")
    args = ["diagnose", str(image), "--microscope", str(mic), "--max-effects", "1"]
    assert main([*args, "--out", str(tmp_path / "out")]) == 0
    (note,) = [line for line in capsys.readouterr().err.splitlines() if "camera measured" in line]
    assert "an 8-bit image is mostly a display export scaled from the camera's counts" in note
    # its levels end at 255: so do those of the camera measured from it (was 16 bits)
    doc = json.loads((tmp_path / "out" / "diagnosis.json").read_text())
    assert doc["camera"]["bit_depth"] == 8
    settings = load_settings(tmp_path / "out" / "settings.yaml", PipelineSettings)
    assert settings.camera.bit_depth == 8


def test_diagnose_refuses_what_fit_refuses(tmp_path, capsys):
    """Found as a user: `fit` refused negative values with what to pass, `diagnose` ran on
    them (DeLTA's normalised trench, which both now read as counts) and reported a camera
    of 1.6e-06 ADU/e-. Counts with an offset taken off below zero are refused by both."""
    image = tmp_path / "subtracted.tif"
    counts = np.random.default_rng(1).poisson(500, (64, 32)).astype(np.int32) - 520
    tifffile.imwrite(image, counts)
    mic = _microscope_file(tmp_path)
    out = tmp_path / "out"
    assert main(["diagnose", str(image), "--microscope", str(mic), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "has negative values" in err
    assert "baseline_adu" in err
    assert "Traceback" not in err
    assert not out.exists()


def test_refusals_name_the_file_as_fit_does_and_come_alone(tmp_path, capsys):
    """Found as a user: a 5 x 5 image was refused as `real_image` (the Python API's name),
    float --labels were called an instance mask that diagnose "does not take" (it takes
    --masks), and "note: no camera given" came before each refusal."""
    mic = tmp_path / "mic.yaml"
    mic.write_text("pixel_size_um: 0.065\nmodality: phase\n")  # no camera: measured
    tiny = tmp_path / "tiny.tif"
    tifffile.imwrite(tiny, np.random.default_rng(0).integers(90, 110, (5, 5)).astype(np.uint16))
    out = str(tmp_path / "o")
    assert main(["diagnose", str(tiny), "--microscope", str(mic), "--out", out]) == 2
    err = capsys.readouterr().err
    assert err.splitlines() == [
        "napari-symbac diagnose: error: tiny.tif of shape (5, 5) is too small to fit: it "
        "needs at least 8 x 8 px (a whole cell and some background around it)"
    ]
    image = tmp_path / "image.tif"
    tifffile.imwrite(image, np.random.default_rng(1).poisson(500, (64, 32)).astype(np.uint16))
    labels = tmp_path / "labels.tif"
    tifffile.imwrite(labels, np.full((64, 32), 1.5, np.float32))
    args = ["diagnose", str(image), "--microscope", str(mic), "--labels", str(labels)]
    assert main([*args, "--out", out]) == 2
    err = capsys.readouterr().err
    assert err.splitlines() == [
        "napari-symbac diagnose: error: --labels labels.tif must hold integer classes 0-3, "
        "got dtype float32"
    ]


def test_a_normalised_trench_is_diagnosed_in_the_units_it_was_read_in(
    tmp_path, capsys, real_data_dir
):
    """Found as a user: `diagnose` read DeLTA's normalised trench as counts (x 10000 ADU)
    and said so on stderr only; report.txt and diagnosis.json gave its 0.016 ADU/e- and
    ~500 e- as a camera's. Both now say what the values are, as `fit`'s report does."""
    image = real_data_dir / "ecoli_delta_phase_normalised.tiff"
    mic = _microscope_file(tmp_path)
    out = tmp_path / "out"
    args = ["diagnose", str(image), "--microscope", str(mic), "--out", str(out)]
    assert main([*args, "--region", "0:64,0:32"]) == 0
    read_as = "(value + 0.02847) x 10000 ADU"
    err = capsys.readouterr().err
    (camera_note,) = [line for line in err.splitlines() if "camera measured from" in line]
    assert camera_note.endswith(f"[normalised image read as counts, {read_as}: not a real "
                                "camera's units]")  # fmt: skip
    # found as a user: its chi-square was blamed on the scene alone (cells missed), while
    # the note above says its noise is correlated: the caution names that too
    (caution,) = [line for line in err.splitlines() if "reduced chi-square of" in line]
    assert "above 50 the scene itself is wrong" in caution
    assert "here the noise is correlated between neighbours (lag ratio 4" in caution
    report = (out / "report.txt").read_text()
    assert report.startswith(
        f"image values: normalised values (-0.02847..1.007, not camera counts): read as {read_as}"
    )
    assert report.rstrip().endswith(
        f"- every ADU and e- in this report is of the normalised image read as counts, "
        f"{read_as}: not of a real camera (its gain, baseline and noise in those units)"
    )
    doc = json.loads((out / "diagnosis.json").read_text())
    assert doc["counts_mapping"]["read_as"] == read_as
    assert doc["counts_mapping"]["shift"] == pytest.approx(0.028468, abs=1e-6)
    assert any(note.endswith("not a real camera's units]") for note in doc["notes"])


def test_diagnose_refuses_an_implausible_pixel_size(tmp_path, capsys):
    image = tmp_path / "image.tif"
    tifffile.imwrite(image, np.random.default_rng(0).poisson(500, (32, 32)).astype(np.uint16))
    mic = _microscope_file(tmp_path, pixel_size_um=65.0)  # the camera's pixel, not the sample's
    out = tmp_path / "out"
    assert main(["diagnose", str(image), "--microscope", str(mic), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "pixel size 65 um (from --microscope" in err
    assert "Traceback" not in err
    assert not out.exists()


@pytest.mark.slow
def test_diagnose_says_when_the_noise_is_correlated(tmp_path, capsys, real_data_dir):
    """ColiCoords' fields carry noise correlated between neighbouring pixels (lag-2 /
    lag-1 variance 1.27): the measured camera's note says what that means."""
    root = real_data_dir / "colicoords" / "test_data" / "ds1"
    image = tmp_path / "field.tif"
    tifffile.imwrite(image, tifffile.imread(root / "fluorescence" / "00001.tif")[118:182, 59:123])
    mic = _microscope_file(
        tmp_path, modality="fluorescence", pixel_size_um=0.08, NA=1.4, refractive_index=1.515,
        wavelength_um=0.52,
    )  # fmt: skip
    out = tmp_path / "out"
    assert main(["diagnose", str(image), "--microscope", str(mic), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "its noise is correlated between neighbours" in err
    notes = json.loads((out / "diagnosis.json").read_text())["notes"]
    assert any("correlated between neighbours" in note for note in notes)
    # its background, clipped at 0 by background subtraction, drawn as fit draws it
    # (found as a user: settings.yaml kept the unclipped level, its export had 2.5 % of
    # pixels at 0 against the recording's 19.5 %)
    assert any(n.startswith("settings.yaml: background clipped at 0 ADU") for n in notes)
    settings = load_settings(out / "settings.yaml", PipelineSettings)
    assert [s.name for s in settings.extra_stages].count("saturation") == 1
    real = tifffile.imread(image).astype(float)
    assert settings.render.media_intensity < np.median(real[real > 0])


@pytest.mark.parametrize(("n_frames", "region"), [(1, "centre"), (2, "centre"), (1, " Centre")])
def test_no_cells_in_the_diagnosed_window_names_it_and_the_fix(
    tmp_path, capsys, n_frames, region
):
    """Found as a user: `diagnose` of ColiCoords ds3 (4 frames of 512 x 512 px) said only
    "error: the start found no cells in the image (no region of 6 pixels or more)": its
    frame 1 held no cell in the centre 256 x 256 px window, then diagnosed by default,
    which the message did not say, nor that --region picks another. Here a 300 x 300
    field whose only cell lies in a corner, outside the centre window (the default now
    takes the window holding the most cells: test_region). The centre window's place is
    said in a note (``--region centre`` once said nothing of where it was)."""
    rng = np.random.default_rng(0)
    frame = rng.poisson(200, (300, 300)).astype(np.float64) + 100
    frame[3:12, 3:40] += 3000
    image = tmp_path / "corner.tif"
    tifffile.imwrite(image, np.stack([frame] * n_frames).astype(np.uint16).squeeze())
    mic = tmp_path / "mic.yaml"
    mic.write_text("pixel_size_um: 0.08\nmodality: fluorescence\nwavelength_um: 0.53\n")
    out = tmp_path / "out"
    code = main(["diagnose", str(image), "--microscope", str(mic), "--out", str(out),
                 "--region", region])  # fmt: skip
    said = capsys.readouterr().err.strip().splitlines()
    error = said[-1]
    assert code == 2
    note = "note: diagnosing rows 22:278, columns 22:278 of the 300 x 300 frame, the centre one"
    assert any(line.startswith(note) for line in said)
    where = "frame 0" if n_frames > 1 else "the image"
    assert f"{where}, rows 22:278, columns 22:278: the start found no cells" in error
    assert "pass --region Y0:Y1,X0:X1 for a window with cells" in error
    assert "--region full" in error
    assert not out.exists()


def _diagnose_refused(tmp_path, capsys, image, microscope_yaml: str) -> str:
    """``diagnose`` of ``image`` refused at its base fit's start: exit 2, nothing
    written; returns the error line."""
    mic = tmp_path / "mic.yaml"
    mic.write_text(microscope_yaml)
    out = tmp_path / "out"
    code = main(["diagnose", str(image), "--microscope", str(mic), "--out", str(out)])
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert code == 2
    assert not out.exists()
    return error


def test_a_colony_start_names_diagnoses_own_fix(tmp_path, capsys, real_data_dir):
    """The Omnipose colony Sample000033 (touching cells; 0.118 um/px, 1 um per median
    mask width): the automatic start takes them as wide regions and the base fit stops;
    the message names diagnose's own ways out, --masks and a window of separate cells."""
    image = real_data_dir / "omnipose" / "Sample000033.png"
    error = _diagnose_refused(tmp_path, capsys, image, "pixel_size_um: 0.118\nmodality: phase\n")
    assert "cells the automatic start found are wider than any rod-shaped bacterium" in error
    assert error.endswith(
        "pass the cells' instance masks as --masks M, or --region Y0:Y1,X0:X1 for a window "
        "of separate cells"
    )


def test_a_fluorescence_field_diagnosed_as_phase_is_refused_as_fit_refuses_it(
    tmp_path, capsys, real_data_dir
):
    """Found as a user: a fluorescence crop diagnosed with a microscope file that names
    no modality (phase) ran on to advice about cells wider than any rod; `fit` says the
    image does not look like phase. diagnose now says so too, with --modality, which it
    takes as fit does."""
    image = real_data_dir / "colicoords" / "test_data" / "ds1" / "fluorescence" / "00001.tif"
    error = _diagnose_refused(tmp_path, capsys, image, "pixel_size_um: 0.08\n")
    assert "the image does not look like phase" in error
    assert "Pass --modality fluorescence" in error
    # --modality overrides the file: a window around one cell, phase in the file, passes
    # the modality check as fluorescence and meets the fluorescence start's own refusal
    mic = tmp_path / "mic.yaml"
    args = ["diagnose", str(image), "--microscope", str(mic), "--region", "290:360,230:280",
            "--out", str(tmp_path / "window")]  # fmt: skip
    assert main(args) == 2
    assert "the image does not look like phase" in capsys.readouterr().err
    assert main([*args, "--modality", "fluorescence"]) == 2
    error = capsys.readouterr().err
    assert "does not look like" not in error
    assert "no bright region stands 40 times" in error


def test_a_crop_around_one_cell_is_diagnosed_from_its_masks(tmp_path, capsys, real_data_dir):
    """ColiCoords' single-cell crop ``01``: the automatic start finds no cell (its glow is
    most of the crop) and says to pass the masks or painted strokes. Found as a user:
    diagnose took no masks, so a lab's own masks could not start it as they start `fit`;
    with --masks the base fit starts from the crop's binary mask (one cell)."""
    folder = real_data_dir / "colicoords" / "01"
    mic = "pixel_size_um: 0.08\nmodality: fluorescence\nwavelength_um: 0.53\n"
    error = _diagnose_refused(tmp_path, capsys, folder / "fluorescence.tif", mic)
    assert "no bright region stands 40 times" in error
    assert error.endswith(
        "pass the cells' instance masks as --masks M, or paint rough cell and background "
        "strokes and pass them as --labels L"
    )
    out = tmp_path / "masked"
    args = ["diagnose", str(folder / "fluorescence.tif"), "--masks", str(folder / "binary.tif"),
            "--microscope", str(tmp_path / "mic.yaml"), "--max-effects", "1",
            "--out", str(out)]  # fmt: skip
    assert main(args) == 0, capsys.readouterr().err
    doc = json.loads((out / "diagnosis.json").read_text())
    assert doc["start"] == {"from": "instance masks", "cells_per_frame": [1]}
    assert sum(e["accepted"] for e in doc["effects"]) == 1
    assert (out / "residuals.png").stat().st_size > 0


def test_diagnose_masks_that_do_not_fit_the_window_are_refused(tmp_path, capsys, real_data_dir):
    """--masks of another image's shape, or with no cell in the window diagnosed: one
    line that says what to pass, exit 2, nothing written."""
    import tifffile

    folder = real_data_dir / "colicoords" / "01"
    mic = tmp_path / "mic.yaml"
    mic.write_text("pixel_size_um: 0.08\nmodality: fluorescence\nwavelength_um: 0.53\n")
    small = tmp_path / "small.tif"
    tifffile.imwrite(small, np.ones((20, 20), np.uint8))
    base = ["diagnose", str(folder / "fluorescence.tif"), "--microscope", str(mic)]
    out = tmp_path / "out"
    assert main([*base, "--masks", str(small), "--out", str(out)]) == 2
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert "--masks small.tif has shape (20, 20) but the image frame has shape (57, 61)" in error
    assert main([*base, "--masks", str(folder / "binary.tif"), "--region", "0:12,0:12",
                 "--out", str(out)]) == 2  # fmt: skip
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert "--masks binary.tif hold no cell in rows 0:12, columns 0:12" in error
    assert "pass --region Y0:Y1,X0:X1 for a window with cells" in error
    assert not out.exists()


def test_diagnose_masks_of_a_dense_colony_name_the_colony_fit(tmp_path, capsys, real_data_dir):
    """The Omnipose colony Sample000193 with its masks: diagnose's base fit draws
    separate rods, which cannot make a colony's halo and seams (the engine refused in
    the words of its Python API); the command names the colony fit, exit 2."""
    folder = real_data_dir / "omnipose"
    mic = tmp_path / "mic.yaml"
    mic.write_text("pixel_size_um: 0.07\nmodality: phase\n")
    out = tmp_path / "out"
    code = main(["diagnose", str(folder / "Sample000193.png"), "--masks",
                 str(folder / "Sample000193_cp_masks.tif"), "--microscope", str(mic),
                 "--region", "234:330,234:330", "--out", str(out)])  # fmt: skip
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert code == 2
    assert "--masks Sample000193_cp_masks.tif hold a dense colony of touching cells" in error
    assert "the colony fit (`napari-symbac fit IMAGE --masks MASKS`" in error
    assert "fit_colony" not in error
    assert not out.exists()


def test_candidates_no_held_out_check_reached_are_said_so(tmp_path, capsys, real_data_dir):
    """Found as a user: ColiCoords' single-cell crop ``01`` with strokes accepted four
    effects, the most a diagnosis accepts, and its plain envelope stain (score evidence
    above 100) read "not accepted" as if it had been checked and refused."""
    import tifffile

    strokes = np.zeros((57, 61), np.uint8)
    strokes[27:31, 15:45] = 1  # along the cell
    strokes[2:6, 2:20] = strokes[50:54, 40:58] = 2  # two corners of media
    labels = tmp_path / "strokes.tif"
    tifffile.imwrite(labels, strokes)
    mic = tmp_path / "mic.yaml"
    mic.write_text("pixel_size_um: 0.08\nmodality: fluorescence\nwavelength_um: 0.53\n")
    out = tmp_path / "out"
    image = real_data_dir / "colicoords" / "01" / "fluorescence.tif"
    args = ["diagnose", str(image), "--microscope", str(mic), "--labels", str(labels)]
    # at most 2 (since its 3.4-fold illumination is refused, this crop accepts 3 of 4)
    assert main([*args, "--max-effects", "2", "--out", str(out)]) == 0
    effects = json.loads((out / "diagnosis.json").read_text())["effects"]
    assert sum(e["accepted"] for e in effects) == 2
    envelope = next(e for e in effects if e["name"] == "envelope_stain")
    assert envelope["evidence"] > 3
    assert not envelope["held_out_tested"]
    assert all(e["held_out_tested"] for e in effects if e["accepted"])
    report = (out / "report.txt").read_text()
    assert re.search(r"envelope_stain +evidence +[0-9.]+  not held-out tested", report)
    assert "(a diagnosis accepts at most 2 effects: " in report
    assert "envelope_stain" in report.split("(a diagnosis accepts at most 2 effects: ")[1]
    assert "--max-effects N" in report
    # raised, the stain is checked after them (and its held-out gain decides)
    raised = tmp_path / "raised"
    assert main([*args, "--max-effects", "6", "--out", str(raised)]) == 0
    effects = json.loads((raised / "diagnosis.json").read_text())["effects"]
    assert next(e for e in effects if e["name"] == "envelope_stain")["held_out_tested"]
    assert "a diagnosis accepts at most" not in (raised / "report.txt").read_text()


def test_bright_field_is_diagnosed_with_its_lens_term(tmp_path, capsys, real_data_dir):
    """Found as a user: diagnose refused ColiCoords' bright-field crop (its base design
    had no lens term). The lens amplitude ``kappa I_m`` is now a column of the base
    design, re-fitted with the intensities; the effects that need a fluorophore or a
    phase ring are not tested; settings.yaml carries the re-fitted lens term."""
    image = real_data_dir / "colicoords" / "01" / "brightfield.tif"
    mic = tmp_path / "mic.yaml"
    mic.write_text(
        "pixel_size_um: 0.08\nmodality: brightfield\nwavelength_um: 0.55\nNA: 1.4\n"
        "refractive_index: 1.518\n"
    )
    out = tmp_path / "out"
    code = main(["diagnose", str(image), "--microscope", str(mic), "--out", str(out),
                 "--max-effects", "1"])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    doc = json.loads((out / "diagnosis.json").read_text())
    assert len([e for e in doc["effects"] if e["accepted"]]) == 1
    assert doc["final_fit"]["held_out"] < doc["base_fit"]["held_out"]
    report = (out / "report.txt").read_text()
    untested = report.split("not tested (need a time series, another modality or more cells): ")[1]
    for name in ("halo", "photobleaching", "envelope_stain"):
        assert name in untested.splitlines()[0]
    settings = load_settings(out / "settings.yaml", PipelineSettings)
    assert settings.microscope.modality == "brightfield"
    assert settings.render.defocus_contrast_um2 > 0.005  # a bright centre, as fitted
    assert settings.render.cell_intensity < settings.render.media_intensity


def test_the_most_effects_the_command_accepts_is_the_diagnosis_default():
    """``--max-effects``' default (a constant, so that ``--help`` need not import the
    diagnosis) is :func:`~napari_symbac.diagnose.diagnose`'s own."""
    import inspect

    from napari_symbac.cli import DIAGNOSE_MAX_EFFECTS
    from napari_symbac.diagnose import diagnose

    assert inspect.signature(diagnose).parameters["max_steps"].default == DIAGNOSE_MAX_EFFECTS


def test_an_instance_mask_given_as_labels_is_refused_whatever_the_window(
    tmp_path, capsys, real_data_dir
):
    """Found as a user: ColiCoords ds1's instance mask (ids 0-8) passed as --labels with
    a window holding only cells 1 and 3 ran, cell 3 read as the device class, exit 0."""
    ds1 = real_data_dir / "colicoords" / "test_data" / "ds1"
    mic = tmp_path / "mic.yaml"
    mic.write_text("pixel_size_um: 0.08\nmodality: fluorescence\nwavelength_um: 0.53\n")
    out = tmp_path / "out"
    args = [
        "diagnose", str(ds1 / "fluorescence" / "00001.tif"), "--microscope", str(mic),
        "--labels", str(ds1 / "binary" / "00001_Probabilities_filtered.tif"),
        "--region", "95:146,250:420", "--out", str(out),
    ]  # fmt: skip
    assert main(args) == 2
    error = capsys.readouterr().err
    assert "holds classes [4, 5, 6, 7, 8]" in error
    assert "an instance mask goes to --masks instead" in error
    assert "Traceback" not in error
    assert not out.exists()


def test_a_large_phase_field_is_announced_as_slow(tmp_path, capsys, real_data_dir):
    """Found as a user: diagnose of an Omnipose colony's default 256 x 256 px window ran
    past 10 minutes with nothing said up front; a 96 x 96 px window takes under one."""
    mic = tmp_path / "mic.yaml"
    mic.write_text("pixel_size_um: 0.118\nmodality: phase\n")
    image = real_data_dir / "omnipose" / "Sample000033.png"
    args = ["diagnose", str(image), "--microscope", str(mic)]
    main([*args, "--out", str(tmp_path / "whole")])  # refused at its start (touching cells)
    said = capsys.readouterr().err
    assert "a phase-contrast field of 65,339 pixels takes tens of minutes" in said
    assert "--region Y0:Y1,X0:X1 picks a smaller window" in said


def test_a_large_diagnosis_of_any_modality_is_announced_as_slow(tmp_path, capsys):
    """Found as a user: `--region full` of ColiCoords ds3 (4 frames of 512 x 512 px,
    fluorescence) had done 2 of 11 held-out checks after 9 min, with nothing said up
    front. Two 200 x 200 px frames (80,000 pixels, more than the default window's) are
    announced before the base fit (which finds no cells in this noise and stops)."""
    image = tmp_path / "series.tif"
    tifffile.imwrite(image, np.random.default_rng(2).poisson(500, (2, 200, 200)).astype(np.uint16))
    mic = tmp_path / "mic.yaml"
    mic.write_text("pixel_size_um: 0.08\nmodality: fluorescence\n")
    args = ["diagnose", str(image), "--microscope", str(mic), "--out", str(tmp_path / "o")]
    assert main([*args, "--region", "full"]) == 2
    said = capsys.readouterr().err
    assert "note: diagnosing 80,000 pixels (2 x 200 x 200) takes long" in said
    assert "--region Y0:Y1,X0:X1 picks a smaller window" in said
    assert main([*args, "--region", "0:100,0:100"]) == 2  # 20,000 pixels: nothing said
    assert "takes long" not in capsys.readouterr().err


def test_a_diagnosis_on_a_poor_base_fit_is_cautioned(tmp_path, capsys, real_data_dir):
    """Found as a user: a window of the dense Omnipose colony, diagnosed without its
    masks, fitted 2 cells for ~20 (reduced chi-square ~300) and accepted effects such as
    fixed-pattern noise from the cells the fit missed, without a word. That window's fit
    kept 2 of the 11 cells of its start and is now refused with the colony's fix; another,
    whose fit keeps 6 of 9 at a reduced chi-square of ~340, is diagnosed, and report.txt
    and the terminal caution that the base fit, not physics, may be the misfit, name the
    colony's way (fit --masks), and report.txt says what to do next."""
    mic = tmp_path / "mic.yaml"
    mic.write_text("pixel_size_um: 0.07\nmodality: phase\n")
    image = real_data_dir / "omnipose" / "Sample000193.png"
    refused = tmp_path / "refused"
    code = main(["diagnose", str(image), "--microscope", str(mic), "--region",
                 "234:330,234:330", "--out", str(refused)])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2
    assert "the fit kept 2 of the 11 cells its automatic start found" in err
    assert "pass the cells' instance masks as --masks M" in err
    assert not refused.exists()
    out = tmp_path / "omni"
    code = main(["diagnose", str(image), "--microscope", str(mic), "--region",
                 "400:496,234:330", "--out", str(out)])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 0
    report = (out / "report.txt").read_text()
    base = json.loads((out / "diagnosis.json").read_text())["base_fit"]["value"]
    assert base > 50
    assert f"CAUTION: the base fit leaves a reduced chi-square of {base:.3g}" in report
    assert "napari-symbac diagnose: warning: the base fit leaves a reduced chi-square" in err
    assert "the colony fit (`napari-symbac fit IMAGE --masks MASKS`" in err
    assert f"`napari-symbac export --config {out / 'settings.yaml'} --out DATASET`" in report
    # and where the final model misses most, as residuals.png shows it
    where = re.search(r"largest remaining misfit: row (\d+), column (\d+) of the diag", report)
    assert where is not None
    assert 0 <= int(where[1]) < 96
    assert 0 <= int(where[2]) < 96


def test_a_small_window_without_cells_found_says_it_may_be_too_small(
    tmp_path, capsys, real_data_dir
):
    """Found as a user: a 40 x 40 px window around one ColiCoords cell was "the start
    found no cells ... pass --region for a window with cells"; a 64 x 64 one worked."""
    mic = tmp_path / "mic.yaml"
    mic.write_text("pixel_size_um: 0.08\nmodality: fluorescence\nwavelength_um: 0.52\n")
    image = real_data_dir / "colicoords" / "test_data" / "ds1" / "fluorescence" / "00001.tif"
    out = tmp_path / "small"
    code = main(["diagnose", str(image), "--microscope", str(mic), "--region",
                 "130:170,60:100", "--out", str(out)])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2
    assert "the 40 x 40 px window may be too small for the start to tell the cells" in err
    assert not out.exists()



def test_one_cell_leaves_cell_to_cell_brightness_untested(tmp_path, real_data_dir, capsys):
    """Found as a user: the top 96 rows of the real trench hold one cell, and
    cell_intensity_variability was accepted at a CV of 0 (one cell's gain is the fitted
    cell intensity's own), taking one of the four places for effects; its settings then
    drew nothing. With fewer than two cells it is not tested, and the report says so."""
    out = tmp_path / "one-cell"
    trench = real_data_dir / "ecoli_100x_oil_exponential.tiff"
    code = main(["diagnose", str(trench), "--pixel-size-um", "0.065", "--region", "0:96,0:46",
                 "--out", str(out)])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    doc = json.loads((out / "diagnosis.json").read_text())
    assert doc["start"]["cells_per_frame"] == [1]
    assert "cell_intensity_variability" in doc["not_tested"]
    assert "cell_intensity_variability" not in [effect["name"] for effect in doc["effects"]]
    assert "another modality or more cells): " in (out / "report.txt").read_text()


def test_frames_of_a_series_are_picked_as_fit_picks_them(tmp_path, capsys, real_data_dir):
    """Found as a user: ColiCoords ds3 holds four fields in one file, and diagnose took
    them only together, as one time series (its advice: "a TIFF of those frames"). Now
    --frames picks them as `fit --frames` does, with the masks of the frames picked."""
    ds3 = real_data_dir / "colicoords" / "test_data" / "ds3"
    mic = tmp_path / "mic.yaml"
    mic.write_text("pixel_size_um: 0.08\nmodality: fluorescence\nwavelength_um: 0.53\n")
    out = tmp_path / "two"
    args = ["diagnose", str(ds3 / "flu.tif"), "--microscope", str(mic),
            "--masks", str(ds3 / "binary.tif"), "--region", "280:370,0:96",
            "--max-effects", "1"]  # fmt: skip
    assert main([*args, "--frames", "7", "--out", str(out)]) == 2
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert error.endswith(
        "--frames '7': frame(s) 7 do not exist: flu.tif has 4 frames, numbered 0-3"
    )
    # frame 2's cell at rows 303:346, columns 11:68; frames 0 and 1 have none there
    assert main([*args, "--frames", "2", "--out", str(out)]) == 0, capsys.readouterr().err
    doc = json.loads((out / "diagnosis.json").read_text())
    assert doc["frames"] == [2]
    assert doc["start"]["from"] == "instance masks"
    assert len(doc["start"]["cells_per_frame"]) == 1
    report = (out / "report.txt").read_text()
    assert report.startswith(
        "recording: flu.tif, rows 280:370, columns 0:96 of the 512 x 512 px frame, frames 2 of 4\n"
    )
    assert main([*args, "--frames", "0-1", "--out", str(tmp_path / "none")]) == 2
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert "hold no cell in frame 0, rows 280:370, columns 0:96" in error
