"""Accepted effects reach the images: ``PipelineSettings.extra_stages`` drawn by render and
export, from settings written by ``napari-symbac diagnose`` on the real trench."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import tifffile
import yaml

from napari_symbac.cli import main
from napari_symbac.diagnose.effects.fixed_pattern_noise import column_basis
from napari_symbac.diagnose.stages import DRAWN, drawn_by_export, updated_settings
from napari_symbac.pipeline import render_simulation
from napari_symbac.settings import (
    ExtraStage,
    PipelineSettings,
    SimulationSettings,
    load_settings,
    save_settings,
)
from napari_symbac.sim import simulate

PHASE_100X = {"modality": "phase", "pixel_size_um": 0.065, "NA": 1.45, "refractive_index": 1.518,
              "wavelength_um": 0.65, "condenser": "Ph3", "objective": "100x oil"}  # fmt: skip
ILLUMINATION = {"coefficients": [0.0, 0.1, 0.0, 0.0, 0.0]}  # 10 % brighter at the bottom


def _quiet(settings: PipelineSettings) -> PipelineSettings:
    """No noise: an image is the rounded clean image plus the baseline."""
    return dataclasses.replace(
        settings, render=dataclasses.replace(settings.render, noise_model="none")
    )


def test_settings_carry_the_drawn_effects_and_refuse_others(tmp_path):
    accepted = [
        ("uneven_illumination", ILLUMINATION),
        ("camera_noise", {"gain_ratio": 1.2, "read_variance_ratio": 1.0}),
        ("stage_drift", {"velocity_x_px_per_frame": 0.1, "velocity_y_px_per_frame": 0.0}),
    ]
    settings, extra = updated_settings(PipelineSettings(), accepted)
    assert settings.extra_stages == (ExtraStage("uneven_illumination", ILLUMINATION),)
    assert [e["name"] for e in extra] == ["uneven_illumination", "stage_drift"]
    path = save_settings(settings, tmp_path / "settings.yaml")
    assert load_settings(path, PipelineSettings) == settings
    hash(settings)  # settings stay usable as keys
    said = drawn_by_export([name for name, _ in accepted])
    assert said.startswith("render and export draw uneven_illumination, camera_noise;")
    assert "they do not draw stage_drift, which changes from frame to frame" in said
    refusals = {
        "stage_drift": "changes from frame to frame",
        "vignette": "not an effect render and export draw as a stage; the stages are",
        "stray_lite": "(did you mean 'stray_light'?)",
        "cell_intensity_variability": "are settings fields, not stages",
        "halo": "lacks 'amplitude_adu'",
    }
    for name, words in refusals.items():
        bad = {"extra_stages": [{"name": name, "parameters": {}}]}
        path.write_text(yaml.safe_dump(bad))
        with pytest.raises(ValueError, match=words) as err:
            load_settings(path, PipelineSettings)
        assert str(path) in str(err.value)  # the file that holds it is named
    # the scene fit's surface of any degree (fit --illumination-order), checked alike
    surface = ExtraStage("uneven_illumination", {"coefficients": [0.1, 0.0], "order": 1})
    assert PipelineSettings(extra_stages=(surface,)).extra_stages == (surface,)
    for parameters, words in (
        ({"coefficients": [0.1, 0.0, 0.2], "order": 1}, "order 1 needs 2 coefficients"),
        ({"coefficients": [0.1, 0.0], "order": 9}, "illumination_order must be an integer"),
        ({"coefficients": [0.1, 0.0]}, "coefficients must be 5 numbers"),
    ):
        with pytest.raises(ValueError, match=words):
            ExtraStage("uneven_illumination", parameters)


def test_render_draws_the_extra_stages_on_any_frame_size():
    """Illumination scales each row by its surface; column offsets fitted on 10 columns
    are repeated over a wider frame (a simulation's, not the diagnosed window's)."""
    simulation = simulate(SimulationSettings(n_frames=3, seed=2))
    plain = _quiet(PipelineSettings(simulation=simulation.settings))
    offsets = [40.0, -40.0] * 5
    lit = dataclasses.replace(
        plain,
        extra_stages=(
            ExtraStage("uneven_illumination", ILLUMINATION),
            ExtraStage("fixed_pattern_noise", {"column_offsets_adu": offsets}),
        ),
    )
    before = render_simulation(simulation, plain).images.astype(float) - 100
    after = render_simulation(simulation, lit).images.astype(float) - 100
    rows, cols = before.shape[-2:]
    assert cols > len(offsets)
    surface = 1 + 0.1 * np.linspace(-1, 1, rows)[:, None]
    expected = before * surface + np.tile(offsets, 10)[:cols]
    assert np.abs(after - expected).max() <= 0.5 + 1e-3 * before.max()  # rounding


def test_clipping_acts_on_the_recorded_values():
    """A recording clipped at zero after background subtraction (ColiCoords: 19 % of the
    pixels at 0) is drawn with the same spike: the noisy pixels below the level, not the
    clean image, are clipped; the others are untouched."""
    simulation = simulate(SimulationSettings(n_frames=2, seed=3))
    plain = PipelineSettings(simulation=simulation.settings)
    level = float(np.percentile(render_simulation(simulation, plain).images, 20))
    clipped = dataclasses.replace(
        plain,
        extra_stages=(ExtraStage("saturation", {"clip_level_adu": level, "high": False}),),
    )
    before = render_simulation(simulation, plain).images  # the same seed: the same noise
    after = render_simulation(simulation, clipped).images
    assert after.dtype == before.dtype == np.uint16
    np.testing.assert_array_equal(after, np.maximum(before, round(level)))
    assert np.mean(after == round(level)) >= 0.19  # the spike
    assert [stage.name for stage in _stages(clipped)][-2:] == ["camera", "saturation"]


def _stages(settings: PipelineSettings):
    from napari_symbac.diagnose.stages import drawn_stages
    from napari_symbac.optics.forward import ForwardModel

    return ForwardModel(
        settings.microscope, settings.render, settings.camera,
        extra_stages=drawn_stages(settings),
    ).stages  # fmt: skip


#: Rows of the SyMBac trench above its closed end: PDMS only (the end's dark rim starts
#: at row 12), where nothing but the illumination and the camera shapes the columns.
PDMS_ROWS = slice(0, 12)


def _pdms_spread_adu(frames: np.ndarray) -> float:
    """Spread (s.d. over the columns, ADU) of the column means of :data:`PDMS_ROWS`,
    averaged over the frames."""
    return float(frames[:, PDMS_ROWS].mean(axis=1).std(axis=1).mean())


def _camera_stripes_adu(frames: np.ndarray) -> float:
    """Rms (ADU) of the column means of :data:`PDMS_ROWS` in the modes column offsets
    take (``column_basis``: the smooth trends left out), averaged over the frames."""
    basis = column_basis(frames.shape[-1], PHASE_100X["pixel_size_um"])
    means = frames[:, PDMS_ROWS].mean(axis=1)
    return float(np.mean(np.sqrt(np.sum((means @ basis) ** 2, axis=1) / frames.shape[-1])))


@pytest.mark.slow
def test_diagnose_settings_export_the_accepted_effects_of_the_real_trench(
    tmp_path, capsys, real_data_dir
):
    """The user's round trip: diagnose the SyMBac trench, export with its settings.yaml.
    The dataset has the recording's frame and the effects diagnose accepted. Column
    offsets and an illumination surface are not among them: both gain on the held-out
    pixels by taking the trench's and the cells' misfit, and the pixels far from the cells
    do not show them (the columns' means would be worse with the offsets; those pixels
    ask for another surface than the fitted one); the report says so, and the export's
    PDMS above the closed end has neither the camera stripes nor the spread across the
    columns that the recording lacks (with the offsets accepted: 82 ADU rms of stripes
    against the recording's 15; with the surface: a spread of 85 ADU against 31)."""
    microscope = tmp_path / "phase100x.json"
    microscope.write_text(json.dumps(PHASE_100X))
    image = real_data_dir / "ecoli_100x_oil_exponential.tiff"  # 256 x 46
    out = tmp_path / "diagnosis"
    assert main(["diagnose", str(image), "--microscope", str(microscope), "--out", str(out)]) == 0
    said, noted = capsys.readouterr()
    # read noise 0 e- (the trench's photon transfer has no positive intercept), said why
    assert "read noise 0 e-, baseline 100 ADU (the read noise is too small to measure" in noted
    doc = json.loads((out / "diagnosis.json").read_text())
    accepted = {e["name"]: e["params"] for e in doc["effects"] if e["accepted"]}
    assert accepted, said  # the trench's misfit names some effect
    # the column offsets and the illumination surface pass the held-out check but not
    # their own (docs/diagnosis.md, section 2)
    assert "fixed_pattern_noise" not in accepted, said
    assert "uneven_illumination" not in accepted, said
    light = next(e for e in doc["effects"] if e["name"] == "uneven_illumination")
    refused_light = light["confirmation"]
    assert refused_light["confirmed"] is False
    assert refused_light["tiles_judged"] >= 12
    assert (
        refused_light["far_disagreement_beyond_noise_adu"]
        > 0.5 * refused_light["far_change_rms_adu"]
    )
    assert refused_light["reason"].startswith(
        "illumination does not match the pixels far from cells"
    )
    offsets = next(e for e in doc["effects"] if e["name"] == "fixed_pattern_noise")
    refused = offsets["confirmation"]
    assert refused["confirmed"] is False
    assert refused["columns_judged"] == refused["columns"] == 46
    assert (
        refused["far_column_misfit_with_offsets_adu2"]
        > refused["far_column_misfit_without_offsets_adu2"]
    )
    assert refused["reason"].startswith("column offsets do not match the columns far from cells")
    # asked again at every later step, their own check first: their held-out check
    # (a bootstrap) ran once, at the first step, and is not repeated while refused
    for effect in (offsets, light):
        assert effect["held_out_step"] == 1
        assert effect["step"] > 1
    report = (out / "report.txt").read_text()
    assert "cell/trench misfit, not the camera" in report
    assert "cell/trench misfit, not the light" in report
    assert report.index("fixed_pattern_noise") < report.index(refused["reason"])
    assert f"with settings.yaml, {drawn_by_export(list(accepted))}" in said
    settings = _quiet(load_settings(out / "settings.yaml", PipelineSettings))
    stages = [s.name for s in settings.extra_stages]
    assert "fixed_pattern_noise" not in stages
    assert stages == [name for name in accepted if name in DRAWN]
    assert stages
    plain = dataclasses.replace(settings, extra_stages=())
    frames = {}
    for name, pipeline in (("plain", plain), ("diagnosed", settings)):
        config = save_settings(pipeline, tmp_path / f"{name}.yaml")
        folder = tmp_path / name
        args = ["export", "--config", str(config), "--n-items", "2", "--out", str(folder)]
        assert main(args) == 0
        drawn = f"drawn with the settings' extra stages: {', '.join(stages)}"
        assert (drawn in capsys.readouterr().out) == (name == "diagnosed")
        paths = sorted(folder.glob("tiff/*/images/*.tif"))
        frames[name] = np.stack([tifffile.imread(p) for p in paths]).astype(float)
    assert frames["plain"].shape[1:] == (256, 46)  # the fitted trench, the recording's frame
    assert np.abs(frames["diagnosed"] - frames["plain"]).mean() > 10  # the stages are drawn
    recording = tifffile.imread(image).astype(float)[None]
    stripes = _camera_stripes_adu(frames["diagnosed"])
    assert stripes < 2 * _camera_stripes_adu(recording), stripes
    spread = _pdms_spread_adu(frames["diagnosed"])
    assert spread < 1.5 * _pdms_spread_adu(recording), spread


def test_the_settings_carry_the_final_models_intensities():
    """The diagnosis refits the base model's intensities (eq. 3) with the effects;
    settings.yaml draws those, not the base fit's (found as a user: DeLTA's exported
    images came out 20 % brighter than the recording). A base fit 10 % off in its media
    and device intensities is put right in the settings; its optics are kept."""
    from napari_symbac.diagnose import diagnose
    from napari_symbac.diagnose.concealed import _cells, _draw, base_settings
    from napari_symbac.diagnose.model import FittedModel, build_design
    from napari_symbac.diagnose.stages import refitted_render
    from napari_symbac.optics import ForwardModel

    microscope, render, camera = base_settings("phase")
    cells, trench, field, shape = _cells("trench", np.random.default_rng(0))
    scene = _draw(cells, trench, field, shape, microscope, render)
    image = ForwardModel(microscope, render, camera).render(scene, np.random.default_rng(1))
    off = dataclasses.replace(
        render, media_intensity=1.1 * render.media_intensity,
        device_intensity=0.9 * render.device_intensity,
    )  # fmt: skip
    design = build_design([scene], microscope, off, camera)
    result = diagnose(image[None], design, n_bootstrap=10, rng=np.random.default_rng(2))
    final, note = refitted_render(off, result.final_model, "phase")
    assert note == ""
    for name in ("cell_intensity", "media_intensity", "device_intensity"):
        assert getattr(final, name) == pytest.approx(getattr(render, name), rel=0.02), name
    assert dataclasses.replace(final, cell_intensity=0, media_intensity=0, device_intensity=0) == (
        dataclasses.replace(off, cell_intensity=0, media_intensity=0, device_intensity=0)
    )
    # an intensity the settings cannot draw is kept at 0, and said
    dark = FittedModel(beta=np.array([-50.0, 2600.0, 900.0, 0.0, 0.0, 0.0]), effects=())
    held, said = refitted_render(render, dark, "phase")
    assert held.cell_intensity == 0.0
    assert held.media_intensity == 2600.0
    assert said.startswith("the final model's cell_intensity -50 ADU is drawn as 0")
    assert held.defocus_contrast_um2 == render.defocus_contrast_um2  # no lens in phase
    # bright field: the fourth coefficient is the lens amplitude kappa I_m
    lens = FittedModel(beta=np.array([2500.0, 2600.0, 2300.0, 52.0, 0.0]), effects=())
    bright, _ = refitted_render(render, lens, "brightfield")
    assert bright.defocus_contrast_um2 == pytest.approx(52.0 / 2600.0)


def test_an_open_field_keeps_the_device_intensity_it_cannot_see():
    """Found as a user on ColiCoords ds1: an open field has no device, so its column in
    the final model's fit is 0; the solver's rounding in that direction, divided by the
    column's vanishing norm, made the device intensity -2.9e135 ADU, and the report said
    it was "drawn as 0 (the cells are darker than the model draws them)". Nothing
    depends on it: it keeps its start, and nothing is said."""
    from napari_symbac.diagnose import diagnose
    from napari_symbac.diagnose.concealed import make_case
    from napari_symbac.diagnose.stages import refitted_render
    from napari_symbac.settings import RenderSettings

    case = make_case("uneven_illumination", modality="fluorescence", geometry="field",
                     fraction_of_sd=1.0, seed=5)  # fmt: skip
    assert not np.any(case.design.components[2])  # no device in the field
    result = diagnose(case.images, case.design, n_bootstrap=10, rng=np.random.default_rng(0))
    assert [e.name for e in result.accepted] == ["uneven_illumination"]
    assert result.final_model.beta[2] == case.design.start()[2]
    _, note = refitted_render(RenderSettings(), result.final_model, "fluorescence")
    assert note == ""
