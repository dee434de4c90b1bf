"""The ``napari-symbac`` command, as a user runs it."""

from __future__ import annotations

import json
import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import tifffile

from napari_symbac.cli import build_parser, main

COMMANDS = [
    "demo", "simulate", "render", "fit", "calibrate", "diagnose", "export", "bench", "defaults"
]  # fmt: skip


def test_top_level_help_lists_every_command():
    text = build_parser().format_help()
    assert all(command in text for command in COMMANDS)


@pytest.mark.parametrize("command", COMMANDS)
def test_every_command_has_help(command, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main([command, "--help"])
    assert exit_info.value.code == 0
    text = capsys.readouterr().out
    assert "usage: napari-symbac" in text
    # the help ends with examples, one command a line, each one the parser takes
    examples = text.split("\nexamples:\n")[1].splitlines()
    commands = [
        part.partition("#")[0].strip()
        for line in examples
        for part in line.split("&&")
        if part.strip().startswith("napari-symbac")
    ]
    assert any(c.startswith(f"napari-symbac {command}") for c in commands), examples
    for example in commands:
        build_parser().parse_args(shlex.split(example)[1:])  # exits 2 on a usage error


@pytest.mark.parametrize("command", ["fit", "diagnose"])
def test_fit_and_diagnose_take_the_same_geometry_words(command):
    """Found as a user: `diagnose --geometry open` ran, `fit --geometry open` was a usage
    error; both now take 'open' (the Python API's word) as 'field', and nothing else."""
    parser = build_parser()
    base = [command, "image.tif", "--microscope", "m.yaml", "--out", "out"]
    assert parser.parse_args([*base, "--geometry", "open"]).geometry == "field"
    assert parser.parse_args([*base, "--geometry", "trench"]).geometry == "trench"
    with pytest.raises(SystemExit):
        parser.parse_args([*base, "--geometry", "pad"])


@pytest.mark.parametrize("command", ["fit", "diagnose", "calibrate"])
def test_a_pixel_size_the_files_disagree_on_is_settled_by_the_flag(command, tmp_path, capsys):
    """Found as a user: the TIFF's pixel size always won over --microscope, so a TIFF
    saved with a 1 um scale (none set) was fitted at 1 um per pixel; the three commands
    that fit a recording now refuse the disagreement and take --pixel-size-um."""
    image = tmp_path / "scaled.tif"
    pixels = np.random.default_rng(0).poisson(500, (64, 32)).astype(np.uint16)
    tifffile.imwrite(image, pixels, imagej=True, resolution=(1.0, 1.0), metadata={"unit": "um"})
    mic = tmp_path / "mic.yaml"
    mic.write_text("pixel_size_um: 0.065\nmodality: phase\n")
    base = [command, str(image), "--microscope", str(mic), "--out", str(tmp_path / "o")]
    assert main(base) == 2
    assert capsys.readouterr().err.splitlines()[-1] == (
        f"napari-symbac {command}: error: the image file records a pixel size of 1 um (1 um "
        "per pixel is often a scale that was never set) and --microscope 0.065 um: say which "
        "is right with --pixel-size-um 0.065 (or 1), or correct the file that is wrong"
    )
    assert main([*base, "--pixel-size-um", "6.5"]) == 2  # a camera pixel: refused too
    assert "pixel size 6.5 um (from --pixel-size-um) is outside" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("command", ["fit", "diagnose", "calibrate"])
def test_without_a_microscope_file_the_pixel_size_is_asked_for(command, tmp_path, capsys):
    """Found as a user: --pixel-size-um given, and still "the following arguments are
    required: --microscope". The file is optional: without it the default optics, said
    in a note, and a pixel size from the image or --pixel-size-um."""
    image = tmp_path / "bare.tif"
    tifffile.imwrite(image, np.random.default_rng(0).poisson(500, (64, 32)).astype(np.uint16))
    assert main([command, str(image), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "neither the image nor --microscope gives the pixel size: pass --pixel-size-um" in err
    assert not (tmp_path / "o").exists()


def test_fit_without_a_microscope_file_says_which_optics_it_took(tmp_path, real_data_dir, capsys):
    image = tmp_path / "trench.tif"
    trench = tifffile.imread(real_data_dir / "ecoli_100x_oil_exponential.tiff")[:96]
    tifffile.imwrite(image, trench)
    out = tmp_path / "fit"
    args = ["fit", str(image), "--pixel-size-um", "0.065", "--max-iterations", "1"]
    assert main([*args, "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "note: no --microscope: the default optics (NA 1.45, wavelength 0.65 um" in err
    assert "pixel size 0.065 um from --pixel-size-um" in (out / "report.txt").read_text()


def test_console_script_is_installed():
    result = subprocess.run(
        [Path(sys.executable).with_name("napari-symbac"), "--version"],
        capture_output=True,
        text=True,
        check=True,
    )
    assert result.stdout.startswith("napari-symbac ")


@pytest.fixture(scope="module")
def demo_dirs(tmp_path_factory):
    """The demo run twice with one seed, once with another."""
    root = tmp_path_factory.mktemp("demo")
    for name, seed in (("a", 5), ("b", 5), ("c", 6)):
        assert main(["demo", "--out", str(root / name), "--frames", "8", "--seed", str(seed)]) == 0
    return root


def _dataset_files(folder: Path) -> dict[str, bytes]:
    return {
        str(path.relative_to(folder)): path.read_bytes()
        for path in sorted(folder.rglob("*"))
        if path.is_file() and path.suffix in {".tif", ".tiff", ".txt", ".png", ".npz"}
    }


def test_demo_writes_what_it_reports(demo_dirs, capsys):
    out = demo_dirs / "a"
    for name in ("settings.yaml", "preview.png", "simulation", "dataset"):
        assert (out / name).exists(), name
    main(["demo", "--out", str(demo_dirs / "again"), "--frames", "3"])
    report = capsys.readouterr().out
    for step in ("simulate", "render", "write dataset", "total"):
        assert step in report


def test_demo_masks_match_rendered_cells(demo_dirs):
    images = sorted((demo_dirs / "a" / "dataset" / "tiff" / "train" / "images").glob("*.tif"))
    masks = sorted((demo_dirs / "a" / "dataset" / "tiff" / "train" / "labels").glob("*.tif"))
    assert len(images) == len(masks) == 8
    for image_path, mask_path in zip(images, masks):
        image = tifffile.imread(image_path).astype(float)
        mask = tifffile.imread(mask_path)
        assert image.shape == mask.shape
        assert mask.dtype in (np.uint16, np.uint32)
        trench_columns = slice(mask.shape[1] // 2 - 3, mask.shape[1] // 2 + 4)
        trench = np.zeros(mask.shape, bool)
        trench[20:, trench_columns] = True  # below the closed-end margin
        background = trench & (mask == 0)
        for cell_id in np.unique(mask)[1:]:
            inside = image[mask == cell_id]
            # Every labelled cell is darker than the media around it (phase contrast).
            if background.any():
                assert inside.mean() < image[background].mean()


def test_same_seed_same_bytes(demo_dirs):
    first = _dataset_files(demo_dirs / "a")
    second = _dataset_files(demo_dirs / "b")
    other = _dataset_files(demo_dirs / "c")
    assert first
    assert first.keys() == second.keys()
    assert all(first[name] == second[name] for name in first)
    assert any(first[name] != other.get(name) for name in first)


def test_demo_again_with_other_settings_is_refused(demo_dirs, capsys):
    """Found as a user: `demo --seed 3` into the README's seed-0 demo folder replaced
    its settings, simulation and preview and kept the seed-0 dataset ("0 written, 40
    already there"), exit 0. The folder is refused, untouched, naming what differs."""
    folder = demo_dirs / "a"
    before = _dataset_files(folder)
    settings = (folder / "settings.yaml").read_text()
    capsys.readouterr()
    assert main(["demo", "--out", str(folder), "--frames", "8", "--seed", "7"]) == 2
    error = capsys.readouterr().err
    assert "holds a demo made with other settings (simulation.seed: 5 there, 7 here)" in error
    assert "give another --out" in error
    assert (folder / "settings.yaml").read_text() == settings
    assert _dataset_files(folder) == before


def test_a_reader_that_stops_reading_ends_the_command_quietly(tmp_path):
    """Found as a user: `napari-symbac demo | head -3` ended with "error: Broken pipe:
    the path given; check that the path is right", of a demo that had finished. It ends
    as a shell's tools do when their reader goes: no message, status 141."""
    out = tmp_path / "demo"
    command = ["demo", "--out", str(out), "--frames", "2"]
    code = f"import sys; from napari_symbac.cli import main; sys.exit(main({command!r}))"
    process = subprocess.Popen(
        [sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    process.stdout.close()  # the reader is gone before the report is printed
    error = process.stderr.read().decode()
    assert process.wait(timeout=300) == 141, error
    assert "error" not in error, error
    assert "Traceback" not in error, error
    assert (out / "settings.yaml").is_file()
    assert (out / "preview.png").is_file()


def test_render_refuses_fluorescence_with_dark_cells_as_export_does(tmp_path, capsys):
    """Found as a user: a pipeline set to fluorescence kept phase-contrast intensities;
    export refused it, render drew dark cells on a bright background and exited 0."""
    import dataclasses

    from napari_symbac.settings import Microscope, PipelineSettings, save_settings

    assert main(["simulate", "--out", str(tmp_path / "sim"), "--frames", "2", "--seed", "1"]) == 0
    pipeline = PipelineSettings(microscope=Microscope(modality="fluorescence"))
    config = save_settings(pipeline, tmp_path / "pipeline.yaml")
    capsys.readouterr()
    out = tmp_path / "render"
    assert main(["render", str(tmp_path / "sim"), "--config", str(config), "--out", str(out)]) == 2
    error = capsys.readouterr().err
    assert "fluorescence but its cells are not brighter than the medium" in error
    assert "Traceback" not in error
    assert not out.exists()
    render = dataclasses.replace(pipeline.render, cell_intensity=3000.0, media_intensity=150.0)
    bright = dataclasses.replace(pipeline, render=render)
    config = save_settings(bright, tmp_path / "bright.yaml")
    assert main(["render", str(tmp_path / "sim"), "--config", str(config), "--out", str(out)]) == 0
    images, labels = (tifffile.imread(out / f"{name}.tif") for name in ("images", "labels"))
    assert images[labels > 0].mean() > images[labels == 0].mean()


def test_bad_config_is_one_clear_line(tmp_path, capsys):
    config = tmp_path / "sim.yaml"
    config.write_text("n_frames: 10\ncell_width_um: 3.0\n")
    assert main(["simulate", "--config", str(config), "--out", str(tmp_path / "out")]) == 2
    error = capsys.readouterr().err
    assert "does not fit in a trench" in error
    assert "Traceback" not in error
    assert not (tmp_path / "out").exists()


def test_simulate_then_render(tmp_path, capsys):
    assert main(["simulate", "--out", str(tmp_path / "sim"), "--frames", "4", "--seed", "1"]) == 0
    assert main(["render", str(tmp_path / "sim"), "--out", str(tmp_path / "render")]) == 0
    err = capsys.readouterr().err
    assert "replaced" not in err
    # found as a user: a fitted field's simulation rendered as the built-in microscope,
    # unsaid
    assert "note: no --config: the built-in microscope renders it (phase, 0.065 um/px)" in err
    images = tifffile.imread(tmp_path / "render" / "images.tif")
    labels = tifffile.imread(tmp_path / "render" / "labels.tif")
    assert images.shape == labels.shape
    assert images.shape[0] == 4
    assert labels.dtype == np.uint32
    for name in ("images", "labels", "semantic"):  # frames, rows, columns for tifffile
        with tifffile.TiffFile(tmp_path / "render" / f"{name}.tif") as tif:
            assert tif.series[0].axes == "TYX", name
    # rendered again into the same folder: the earlier files are replaced, and it says so
    assert main(["render", str(tmp_path / "sim"), "--out", str(tmp_path / "render")]) == 0
    assert "replaced the images.tif, labels.tif, semantic.tif" in capsys.readouterr().err
    # simulated again into the same folder: said as render says it (found as a user)
    assert main(["simulate", "--out", str(tmp_path / "sim"), "--frames", "3", "--seed", "1"]) == 0
    assert f"replaced the simulation that {tmp_path / 'sim'} held" in capsys.readouterr().err
    # ... and what it held beside it, renders of the earlier simulation, is named as
    # removed (found as a user: images.tif, labels.tif and semantic.tif went unsaid)
    assert main(["render", str(tmp_path / "sim"), "--out", str(tmp_path / "sim")]) == 0
    capsys.readouterr()
    assert main(["simulate", "--out", str(tmp_path / "sim"), "--frames", "2", "--seed", "1"]) == 0
    assert (
        "held, and removed what it held beside it (images.tif, labels.tif, semantic.tif)"
        in capsys.readouterr().err
    )


def test_simulate_takes_the_simulation_of_a_pipeline_file(tmp_path, capsys):
    """Found as a user: `simulate --config` with the settings.yaml that `fit` wrote (a
    pipeline file) refused its camera, microscope and render sections."""
    from napari_symbac.settings import PipelineSettings, SimulationSettings, save_settings
    from napari_symbac.sim.io import load_simulation

    simulation = SimulationSettings(n_frames=3, seed=4, geometry="agar_pad")
    config = save_settings(PipelineSettings(simulation=simulation), tmp_path / "settings.yaml")
    assert main(["simulate", "--config", str(config), "--out", str(tmp_path / "sim")]) == 0
    saved = load_simulation(tmp_path / "sim")
    assert saved.settings.geometry == "agar_pad"
    assert len(saved.frames) == 3
    # a field the simulation does not know is still refused, naming the section
    config.write_text("simulation:\n  n_frame: 3\n")
    assert main(["simulate", "--config", str(config), "--out", str(tmp_path / "x")]) == 2
    assert "n_frame" in capsys.readouterr().err


def test_defaults_round_trip(tmp_path):
    from napari_symbac.settings import PipelineSettings, load_settings

    path = tmp_path / "pipeline.yaml"
    assert main(["defaults", "pipeline", "--out", str(path)]) == 0
    assert load_settings(path, PipelineSettings) == PipelineSettings()


def test_defaults_never_replaces_an_edited_file(tmp_path, capsys):
    """Found as a user: running the README's `defaults microscope --out microscope.yaml`
    again (the line is pasted with the rest) silently replaced the pixel size entered in
    the file with 0.065 um."""
    path = tmp_path / "microscope.yaml"
    assert main(["defaults", "microscope", "--out", str(path)]) == 0
    assert main(["defaults", "microscope", "--out", str(path)]) == 0  # the same: harmless
    edited = path.read_text().replace("pixel_size_um: 0.065", "pixel_size_um: 0.08")
    path.write_text(edited)
    capsys.readouterr()
    assert main(["defaults", "microscope", "--out", str(path)]) == 2
    error = capsys.readouterr().err
    assert "exists and is not the default microscope settings" in error
    assert "--force" in error
    assert path.read_text() == edited
    assert main(["defaults", "microscope", "--out", str(path), "--force"]) == 0
    assert "pixel_size_um: 0.065" in path.read_text()


@pytest.mark.parametrize(
    "kind", ["export", "pipeline", "simulation", "microscope", "render", "camera"]
)
def test_defaults_again_on_an_untouched_file_is_harmless(tmp_path, kind):
    """Found as a user: a second `defaults export --out export.yaml` (and pipeline,
    simulation) called the untouched file "your edits": its empty lists read back from
    YAML were compared with the defaults' empty tuples."""
    path = tmp_path / f"{kind}.yaml"
    assert main(["defaults", kind, "--out", str(path)]) == 0
    written = path.read_text()
    assert main(["defaults", kind, "--out", str(path)]) == 0
    assert path.read_text() == written


def test_fit_refusal_from_the_shell_is_a_message_not_a_traceback(tmp_path):
    """The console script as a user pipes it: message, exit 2, nothing written."""
    image = tmp_path / "negative.tif"
    tifffile.imwrite(image, np.full((32, 32), -5.0, np.float32))
    microscope = tmp_path / "microscope.yaml"
    microscope.write_text("pixel_size_um: 0.065\n")
    out = tmp_path / "out"
    command = [Path(sys.executable).with_name("napari-symbac"), "fit", str(image)]
    command += ["--microscope", str(microscope), "--out", str(out)]
    result = subprocess.run(
        command,
        capture_output=True,
        text=True,
    )
    assert result.returncode == 2
    assert "napari-symbac fit: loading inputs" in result.stderr  # one line per stage, piped
    assert "has negative values" in result.stderr
    assert "Traceback" not in result.stderr
    assert not out.exists()


def test_render_and_export_on_the_torch_backend(tmp_path, capsys):
    import torch
    import yaml

    from napari_symbac import cli
    from napari_symbac.optics import batched

    assert cli._BACKENDS == batched.BACKENDS
    assert cli._DEVICES == batched.DEVICES
    assert main(["simulate", "--out", str(tmp_path / "sim"), "--frames", "4", "--seed", "1"]) == 0
    assert main(["render", str(tmp_path / "sim"), "--out", str(tmp_path / "cpu")]) == 0
    args = ["render", str(tmp_path / "sim"), "--out", str(tmp_path / "dev"), "--backend", "torch"]
    assert main([*args, "--device", "cpu"]) == 0
    assert "render (torch:cpu)" in capsys.readouterr().out
    cpu = tifffile.imread(tmp_path / "cpu" / "images.tif").astype(float)
    dev = tifffile.imread(tmp_path / "dev" / "images.tif").astype(float)
    assert dev.shape == cpu.shape
    np.testing.assert_array_equal(
        tifffile.imread(tmp_path / "dev" / "labels.tif"),
        tifffile.imread(tmp_path / "cpu" / "labels.tif"),
    )
    # other noise stream, same image: the frame means agree to a fraction of the noise
    assert not np.array_equal(dev, cpu)
    np.testing.assert_allclose(dev.mean(axis=(1, 2)), cpu.mean(axis=(1, 2)), rtol=2e-3)
    # bad choices: a message, exit 2, no traceback, nothing written
    if not torch.cuda.is_available():
        assert main([*args, "--device", "cuda"]) == 2
        assert "sees no CUDA GPU" in capsys.readouterr().err
    out = ["--out", str(tmp_path / "x")]
    assert main(["render", str(tmp_path / "sim"), *out, "--device", "cpu"]) == 2
    error = capsys.readouterr().err
    assert "torch backend only" in error
    assert "Traceback" not in error
    assert not (tmp_path / "x").exists()
    # a stage the device cannot run is refused by name, pointing at scipy
    coherent = tmp_path / "coherent.yaml"
    coherent.write_text(yaml.safe_dump({"render": {"phase_model": "partially_coherent"}}))
    bad = ["render", str(tmp_path / "sim"), "--out", str(tmp_path / "y"), "--backend", "torch"]
    assert main([*bad, "--device", "cpu", "--config", str(coherent)]) == 2
    error = capsys.readouterr().err
    assert "'phase_image' stage cannot run on the torch device" in error
    assert "--backend scipy" in error
    assert "Traceback" not in error
    config = tmp_path / "export.yaml"
    config.write_text(
        yaml.safe_dump(
            {"n_items": 1, "kind": "timeseries", "pipeline": {"simulation": {"n_frames": 4}}}
        )
    )
    export = ["export", "--config", str(config), "--out", str(tmp_path / "ds"), "--workers", "1"]
    assert main([*export, "--backend", "torch", "--device", "cpu"]) == 0
    manifest = json.loads((tmp_path / "ds" / "manifest.json").read_text())
    assert manifest["render_backend"] == "torch:cpu"
    assert manifest["status"] == "complete"
    assert len(manifest["items"]) == 4
    # resuming with another backend would mix noise streams: refused
    assert main(export) == 2
    assert "rendered with the torch:cpu backend" in capsys.readouterr().err
    # the manifest's backend makes regenerate give the exported bytes back
    from napari_symbac.export import regenerate

    entry = manifest["items"][2]
    item = regenerate(tmp_path / "ds", entry["name"])
    stored = tifffile.imread(tmp_path / "ds" / entry["files"]["tiff"][0])
    np.testing.assert_array_equal(item.image, stored)


def test_an_export_the_device_cannot_draw_is_refused_before_its_folder(tmp_path, capsys):
    """Found as a user: `export --backend torch` of settings with a diagnosed stage the
    device cannot run (here uneven illumination) was refused after manifest.json was
    written with the torch backend in it, so the `--backend scipy` run that the message
    asks for was refused in turn ("rendered with the torch:cpu backend"). Now nothing is
    written, and the scipy run goes through."""
    import yaml

    config = tmp_path / "export.yaml"
    config.write_text(yaml.safe_dump({
        "n_items": 2,
        "pipeline": {
            "simulation": {"n_frames": 4},
            "extra_stages": [{"name": "uneven_illumination",
                              "parameters": {"coefficients": [0.0, 0.1, 0.0, 0.0, 0.0]}}],
        },
    }))  # fmt: skip
    out = tmp_path / "ds"
    export = ["export", "--config", str(config), "--out", str(out), "--workers", "1"]
    assert main([*export, "--backend", "torch", "--device", "cpu"]) == 2
    error = capsys.readouterr().err
    assert "'uneven_illumination' stage cannot run on the torch device" in error
    assert "--backend scipy" in error
    assert not out.exists()
    assert main(export) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["status"] == "complete"
    assert "render_backend" not in manifest


def test_render_and_export_depth_resolved_fluorescence_on_torch(tmp_path, capsys):
    """Settings with render.depth_layers > 0 (as `fit --depth-layers 5` writes them) were
    refused by --backend torch ("'depth' stage cannot run on the torch device"); the
    device now images the slabs: the same images as scipy's but for the noise stream."""
    import yaml

    assert main(["simulate", "--out", str(tmp_path / "sim"), "--frames", "3", "--seed", "1"]) == 0
    pipeline = {
        "microscope": {"modality": "fluorescence"},
        "render": {
            "depth_layers": 5,
            "focus_offset_um": 0.2,
            "envelope_stain_fraction": 0.5,
            "cell_intensity": 3000.0,
            "media_intensity": 150.0,
            "device_intensity": 100.0,
        },
    }
    config = tmp_path / "depth.yaml"
    config.write_text(yaml.safe_dump(pipeline))
    render = ["render", str(tmp_path / "sim"), "--config", str(config), "--out"]
    assert main([*render, str(tmp_path / "cpu")]) == 0
    capsys.readouterr()
    assert main([*render, str(tmp_path / "dev"), "--backend", "torch", "--device", "cpu"]) == 0
    captured = capsys.readouterr()
    assert "render (torch:cpu)" in captured.out
    assert "Traceback" not in captured.err
    cpu = tifffile.imread(tmp_path / "cpu" / "images.tif").astype(float)
    dev = tifffile.imread(tmp_path / "dev" / "images.tif").astype(float)
    assert dev.shape == cpu.shape == (3, *dev.shape[1:])
    assert not np.array_equal(dev, cpu)  # another noise stream
    np.testing.assert_allclose(dev.mean(axis=(1, 2)), cpu.mean(axis=(1, 2)), rtol=5e-3)
    export_config = tmp_path / "export.yaml"
    export_config.write_text(
        yaml.safe_dump(
            {
                "n_items": 1,
                "kind": "timeseries",
                "pipeline": {**pipeline, "simulation": {"n_frames": 3}},
            }
        )
    )
    export = ["export", "--config", str(export_config), "--out", str(tmp_path / "ds")]
    assert main([*export, "--workers", "1", "--backend", "torch", "--device", "cpu"]) == 0
    manifest = json.loads((tmp_path / "ds" / "manifest.json").read_text())
    assert manifest["render_backend"] == "torch:cpu"
    assert manifest["status"] == "complete"
    assert len(manifest["items"]) == 3


def test_progress_is_lines_when_piped(capsys):
    """A long `diagnose` sent to a log file said nothing for 10 minutes (tqdm is silent
    off a terminal): piped, progress is a line when the count moves, at most every
    PIPED_PROGRESS_INTERVAL_S, and always the last step."""
    from napari_symbac import cli

    update, handle = cli._tqdm_progress("diagnose", unit="held-out checks")
    update(0, 3)  # nothing done yet: no line
    update(1, 3)
    update(2, 3)  # within the interval of the line before: none
    update(3, 3)  # the last: always
    handle.close()
    err = capsys.readouterr().err
    assert err.splitlines() == [
        "napari-symbac diagnose: 1 of 3 held-out checks",
        "napari-symbac diagnose: 3 of 3 held-out checks",
    ]


def test_progress_of_a_shrinking_total_says_at_most(capsys):
    """Found as a user: `diagnose`'s total is the most held-out checks still possible,
    and its lines read "1 of 12", then "6 of 6"; they say "of at most" now."""
    from napari_symbac import cli

    update, handle = cli._tqdm_progress("diagnose", unit="held-out checks", bound=True)
    update(1, 12)
    update(6, 6)
    handle.close()
    assert capsys.readouterr().err.splitlines() == [
        "napari-symbac diagnose: 1 of at most 12 held-out checks",
        "napari-symbac diagnose: 6 of at most 6 held-out checks",
    ]


def test_render_refuses_a_simulation_file_as_its_config_in_one_line(tmp_path, capsys):
    """Found as a user: `render --config sim.yaml` listed 26 fields as unknown."""
    from napari_symbac.settings import SimulationSettings, save_settings

    assert main(["simulate", "--out", str(tmp_path / "sim"), "--frames", "2"]) == 0
    config = save_settings(SimulationSettings(n_frames=2), tmp_path / "sim.yaml")
    capsys.readouterr()
    out = tmp_path / "r"
    code = main(["render", str(tmp_path / "sim"), "--config", str(config), "--out", str(out)])
    error = capsys.readouterr().err
    assert code == 2
    assert "holds simulation settings only" in error
    assert "napari-symbac defaults pipeline" in error
    assert "unknown field" not in error
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("command", ["simulate", "export"])
def test_a_microscope_file_as_config_is_refused_in_one_line(tmp_path, capsys, command):
    """Found as a user: `simulate --config microscope.yaml` (the file `fit` takes) said
    "unknown field(s) condenser, magnification, ... in SimulationSettings; valid fields
    are: ..." (26 of them), without naming the file or the kind of file wanted; `export`
    said the same of ExportSettings. `render` already said it in one line."""
    from napari_symbac.settings import Microscope, save_settings

    config = save_settings(Microscope(), tmp_path / "microscope.yaml")
    out = tmp_path / "out"
    code = main([command, "--config", str(config), "--out", str(out)])
    error = capsys.readouterr().err
    assert code == 2
    assert str(config) in error
    assert "holds microscope settings" in error
    kind = {"simulate": "simulation", "export": "export"}[command]
    assert f"napari-symbac defaults {kind}" in error
    assert "unknown field" not in error
    assert not out.exists()


def test_simulate_and_render_take_the_pipeline_of_an_export_file(tmp_path, capsys):
    """Found as a user: simulate's help and the README say calibrate's settings are
    reused, and simulate and render refused its export_settings.yaml as export
    settings. Its pipeline: section is their settings."""
    from napari_symbac.export import ExportSettings
    from napari_symbac.settings import Microscope, PipelineSettings, SimulationSettings
    from napari_symbac.settings import save_settings as save

    pipeline = PipelineSettings(
        simulation=SimulationSettings(n_frames=3, seed=4), microscope=Microscope(pixel_size_um=0.1)
    )
    config = save(ExportSettings(n_items=2, pipeline=pipeline), tmp_path / "export_settings.yaml")
    assert main(["simulate", "--config", str(config), "--out", str(tmp_path / "sim")]) == 0
    assert main(["render", str(tmp_path / "sim"), "--config", str(config),
                 "--out", str(tmp_path / "r")]) == 0  # fmt: skip
    images = tifffile.imread(tmp_path / "r" / "images.tif")
    assert images.shape[0] == 3  # the export's pipeline's simulation
    with tifffile.TiffFile(tmp_path / "r" / "images.tif") as tif:
        assert tif.imagej_metadata is not None
    default = tmp_path / "d"
    assert main(["render", str(tmp_path / "sim"), "--out", str(default)]) == 0
    assert tifffile.imread(default / "images.tif").shape[1] > images.shape[1]  # 0.065 um px


@pytest.mark.parametrize(
    ("argv", "held", "wanted"),
    [
        (["fit", "IMAGE", "--microscope", "SIM"], "holds simulation settings", "microscope"),
        (["fit", "IMAGE", "--microscope", "PIPE"], "is a pipeline file", "microscope"),
        (["diagnose", "IMAGE", "--microscope", "SIM"], "holds simulation settings", "microscope"),
        (["diagnose", "IMAGE", "--microscope", "PIPE"], "is a pipeline file", "microscope"),
        (["calibrate", "IMAGE", "--microscope", "EXPORT"], "holds export settings", "microscope"),
        (["export", "--config", "SIM"], "holds simulation settings", "export"),
        (["fit", "IMAGE", "--microscope", "MIC", "--camera", "MIC"], "holds microscope", "camera"),
        (["fit", "IMAGE", "--microscope", "MIC", "--camera", "PIPE"], "is a pipeline", "camera"),
    ],
)
def test_a_settings_file_of_another_kind_is_refused_in_one_line(
    tmp_path, capsys, argv, held, wanted
):
    """Found as a user: `fit --microscope settings.yaml` (the pipeline file fit itself
    writes), `diagnose --microscope sim.yaml`, `calibrate --microscope export.yaml`,
    `fit --camera microscope.yaml` listed every
    field of the file as unknown (26 for a simulation file), and `export --config
    sim.yaml` did too, since `seed` is a field of both kinds. Now one line names the
    file, its kind and the kind wanted."""
    from napari_symbac.export import ExportSettings
    from napari_symbac.settings import (
        Microscope,
        PipelineSettings,
        SimulationSettings,
        save_settings,
    )

    files = {
        "SIM": save_settings(SimulationSettings(n_frames=2), tmp_path / "sim.yaml"),
        "PIPE": save_settings(PipelineSettings(), tmp_path / "settings.yaml"),
        "EXPORT": save_settings(ExportSettings(n_items=2), tmp_path / "export.yaml"),
        "MIC": save_settings(Microscope(pixel_size_um=0.08), tmp_path / "microscope.yaml"),
    }
    image = tmp_path / "frame.tif"
    tifffile.imwrite(image, np.random.default_rng(0).integers(900, 1100, (64, 64), np.uint16))
    files["IMAGE"] = image
    files["SIMDIR"] = tmp_path / "sim"
    if "SIMDIR" in argv:
        assert main(["simulate", "--out", str(tmp_path / "sim"), "--frames", "2"]) == 0
    capsys.readouterr()
    out = tmp_path / "out"
    code = main([str(files.get(a, a)) for a in argv] + ["--out", str(out)])
    error = capsys.readouterr().err
    assert code == 2
    line = error.strip().splitlines()[-1]
    assert held in line
    assert str(files[argv[-1]]) in line
    assert f"napari-symbac defaults {wanted} --out FILE" in line
    assert "unknown field" not in error
    assert "Traceback" not in error
    assert not out.exists()


def test_a_typo_in_a_simulation_file_names_the_file(tmp_path, capsys):
    """`simulate --config` with a misspelt field: the message names the file, as every
    other command's settings errors do."""
    config = tmp_path / "sim.yaml"
    config.write_text("n_frame: 4\n")
    code = main(["simulate", "--config", str(config), "--out", str(tmp_path / "s")])
    error = capsys.readouterr().err
    assert code == 2
    assert str(config) in error
    assert "n_frame" in error


def test_an_unknown_option_is_said_by_its_command(tmp_path, capsys):
    """Found as a user: `diagnose IMAGE ... --frames 3` (then an option of fit's alone)
    said "napari-symbac: error: unrecognized arguments: --frames 3 (see napari-symbac
    --help)":
    neither the command nor its help, where the options are. A misspelt option is also
    given its nearest spelling."""
    out = str(tmp_path / "d")
    with pytest.raises(SystemExit) as refused:
        main(["diagnose", "image.tif", "--microscope", "m.yaml", "--out", out, "--dark", "d.tif"])
    assert refused.value.code == 2
    error = capsys.readouterr().err
    assert error == (  # fit's --dark, which diagnose has not
        "napari-symbac diagnose: error: unrecognized arguments: --dark d.tif "
        "(see napari-symbac diagnose --help)\n"
    )
    with pytest.raises(SystemExit):
        main(["fit", "image.tif", "--microscope", "m.yaml", "--out", out, "--modalty", "phase"])
    error = capsys.readouterr().err
    assert error.startswith("napari-symbac fit: error: unrecognized arguments: --modalty phase")
    assert "did you mean --modality?" in error
    assert not (tmp_path / "d").exists()


def test_export_of_a_pipeline_file_takes_n_items(tmp_path, capsys):
    """Found as a user: exporting fit's settings.yaml made the default 100 items, and
    only a hand-written export file could ask for fewer."""
    from napari_symbac.settings import PipelineSettings, SimulationSettings, save_settings

    pipeline = PipelineSettings(simulation=SimulationSettings(n_frames=4, seed=2))
    config = save_settings(pipeline, tmp_path / "settings.yaml")
    out = tmp_path / "ds"
    args = ["export", "--config", str(config), "--out", str(out), "--workers", "1"]
    assert main([*args, "--n-items", "3"]) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["status"] == "complete"
    assert len(manifest["items"]) == 3
    assert manifest["settings"]["n_items"] == 3
    capsys.readouterr()
    with pytest.raises(SystemExit) as refused:  # argparse's usage error
        main([*args, "--n-items", "0"])
    assert refused.value.code == 2
    error = capsys.readouterr().err
    assert error == (  # one line, not the usage block first
        "napari-symbac export: error: argument --n-items: must be at least 1, got 0 "
        "(see napari-symbac export --help)\n"
    )


def test_export_takes_formats_instead_of_the_configs(tmp_path, capsys):
    """Found as a user: a fit's settings.yaml exports only its default formats, and
    COCO or Omnipose needed a hand-written export file."""
    from pycocotools.coco import COCO

    from napari_symbac.settings import PipelineSettings, SimulationSettings, save_settings

    pipeline = PipelineSettings(simulation=SimulationSettings(n_frames=4, seed=2))
    config = save_settings(pipeline, tmp_path / "settings.yaml")
    out = tmp_path / "ds"
    args = ["export", "--config", str(config), "--n-items", "2", "--workers", "1"]
    assert main([*args, "--out", str(out), "--formats", "coco, omnipose"]) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["settings"]["formats"] == ["coco", "omnipose"]
    assert "allowed" not in capsys.readouterr().err  # --workers 1: as asked
    # --workers 2: when fewer were used (a short export stays in this process), it is said
    again = tmp_path / "again"
    assert main([*args[:-2], "--workers", "2", "--out", str(again), "--formats", "tiff"]) == 0
    said = capsys.readouterr()
    used = int(re.search(r"with (\d+) worker\(s\)", said.out).group(1))
    assert ("2 workers allowed (--workers 2), 1 used" in said.err) == (used == 1)
    # more than the cores: the cap and the count used agree (found as a user: "capped
    # to 2", then "--workers 1000 asked, 1 used")
    import os

    many = os.cpu_count() + 6
    third = tmp_path / "third"
    assert main([*args[:-2], "--workers", str(many), "--out", str(third), "--formats", "tiff"]) == 0
    said = capsys.readouterr()
    used = int(re.search(r"with (\d+) worker\(s\)", said.out).group(1))
    assert f"--workers {many} capped to {os.cpu_count()}" in said.err
    if used < os.cpu_count():
        assert f"{os.cpu_count()} workers allowed (--workers {many}), {used} used" in said.err
    assert f"--workers {many} asked" not in said.err
    assert COCO(str(out / "coco" / "annotations" / "instances_train.json")).getAnnIds()
    assert not (out / "tiff").exists()
    capsys.readouterr()
    refused = tmp_path / "refused"
    assert main([*args, "--out", str(refused), "--formats", "coco,cellprofiler"]) == 2
    error = capsys.readouterr().err
    assert "--formats 'coco,cellprofiler'" in error
    assert "unknown format(s) cellprofiler; known formats: tiff, png" in error
    assert not refused.exists()


@pytest.mark.parametrize(
    "argv",
    [
        ["diagnose", "IMAGE", "--microscope", "M", "--seed", "-3"],
        ["calibrate", "IMAGE", "--microscope", "M", "--seed=-4"],
        ["simulate", "--seed", "-1"],
        ["demo", "--seed", "two"],
    ],
)
def test_a_negative_seed_is_a_usage_error_before_any_work(tmp_path, capsys, argv):
    """Found as a user: `diagnose --seed -3` ran its 11 s base fit on the real trench,
    then said "error: expected non-negative integer", naming no option; `calibrate
    --seed -4` refused only after its 25 s fit. Now argparse refuses it at once."""
    image = tmp_path / "frame.tif"
    tifffile.imwrite(image, np.random.default_rng(0).integers(900, 1100, (64, 64), np.uint16))
    microscope = tmp_path / "m.yaml"
    microscope.write_text("pixel_size_um: 0.065\n")
    argv = [{"IMAGE": str(image), "M": str(microscope)}.get(a, a) for a in argv]
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exit_info:
        main([*argv, "--out", str(out)])
    error = capsys.readouterr().err
    assert exit_info.value.code == 2
    assert "argument --seed: must be" in error
    assert len(error.strip().splitlines()) == 1
    assert not out.exists()


def test_the_default_export_file_draws_filled_trenches(tmp_path, capsys):
    """Found as a user following docs/export.md (`defaults export --out export.yaml`,
    then `export --config export.yaml`): the file said first_frame: 0, and the first
    image of the dataset was frame 1 of the simulation, one cell in an empty trench. The
    file is now the default export of the default pipeline (`export.export_of`), whose
    trench images are drawn after the trench has filled, as for a pipeline file."""
    import json

    from napari_symbac.export.dataset import trench_filled_frame
    from napari_symbac.settings import SimulationSettings

    config = tmp_path / "export.yaml"
    assert main(["defaults", "export", "--out", str(config)]) == 0
    out = tmp_path / "dataset"
    code = main(["export", "--config", str(config), "--out", str(out), "--n-items", "8",
                 "--workers", "1"])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    filled = trench_filled_frame(SimulationSettings())
    frames = [
        json.loads(p.read_text())["params"]["frame"]
        for p in sorted((out / "manifest_items").glob("*.json"))
    ]
    assert len(frames) == 8
    assert min(frames) >= filled > 0


@pytest.mark.parametrize("command", ["fit", "calibrate"])
def test_float_masks_are_refused_with_the_fix(tmp_path, capsys, command):
    """Found as a user: masks saved as a float 0/0.7 map got "--masks must hold integer
    cell ids, got float32", which names the problem but not what to do."""
    rng = np.random.default_rng(0)
    image = tmp_path / "field.tif"
    tifffile.imwrite(image, rng.integers(900, 1100, (128, 128), np.uint16))
    masks = np.zeros((128, 128), np.float32)
    masks[40:50, 30:70] = 0.7
    tifffile.imwrite(tmp_path / "masks.tif", masks)
    microscope = tmp_path / "m.yaml"
    microscope.write_text("pixel_size_um: 0.08\nmodality: fluorescence\n")
    out = tmp_path / "out"
    code = main([command, str(image), "--masks", str(tmp_path / "masks.tif"),
                 "--microscope", str(microscope), "--out", str(out)])  # fmt: skip
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert code == 2
    assert "must hold integer cell ids (0 background, 1..N one id per cell), got float32" in error
    assert "skimage.measure.label" in error
    assert not out.exists()


def test_simulate_counts_one_cell_in_the_singular(tmp_path, capsys):
    """Found as a user: `simulate --frames 5` of a fitted trench said "wrote simulation
    of 5 frames, 1 cells"."""
    out = tmp_path / "sim"
    assert main(["simulate", "--frames", "1", "--out", str(out)]) == 0
    assert f"wrote simulation of 1 frame, 1 cell to {out}" in capsys.readouterr().out


def test_render_of_one_frame_writes_three_files_of_one_shape(tmp_path, capsys):
    """Found as a user: `render` of a one-frame simulation (the pad `simulate --config
    fit/settings.yaml` lays out for a fitted field) wrote images.tif and semantic.tif that
    tifffile, scikit-image and napari read as (Y, X), and labels.tif (uint32, not an
    ImageJ file) as (1, Y, X): `images[labels > 0]` failed."""
    import skimage.io

    from napari_symbac.io import read_recording

    sim = tmp_path / "sim"
    assert main(["simulate", "--frames", "1", "--out", str(sim)]) == 0
    out = tmp_path / "render"
    assert main(["render", str(sim), "--out", str(out)]) == 0
    capsys.readouterr()
    shapes = set()
    for name in ("images", "labels", "semantic"):
        path = out / f"{name}.tif"
        shapes |= {tifffile.imread(path).shape, skimage.io.imread(path).shape}
        shapes.add(read_recording(path).data.shape)
    assert len(shapes) == 1
    assert len(shapes.pop()) == 2


def test_export_says_what_the_workers_option_did(tmp_path, capsys, monkeypatch):
    """Found as a user: `--workers 5` beside `--scheduler` was ignored unsaid and then
    "finishes in this process" was printed though the scheduler had done the work; and
    `--workers 8` capped to the cores printed the same note though those cores were used."""
    from napari_symbac.export.cluster import local_cluster
    from napari_symbac.settings import PipelineSettings, SimulationSettings, save_settings

    pipeline = PipelineSettings(simulation=SimulationSettings(n_frames=4, seed=2))
    config = save_settings(pipeline, tmp_path / "settings.yaml")
    args = ["export", "--config", str(config), "--n-items", "3", "--formats", "tiff"]
    with local_cluster(1) as cluster:
        address = cluster.scheduler_address
        assert main([*args, "--out", str(tmp_path / "a"), "--scheduler", address,
                     "--workers", "5"]) == 0  # fmt: skip
    said = capsys.readouterr()
    assert "--workers 5 is not used with --scheduler" in said.err
    assert f"dask worker {address}" in said.err
    assert "asked" not in said.err
    assert "capped" not in said.err
    monkeypatch.setattr("os.cpu_count", lambda: 2)
    monkeypatch.setenv("NAPARI_SYMBAC_CLUSTER_START_S", "0")  # the workers always start
    assert main([*args, "--out", str(tmp_path / "b"), "--workers", "8"]) == 0
    said = capsys.readouterr()
    assert "--workers 8 capped to 2" in said.err
    assert "with 2 worker(s)" in said.out
    assert "asked" not in said.err  # the capped count was used: no "1 used" note
