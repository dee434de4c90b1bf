"""``napari-symbac calibrate``: a matched dataset and report from a real crop; refusals."""

from __future__ import annotations

import json

import imageio.v3 as iio
import numpy as np
import pytest
import tifffile
import yaml

from napari_symbac.cli import main
from napari_symbac.export.visibility import pixel_noise


@pytest.fixture
def colicoords_files(real_data_dir, tmp_path):
    ds1 = real_data_dir / "colicoords" / "test_data" / "ds1"
    image = tifffile.imread(ds1 / "fluorescence" / "00001.tif")[:192, :256]
    masks = tifffile.imread(ds1 / "binary" / "00001_Probabilities_filtered.tif")[:192, :256]
    tifffile.imwrite(tmp_path / "flu.tif", image)
    tifffile.imwrite(tmp_path / "mask.tif", masks)
    (tmp_path / "m80.yaml").write_text("pixel_size_um: 0.08\nwavelength_um: 0.53\n")
    return tmp_path


def test_calibrate_writes_a_matched_dataset_and_report(colicoords_files, capsys):
    d = colicoords_files
    out = d / "out"
    code = main(
        [
            "calibrate", str(d / "flu.tif"), "--masks", str(d / "mask.tif"),
            "--microscope", str(d / "m80.yaml"), "--modality", "fluorescence",
            "--out", str(out), "--n-items", "3", "--formats", "tiff,omnipose",
        ]
    )
    assert code == 0, capsys.readouterr().err
    assert {p.name for p in out.iterdir()} == {
        "dataset", "report.txt", "report.png", "export_settings.yaml", "masks.tif"
    }
    # masks.tif opens as labels at the pixel size calibrated at (found as a user: none)
    from napari_symbac.io import read_recording

    masks = read_recording(out / "masks.tif")
    assert masks.kind == "labels"
    assert masks.pixel_size_um == pytest.approx(0.08, rel=1e-6)
    manifest = json.loads((out / "dataset" / "manifest.json").read_text())
    assert manifest["status"] == "complete"
    assert len(manifest["items"]) == 3
    assert manifest["settings"]["visibility"]["action"] == "drop"
    assert manifest["settings"]["pipeline"]["microscope"]["modality"] == "fluorescence"
    assert (out / "dataset" / "omnipose").is_dir()
    images = sorted((out / "dataset" / "tiff").rglob("*.tif"))
    assert images
    report = (out / "report.txt").read_text()
    assert "fluorescence" in report
    assert "power spectrum" in report
    # the pixel size said once (was "pixel size 0.08 um (pixel size 0.08 um from ...)")
    assert "\npixel size 0.08 um from --microscope (the image file records none)\n" in report
    printed = capsys.readouterr()
    _assert_flags_follow_the_numbers(report, printed.out)
    # a line per stage on stderr (the fit, the comparison, the export), and the export's
    # progress (found as a user: piped, 188 s of a 500-item export passed without a line)
    lines = printed.err.splitlines()
    assert [line for line in lines if line.startswith("napari-symbac calibrate")] == [
        "napari-symbac calibrate: fitting",
        "napari-symbac calibrate: comparing real and synthetic",
        "napari-symbac calibrate: exporting",
    ]
    exported = [line for line in lines if line.startswith("napari-symbac export: ")]
    assert exported[-1] == "napari-symbac export: 3 of 3 images"
    assert lines.index(exported[0]) > lines.index("napari-symbac calibrate: exporting")
    assert "pass --masks" not in report  # they were given: the advice does not ask for them
    assert "read as counts" not in report  # camera counts: nothing to mark
    # the masks' outline convention, read in the light against the fitted model's,
    # goes to the dataset: the ColiCoords annotations lie outside the model cells
    assert "mask outline at " in report
    dilation = manifest["settings"]["mask_dilation_um"]
    assert 0.02 < dilation < 0.4
    assert f"{dilation:.3f}" in report or f"{dilation:+.3f}" in report
    picture = iio.imread(out / "report.png")
    assert picture.ndim == 3
    assert picture.shape[1] > 2 * 192
    assert not [p for p in d.iterdir() if p.name.startswith(".out")]  # staging removed
    # the same command again: refused, saying why (found as a user: no word of the
    # earlier calibration there)
    assert main(["calibrate", str(d / "flu.tif"), "--masks", str(d / "mask.tif"),
                 "--microscope", str(d / "m80.yaml"), "--out", str(out)]) == 2  # fmt: skip
    assert "it holds an earlier calibration" in capsys.readouterr().err
    _follow_the_tracking_advice(out, d, capsys)


def _follow_the_tracking_advice(out, d, capsys):
    """calibrate's advice for tracking formats, followed as it reads (found as a user:
    it named kind and formats but not visibility.action, and export then refused the
    settings for dropping faint cells from their tracks)."""
    import yaml

    code = main(["calibrate", str(d / "flu.tif"), "--microscope", str(d / "m80.yaml"),
                 "--modality", "fluorescence", "--out", str(d / "x"), "--formats", "ctc"])
    advice = capsys.readouterr().err
    assert code == 2
    for words in ("kind: timeseries", "formats: [ctc]", "visibility: action: flag",
                  "pipeline: simulation: n_frames"):  # fmt: skip
        assert words in advice
    settings = yaml.safe_load((out / "export_settings.yaml").read_text())
    settings.update(kind="timeseries", formats=["ctc"], n_items=2)
    settings["visibility"]["action"] = "flag"
    settings["pipeline"]["simulation"]["n_frames"] = 4
    (d / "tracks.yaml").write_text(yaml.safe_dump(settings))
    code = main(["export", "--config", str(d / "tracks.yaml"), "--out", str(d / "tracks")])
    assert code == 0, capsys.readouterr().err
    manifest = json.loads((d / "tracks" / "manifest.json").read_text())
    assert manifest["status"] == "complete"
    assert len(manifest["items"]) == 2 * 4  # two series of 4 frames
    assert (d / "tracks" / "ctc").is_dir()


def test_calibrate_says_a_normalised_field_was_read_as_counts(colicoords_files, capsys):
    """A real field divided by its maximum (0..1 floats, as normalised crops are; the
    normalised DeLTA file is a trench, which calibrate refuses) is read as counts, x 10000
    ADU. report.txt said nothing of it: its camera (ADU/e-, e-) read as a real camera's.
    It now says so as ``fit``'s report does."""
    d = colicoords_files
    counts = tifffile.imread(d / "flu.tif")
    tifffile.imwrite(d / "normalised.tif", (counts / counts.max()).astype(np.float32))
    out = d / "out"
    code = main(
        [
            "calibrate", str(d / "normalised.tif"), "--masks", str(d / "mask.tif"),
            "--microscope", str(d / "m80.yaml"), "--modality", "fluorescence",
            "--out", str(out), "--n-items", "1",
        ]
    )
    captured = capsys.readouterr()
    assert code == 0, captured.err
    read_as = "(value) x 10000 ADU"
    assert f"not camera counts): read as {read_as}" in captured.err
    lines = (out / "report.txt").read_text().splitlines()
    assert lines[2] == (
        f"image values: normalised values (0..1, not camera counts): read as {read_as}, so "
        "that the fit can measure their noise; intensities and datasets are in those units"
    )
    (camera,) = [line for line in lines if line.startswith("- camera: measured from the image")]
    assert camera.endswith(
        f" e-, 16 bit [normalised image read as counts, {read_as}: not a real camera's units]"
    )
    assert (
        f"- every ADU and e- in this report is of the normalised image read as counts, "
        f"{read_as}: not of a real camera (its gain, baseline and noise in those units)"
    ) in lines


def _assert_flags_follow_the_numbers(report: str, stdout: str) -> None:
    """Each quantity's MATCH / MISMATCH agrees with the numbers report.txt prints (found
    as a user: ColiCoords field 1's synthetic cells at 1.171 against the real 0.993, and
    spectra 1.5-5x apart, were printed unflagged), and the summary counts them."""
    from napari_symbac.calibrate.compare import MEDIAN_TOLERANCE

    rows = {
        line[:19].strip(): [float(v) for v in line[19:].split()]
        for line in report.splitlines()
        if line.startswith(("cells median", "background median"))
    }
    assert len(rows) == 2
    matched = 0
    for name, (real, synthetic) in rows.items():
        word = "MATCH" if abs(synthetic - real) <= MEDIAN_TOLERANCE else "MISMATCH"
        assert f"- {name}: {word}: synthetic {synthetic:.3f} against real {real:.3f}" in report
        matched += word == "MATCH"
    bands = [line for line in report.splitlines() if line.startswith("  0.")]
    assert len(bands) == 16
    out = [line for line in bands if line.endswith("MISMATCH")]
    for line in out:  # a flagged band is at least the 1.5x tolerance away
        ratio = float(line.split("x")[-1].split()[0])
        assert not 1 / 1.5 <= ratio <= 1.5
    spectrum = "MISMATCH" if out else "MATCH"
    assert f"- power spectrum: {spectrum}:" in report
    matched += spectrum == "MATCH"
    matched += "- background noise: MATCH:" in report
    summary = f"the synthetic data match the recording in {matched} of 4 comparisons"
    assert summary in report
    assert summary in stdout  # the CLI's summary says the same


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--modality", "phase"], "does not look like phase"),
        (["--masks", "MISSING.tif"], "does not exist"),
        (["--formats", "nonsense"], "unknown format"),
        (["--formats", "tiff,ctc"], "--formats ctc: tracking ground truth needs a time series"),
    ],
)
def test_calibrate_bad_input_is_one_line_and_writes_nothing(
    colicoords_files, capsys, extra, message
):
    d = colicoords_files
    args = [
        "calibrate", str(d / "flu.tif"), "--microscope", str(d / "m80.yaml"),
        "--out", str(d / "out"), "--n-items", "2",
    ]
    if "--masks" not in extra:
        args += ["--masks", str(d / "mask.tif")]
    if "--modality" not in extra:
        args += ["--modality", "fluorescence"]
    code = main(args + extra)
    err = capsys.readouterr().err
    assert code == 2
    assert message in err
    assert err.count("\n") <= 2
    assert "Traceback" not in err
    assert not (d / "out").exists()
    assert not [p for p in d.iterdir() if p.name.startswith(".out")]


def test_calibrate_refuses_a_colour_image_and_a_full_out_folder(colicoords_files, capsys):
    d = colicoords_files
    rgb = np.zeros((64, 64, 3), np.uint8)
    rgb[..., 0] = 200
    iio.imwrite(d / "colour.png", rgb)
    code = main(
        ["calibrate", str(d / "colour.png"), "--microscope", str(d / "m80.yaml"),
         "--out", str(d / "o2")]
    )
    assert code == 2
    assert "colour image" in capsys.readouterr().err
    (d / "full").mkdir()
    (d / "full" / "x.txt").write_text("keep me")
    code = main(
        ["calibrate", str(d / "flu.tif"), "--masks", str(d / "mask.tif"), "--microscope",
         str(d / "m80.yaml"), "--modality", "fluorescence", "--out", str(d / "full")]
    )
    assert code == 2
    assert "not an empty folder" in capsys.readouterr().err
    assert [p.name for p in (d / "full").iterdir()] == ["x.txt"]


def test_calibrate_refuses_an_implausible_pixel_size(colicoords_files, capsys):
    d = colicoords_files
    (d / "m8.yaml").write_text("pixel_size_um: 8.0\nmodality: fluorescence\n")
    code = main(
        ["calibrate", str(d / "flu.tif"), "--masks", str(d / "mask.tif"), "--microscope",
         str(d / "m8.yaml"), "--out", str(d / "o8")]
    )  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2
    assert "pixel size 8 um (from --microscope" in err
    assert "Traceback" not in err
    assert not (d / "o8").exists()


def test_calibrate_from_painted_labels(colicoords_files, capsys):
    d = colicoords_files
    from scipy import ndimage

    masks = tifffile.imread(d / "mask.tif")
    labels = np.zeros(masks.shape, np.uint8)
    labels[ndimage.binary_erosion(masks > 0, iterations=3)] = 1
    labels[ndimage.distance_transform_edt(masks == 0) > 10] = 2
    tifffile.imwrite(d / "labels.tif", labels)
    out = d / "from_labels"
    code = main(
        ["calibrate", str(d / "flu.tif"), "--labels", str(d / "labels.tif"), "--microscope",
         str(d / "m80.yaml"), "--modality", "fluorescence", "--out", str(out), "--n-items", "2"]
    )
    printed = capsys.readouterr()
    assert code == 0, printed.err
    report = (out / "report.txt").read_text()
    assert "no masks: sizes from the fit's cells on the crop" in report
    # what was measured, said as a measurement of masks.tif, not as the fit's sizes
    assert "; masks.tif measures " in printed.out
    fitted = tifffile.imread(out / "masks.tif")
    assert len(np.unique(fitted)) - 1 >= 1  # the fit's own cells were measured
    # the simulated field is the whole image, with the image's clusters, not the crop's
    from napari_symbac.export import load_export_settings

    image = tifffile.imread(d / "flu.tif")
    pad = load_export_settings(out / "export_settings.yaml").pipeline.simulation.agar_pad
    assert pad.field_height_um == pytest.approx(image.shape[0] * 0.08)
    assert pad.field_width_um == pytest.approx(image.shape[1] * 0.08)
    assert f"the whole image ({image.shape[0]} x {image.shape[1]} px)" in report


def test_calibrate_help_lists_the_frame_formats_it_writes(capsys):
    """Found as a user: the help did not say which formats calibrate takes."""
    from napari_symbac.export.formats import FORMATS

    with pytest.raises(SystemExit):
        main(["calibrate", "--help"])
    words = " ".join(capsys.readouterr().out.split())
    frames = [name for name, fmt in FORMATS.items() if not fmt.timeseries_only]
    assert f"frame formats: {', '.join(frames)} (default tiff)" in words
    assert "the recording's contrast" in words  # --modality says what it is


def test_calibrate_takes_one_frame_of_a_series(real_data_dir, tmp_path, capsys):
    """Found as a user: a (T, Y, X) recording needed a script to cut one frame out. ColiCoords
    ds3 (4 fluorescence frames that kept the camera offset, masks for each): --frame
    picks the frame and its masks; the offset becomes the camera baseline."""
    ds3 = real_data_dir / "colicoords" / "test_data" / "ds3"
    stack = tifffile.imread(ds3 / "flu.tif")[:, 128:384, 128:384]
    masks = tifffile.imread(ds3 / "binary.tif")[:, 128:384, 128:384]
    tifffile.imwrite(tmp_path / "movie.tif", stack)
    tifffile.imwrite(tmp_path / "movie_masks.tif", masks)
    (tmp_path / "m.yaml").write_text("pixel_size_um: 0.08\nwavelength_um: 0.53\n")
    args = [
        "calibrate", str(tmp_path / "movie.tif"), "--masks", str(tmp_path / "movie_masks.tif"),
        "--microscope", str(tmp_path / "m.yaml"), "--modality", "fluorescence",
        "--n-items", "2",
    ]  # fmt: skip
    assert main([*args, "--out", str(tmp_path / "a")]) == 2
    assert "holds 4 frames: pass --frame K (0..3)" in capsys.readouterr().err
    assert main([*args, "--out", str(tmp_path / "b"), "--frame", "4"]) == 2
    assert "--frame 4: IMAGE movie.tif has frames 0..3" in capsys.readouterr().err
    assert main([*args, "--out", str(tmp_path / "c"), "--frame", "3"]) == 0
    report = (tmp_path / "c" / "report.txt").read_text()
    baseline = float(report.split("camera: measured from the image: baseline ")[1].split()[0])
    assert 1700 < baseline < float(stack[3].min()) + 50


def test_calibrate_refuses_a_frame_a_single_image_lacks(colicoords_files, capsys):
    """Found as a user: --frame 2 on one 2D frame was ignored, and calibrate fitted and
    exported frame 0 with exit 0; now it is refused before the fit, nothing written."""
    d = colicoords_files
    args = [
        "calibrate", str(d / "flu.tif"), "--microscope", str(d / "m80.yaml"),
        "--modality", "fluorescence", "--n-items", "1", "--out", str(d / "out"),
    ]  # fmt: skip
    assert main([*args, "--frame", "2"]) == 2
    err = capsys.readouterr().err
    assert "--frame 2: IMAGE flu.tif is one frame (frame 0): leave --frame out" in err
    assert "Traceback" not in err
    assert not (d / "out").exists() or not any((d / "out").iterdir())


def test_calibrate_refuses_a_trench_and_names_fit_and_export(real_data_dir, tmp_path, capsys):
    """Found as a user: DeLTA's trench (32 px wide) was laid out as a 2 x 17 um agar pad,
    and 3 of 4 images held no cell."""
    (tmp_path / "m.yaml").write_text("pixel_size_um: 0.065\n")
    image = real_data_dir / "ecoli_delta_phase_normalised.tiff"
    out = tmp_path / "out"
    code = main(["calibrate", str(image), "--microscope", str(tmp_path / "m.yaml"),
                 "--out", str(out)])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2
    assert "is 256 x 32 px (rows x columns), narrow and tall: a mother-machine trench" in err
    assert "napari-symbac export --config FIT/settings.yaml" in err
    # the user's own files in the command to copy (was a placeholder, M.yaml)
    assert f"`napari-symbac fit {image} --microscope {tmp_path / 'm.yaml'} --out FIT`" in err
    assert not out.exists()
    # on its side (found as a user: laid out as a pad, a dataset of empty frames, exit 0)
    lying = tmp_path / "lying.tif"
    tifffile.imwrite(lying, np.rot90(tifffile.imread(image)).copy())
    code = main(["calibrate", str(lying), "--microscope", str(tmp_path / "m.yaml"),
                 "--out", str(out)])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2
    assert "IMAGE lying.tif is 32 x 256 px (rows x columns), wide and short" in err
    assert "rotate it by 90 degrees" in err
    upright = tmp_path / "lying_upright.tif"  # the command names the turned image
    assert f"turned upright, and export from its settings: `napari-symbac fit {upright} " in err
    assert "napari-symbac export --config FIT/settings.yaml" in err
    assert not out.exists()
    # the pixel size given is in the command to copy (found as a user: left out, the
    # fit then refused for want of one)
    code = main(["calibrate", str(image), "--pixel-size-um", "0.065", "--out", str(out)])
    assert code == 2
    assert f"`napari-symbac fit {image} --pixel-size-um 0.065 --out FIT`" in (
        capsys.readouterr().err
    )


def test_calibrate_of_a_colony_without_masks_asks_for_them(real_data_dir, tmp_path, capsys):
    """The Omnipose colony Sample000033 (touching cells, 0.118 um/px) without masks: the
    fit's automatic start takes the colony as wide regions; calibrate stops there and
    asks for the masks, its option named, with nothing written."""
    (tmp_path / "m.yaml").write_text("pixel_size_um: 0.118\nmodality: phase\n")
    image = real_data_dir / "omnipose" / "Sample000033.png"
    out = tmp_path / "out"
    code = main(["calibrate", str(image), "--microscope", str(tmp_path / "m.yaml"),
                 "--out", str(out)])  # fmt: skip
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert code == 2
    assert error.startswith("napari-symbac calibrate: error: ")
    assert "cells the automatic start found are wider than any rod-shaped bacterium" in error
    assert error.endswith("(--masks M)")
    assert not out.exists()
    assert not list(tmp_path.glob(".out*"))


def test_a_terminated_calibrate_leaves_nothing_behind(colicoords_files, capsys, monkeypatch):
    """Found as a user: `timeout 120 napari-symbac calibrate ...` (SIGTERM) left a 49 MB
    `.OUT.partial-*` folder beside --out. SIGTERM now unwinds as Ctrl-C: exit 143, the
    staging removed, --out never made. (The signal is injected during the export.)"""
    import os
    import signal

    import napari_symbac.export as export_module

    real_export = export_module.export_dataset

    def export_then_terminated(*args, **kwargs):
        report = real_export(*args, **kwargs)  # the dataset is in the staging folder
        os.kill(os.getpid(), signal.SIGTERM)
        return report

    monkeypatch.setattr(export_module, "export_dataset", export_then_terminated)
    d = colicoords_files
    out = d / "out"
    previous = signal.getsignal(signal.SIGTERM)
    code = main(
        [
            "calibrate", str(d / "flu.tif"), "--masks", str(d / "mask.tif"),
            "--microscope", str(d / "m80.yaml"), "--modality", "fluorescence",
            "--out", str(out), "--n-items", "2",
        ]
    )  # fmt: skip
    assert code == 143
    assert signal.getsignal(signal.SIGTERM) == previous  # the handler is put back
    assert "calibrate: interrupted: run the same calibrate again" in capsys.readouterr().err
    assert not out.exists()
    assert not [p for p in d.iterdir() if p.name.startswith(".out")]  # staging removed


def _far_background(masks: np.ndarray, image: np.ndarray) -> np.ndarray:
    """Pixels more than 3 px from every cell, below the 16-bit clip."""
    from scipy import ndimage

    return ~ndimage.binary_dilation(masks > 0, iterations=3) & (image < 65535)


def test_calibrate_matches_a_bright_field_recording(real_data_dir, tmp_path, capsys):
    """Bright field (ColiCoords ds1 field 1, flattened: its pixel variance falls with the
    mean; 9 % of it clipped at 65535) with its masks: the dataset's noise is the image's
    own pixel noise (the fit's residual counted its misfit, 2x on crop 01), its light
    never passes full scale (the 0.8-1.25 exposure turned every image white), and its
    masks follow the annotations' outline (0.26 um outside the model cells)."""
    ds1 = real_data_dir / "colicoords" / "test_data" / "ds1"
    image = tifffile.imread(ds1 / "brightfield" / "00001.tif")[:192, :256]
    masks = tifffile.imread(ds1 / "binary" / "00001_Probabilities_filtered.tif")[:192, :256]
    tifffile.imwrite(tmp_path / "bf.tif", image)
    tifffile.imwrite(tmp_path / "mask.tif", masks)
    (tmp_path / "m.yaml").write_text(
        "pixel_size_um: 0.08\nwavelength_um: 0.55\nnumerical_aperture: 1.4\n"
        "modality: brightfield\n"
    )
    out = tmp_path / "out"
    code = main(["calibrate", str(tmp_path / "bf.tif"), "--masks", str(tmp_path / "mask.tif"),
                 "--microscope", str(tmp_path / "m.yaml"), "--out", str(out),
                 "--n-items", "3"])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    manifest = json.loads((out / "dataset" / "manifest.json").read_text())
    pipeline = manifest["settings"]["pipeline"]
    assert pipeline["microscope"]["modality"] == "brightfield"
    render = pipeline["render"]
    assert render["noise_model"] == "gaussian"
    report = (out / "report.txt").read_text()
    assert "camera: not measurable from the image" in report
    # the pad's mottling (14.5 ADU rms, 4 px on the whole field), drawn: networks trained
    # on a clean pad called it cells
    assert "background texture: " in report
    assert 0.3 < render["texture_scale_um"] < 1.5
    assert 5.0 < render["texture_amplitude"] * render["media_intensity"] < 40.0
    assert f"noise Gaussian, {render['gaussian_noise_sd_adu']:.3g} ADU" in report
    _assert_flags_follow_the_numbers(report, capsys.readouterr().out)
    # the media lie ~45 ADU below full scale: no brighter exposure than the recording's
    headroom_adu = 65535 - pipeline["camera"]["baseline_adu"]
    exposure = manifest["settings"]["randomise"]["exposure_scale"]
    assert exposure["low"] == 0.8
    assert 1.0 <= exposure["high"] == pytest.approx(headroom_adu / render["media_intensity"])
    # the dataset's pixel noise is the recording's (ADU, background away from cells),
    # within the export's noise draw (noise_scale) and 5 % of sampling
    real_noise = pixel_noise(image, _far_background(masks, image))
    drawn = manifest["settings"]["randomise"]["noise_scale"]
    images = sorted((out / "dataset" / "tiff").glob("*/images/*.tif"))
    assert len(images) == 3
    for path in images:
        synthetic = tifffile.imread(path)
        assert np.mean(synthetic == 65535) < 0.5
        labels = tifffile.imread(str(path).replace("images", "labels"))
        noise = pixel_noise(synthetic, _far_background(labels, synthetic))
        assert 0.95 * drawn["low"] < noise / real_noise < 1.05 * drawn["high"]
    assert "mask outline +" in report
    assert 0.1 < manifest["settings"]["mask_dilation_um"] < 0.4


def _refused(argv: list[str], out, capsys) -> str:
    """The one-line error of a calibrate refused with exit 2, nothing written."""
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err
    assert not out.exists()
    return err.strip().splitlines()[-1]


def test_calibrate_refuses_a_colony_given_as_a_cell_background_mask(
    real_data_dir, tmp_path, capsys
):
    """Found as a user: Omnipose's colony Sample000193 with its masks as 0/1 was one cell
    8.88 um long, the pixel size 0.020 um from its width, exit 0."""
    omnipose = real_data_dir / "omnipose"
    masks = tifffile.imread(omnipose / "Sample000193_cp_masks.tif")
    tifffile.imwrite(tmp_path / "bin193.tif", (masks > 0).astype(np.uint8))
    (tmp_path / "m.yaml").write_text("modality: phase\n")
    out = tmp_path / "out"
    error = _refused(
        ["calibrate", str(omnipose / "Sample000193.png"), "--microscope",
         str(tmp_path / "m.yaml"), "--masks", str(tmp_path / "bin193.tif"),
         "--cell-width-um", "1.0", "--out", str(out), "--n-items", "8"],
        out, capsys,
    )  # fmt: skip
    assert "--masks bin193.tif holds one value, a cell/background mask" in error
    assert "Give instance masks, each cell its own number (e.g. Omnipose" in error


def test_calibrate_of_bright_field_as_phase_names_the_modality(real_data_dir, tmp_path, capsys):
    """Found as a user: ColiCoords' bright field as phase failed after a 16-112 s fit with
    "the image is flat between its percentiles: nothing to normalise". A note before the
    fit says it looks like bright field; the fit's saturated dataset is refused naming the
    modality (not a refusal up front: a sparse phase field with faint halos looks alike)."""
    ds1 = real_data_dir / "colicoords" / "test_data" / "ds1"
    (tmp_path / "m.yaml").write_text("pixel_size_um: 0.08\nmodality: phase\n")
    out = tmp_path / "out"
    masks = ["--masks", str(ds1 / "binary" / "00001_Probabilities_filtered.tif")]
    image, microscope = ds1 / "brightfield" / "00001.tif", tmp_path / "m.yaml"
    code = main(["calibrate", str(image), "--microscope", str(microscope), *masks,
                 "--out", str(out), "--n-items", "2"])  # fmt: skip
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert not out.exists()
    note = "napari-symbac calibrate: note: the image shows dark objects and nothing brighter"
    said = [i for i, line in enumerate(lines) if line.startswith(note)]
    assert said
    assert said[0] < lines.index("napari-symbac calibrate: fitting")
    assert "pass --modality brightfield" in lines[said[0]]
    assert "saturated" in lines[-1]
    assert "check the modality (bright field given as phase saturates)" in lines[-1]


def test_calibrate_refuses_cells_wider_than_a_rod(colicoords_files, capsys):
    """Found as a user: pixel_size_um 0.8 for ColiCoords' 0.08 um calibrated cells 29.8 um
    long and 15.2 um wide, the fit at its bounds, exit 0."""
    d = colicoords_files
    (d / "m800.yaml").write_text("pixel_size_um: 0.8\nmodality: fluorescence\n")
    out = d / "out"
    error = _refused(
        ["calibrate", str(d / "flu.tif"), "--masks", str(d / "mask.tif"), "--microscope",
         str(d / "m800.yaml"), "--out", str(out)],
        out, capsys,
    )  # fmt: skip
    assert "the masks' cells are " in error
    assert "wider than any rod-shaped bacterium (over 3 um)" in error
    assert "pixel size 0.8 um from --microscope" in error
    assert "Check pixel_size_um" in error
    assert "--cell-width-um" in error


def test_calibrate_warns_of_cells_no_bacterium_is_as_wide(colicoords_files, capsys):
    """Found as a user: Omnipose's Sample000193 calibrated at 0.134 um/px (its 1 um cells
    are 0.0745 um/px) exported cells 1.80 um wide unsaid, where Auto-fit on the same image
    warned. Here ColiCoords' cells at 1.5 times their pixel size: exported, and warned in
    report.txt and last on stderr; at their own pixel size, no warning."""
    d = colicoords_files
    (d / "m120.yaml").write_text("pixel_size_um: 0.12\nmodality: fluorescence\n")
    out = d / "out"
    code = main(
        ["calibrate", str(d / "flu.tif"), "--masks", str(d / "mask.tif"), "--microscope",
         str(d / "m120.yaml"), "--out", str(out), "--n-items", "1"]
    )  # fmt: skip
    printed = capsys.readouterr()
    assert code == 0, printed.err
    warning = printed.err.strip().splitlines()[-1]
    assert warning.startswith("napari-symbac calibrate: warning: the dataset's cells are ")
    assert "unusual for bacteria (0.4-1.6 um): check the pixel size" in warning
    assert "--cell-width-um" in warning
    report = (out / "report.txt").read_text()
    assert "\nWARNINGS\n- the dataset's cells are " in report
    width = float(warning.split("cells are ")[1].split(" um")[0])
    assert width > 1.6
    code = main(
        ["calibrate", str(d / "flu.tif"), "--masks", str(d / "mask.tif"), "--microscope",
         str(d / "m80.yaml"), "--modality", "fluorescence", "--out", str(d / "own"),
         "--n-items", "1"]
    )  # fmt: skip
    printed = capsys.readouterr()
    assert code == 0, printed.err
    assert "warning" not in printed.err
    assert "WARNINGS" not in (d / "own" / "report.txt").read_text()


def test_calibrate_fits_and_draws_a_stain_in_the_envelope(real_data_dir, tmp_path, capsys):
    """A membrane-stained field (ColiCoords ds2, two cells of 00074) calibrated with
    ``--envelope-stain``: the fit puts the stain in the envelope, the cells come out an
    E. coli's width (volume-stained they are ~1.5 um), and the dataset draws it."""
    ds2 = real_data_dir / "colicoords" / "test_data" / "ds2"
    image = tmp_path / "flu.tif"
    tifffile.imwrite(image, tifffile.imread(ds2 / "fluorescence" / "00074.tif")[60:220, 352:512])
    (tmp_path / "m80.yaml").write_text("pixel_size_um: 0.08\nwavelength_um: 0.53\n")
    out = tmp_path / "out"
    code = main(
        ["calibrate", str(image), "--microscope", str(tmp_path / "m80.yaml"), "--modality",
         "fluorescence", "--envelope-stain", "--out", str(out), "--n-items", "1"]
    )  # fmt: skip
    printed = capsys.readouterr()
    assert code == 0, printed.err
    report = (out / "report.txt").read_text()
    fraction = float(report.split("stain in the envelope ")[1].split(" of it")[0])
    assert fraction > 0.8, report
    width = float(report.split("cells: width ")[1].split(" um")[0])
    assert 0.9 < width < 1.25, report
    settings = yaml.safe_load((out / "export_settings.yaml").read_text())
    assert settings["pipeline"]["render"]["envelope_stain_fraction"] == pytest.approx(
        fraction, abs=0.005
    )


@pytest.mark.parametrize(
    ("flags", "said"),
    [(["--envelope-stain"], "leave --envelope-stain out"),
     (["--depth-layers", "5"], "leave --depth-layers out")],
)  # fmt: skip
def test_calibrate_refuses_a_stain_model_in_bright_field(
    real_data_dir, tmp_path, capsys, flags, said
):
    ds1 = real_data_dir / "colicoords" / "test_data" / "ds1"
    (tmp_path / "m80.yaml").write_text("pixel_size_um: 0.08\n")
    out = tmp_path / "out"
    line = _refused(
        ["calibrate", str(ds1 / "brightfield" / "00001.tif"), "--microscope",
         str(tmp_path / "m80.yaml"), "--modality", "brightfield", "--out", str(out), *flags],
        out, capsys,
    )  # fmt: skip
    assert said in line
