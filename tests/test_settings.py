"""Settings: validation messages and YAML/JSON round trips."""

from __future__ import annotations

import dataclasses

import pytest

from napari_symbac.settings import (
    Camera,
    Microscope,
    PipelineSettings,
    RenderSettings,
    SimulationSettings,
    TrenchGeometry,
    from_dict,
    load_microscope,
    load_settings,
    save_settings,
    to_dict,
)


@pytest.mark.parametrize("suffix", [".yaml", ".json"])
def test_pipeline_settings_round_trip(tmp_path, suffix):
    settings = PipelineSettings(
        simulation=SimulationSettings(n_frames=7, trench=TrenchGeometry(length_um=20.0), seed=3),
        microscope=Microscope(numerical_aperture=0.95, refractive_index=1.0, condenser="Ph2"),
        render=RenderSettings(
            cell_intensity=123.0, noise_model="gaussian", envelope_stain_fraction=0.35
        ),
        camera=Camera(baseline_adu=50.0),
    )
    path = save_settings(settings, tmp_path / f"settings{suffix}")
    loaded = load_settings(path, PipelineSettings)
    assert loaded == settings
    assert loaded.render.envelope_stain_fraction == 0.35


def test_partial_file_takes_defaults(tmp_path):
    path = tmp_path / "sim.yaml"
    path.write_text("n_frames: 5\ntrench:\n  width_um: 2.0\n")
    loaded = load_settings(path, SimulationSettings)
    assert loaded.n_frames == 5
    assert loaded.trench.width_um == 2.0
    assert loaded.cell_width_um == SimulationSettings().cell_width_um


def test_an_empty_value_says_to_give_one_or_leave_the_line_out(tmp_path):
    """Found as a user: ``pixel_size_um: null`` said "must be a number, got None"."""
    from napari_symbac.settings import Microscope, load_settings

    path = tmp_path / "microscope.yaml"
    path.write_text("pixel_size_um: null\nmodality: phase\n")
    with pytest.raises(ValueError, match=r"Microscope.pixel_size_um is empty \(null\): give "
                       "it a value, or leave the line out"):  # fmt: skip
        load_settings(path, Microscope)
    path.write_text("modality: phase\n")
    assert load_settings(path, Microscope) == Microscope()


def test_a_number_yaml_reads_as_text_is_taken(tmp_path):
    """Found as a user: ``pixel_size_um: 65e-3`` (YAML 1.1 reads an exponent without a
    dot as text) was refused as "must be a number, got '65e-3'"; a value with its unit
    is refused with how to write it."""
    from napari_symbac.settings import Microscope, load_settings

    path = tmp_path / "microscope.yaml"
    path.write_text("pixel_size_um: 65e-3\n")
    assert load_settings(path, Microscope).pixel_size_um == pytest.approx(0.065)
    path.write_text("pixel_size_um: 0.065 um\n")
    with pytest.raises(ValueError, match=r"got '0.065 um': write a plain number \(0.065"):
        load_settings(path, Microscope)


def test_settings_are_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        Microscope().numerical_aperture = 2.0  # type: ignore[misc]


@pytest.mark.parametrize(
    ("factory", "match"),
    [
        (lambda: TrenchGeometry(width_um=-1.0), r"TrenchGeometry\.width_um must be a positive"),
        (lambda: SimulationSettings(n_frames=0), r"n_frames must be an integer >= 1"),
        (lambda: SimulationSettings(width_var_um2=-0.1), r"width_var_um2 must be zero or positive"),
        (
            lambda: SimulationSettings(cell_width_um=2.0, trench=TrenchGeometry(width_um=1.5)),
            r"does not fit in a trench",
        ),
        (lambda: SimulationSettings(lysis_p=1.5), r"lysis_p is a probability"),
        (lambda: SimulationSettings(growth_model="random"), r"growth_model must be one of"),
        (
            lambda: Microscope(numerical_aperture=1.4, refractive_index=1.0),
            r"cannot exceed the immersion refractive_index",
        ),
        (lambda: Microscope(wavelength_um=650), r"looks like nanometres"),
        (lambda: Microscope(condenser="Ph9"), r"condenser must be one of"),
        (lambda: RenderSettings(upsample=0), r"upsample must be an integer >= 1"),
        (
            lambda: RenderSettings(envelope_stain_fraction=1.5),
            r"envelope_stain_fraction must be in \[0, 1\]",
        ),
        (
            lambda: RenderSettings(envelope_stain_fraction=float("nan")),
            r"envelope_stain_fraction must be in \[0, 1\]",
        ),
        (lambda: Camera(sensitivity_adu_per_e=0), r"sensitivity_adu_per_e must be a positive"),
        (
            lambda: Camera(baseline_adu=70000),
            r"baseline_adu=70000 is not below the camera's full scale \(65535 ADU",
        ),
        (lambda: Camera(baseline_adu=300, bit_depth=8), r"\(255 ADU at bit_depth 8\)"),
        (lambda: Microscope(wavelength_um=0.00065), r"wavelength_um=0.00065 is below the ultra"),
        (
            lambda: PipelineSettings(render=RenderSettings(apodisation_sigma_um=0.05)),
            r"below the diffraction bound of eq\. 13",
        ),
    ],
)
def test_impossible_values_name_the_field(factory, match):
    with pytest.raises(ValueError, match=match):
        factory()


def test_eq13_bound_matches_formula():
    scope = Microscope(wavelength_um=0.5, refractive_index=1.5, numerical_aperture=1.25)
    assert scope.min_apodisation_sigma_um == pytest.approx(0.9 * 0.5 * 1.5 / (2 * 1.25))


def test_unknown_and_mistyped_fields_are_rejected():
    with pytest.raises(ValueError, match=r"unknown field\(s\) pixel_size in Microscope"):
        from_dict(Microscope, {"pixel_size": 0.1})
    with pytest.raises(ValueError, match=r"SimulationSettings\.n_frames must be an integer"):
        from_dict(SimulationSettings, {"n_frames": "ten"})
    with pytest.raises(ValueError, match=r"PipelineSettings\.camera must be a mapping"):
        from_dict(PipelineSettings, {"camera": 3})


def test_to_dict_is_plain():
    data = to_dict(PipelineSettings())
    assert isinstance(data["simulation"]["trench"], dict)
    assert from_dict(PipelineSettings, data) == PipelineSettings()


def test_load_settings_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_settings(tmp_path / "missing.yaml", Camera)
    bad = tmp_path / "bad.yaml"
    bad.write_text("a: [1, 2\n")
    with pytest.raises(ValueError, match="not valid YAML/JSON"):
        load_settings(bad, Camera)
    with pytest.raises(ValueError, match=r"use a \.yaml, \.yml or \.json file"):
        save_settings(Camera(), tmp_path / "camera.txt")


def test_load_microscope_reads_both_spellings(tmp_path):
    """A Microscope file with the settings' field names and the diagnose command's
    microscope file (NA, objective) give the same microscope."""
    own = tmp_path / "own.yaml"
    own.write_text(
        "modality: phase\npixel_size_um: 0.065\nnumerical_aperture: 1.45\n"
        "refractive_index: 1.518\nwavelength_um: 0.65\ncondenser: Ph3\nmagnification: 100\n"
    )
    diagnose_style = tmp_path / "diagnose.yaml"
    diagnose_style.write_text(
        "modality: phase\npixel_size_um: 0.065\nNA: 1.45\nrefractive_index: 1.518\n"
        "wavelength_um: 0.65\ncondenser: Ph3\nobjective: 100x oil\n"
    )
    assert load_microscope(diagnose_style) == load_microscope(own)
    assert load_microscope(own).numerical_aperture == 1.45
    partial = tmp_path / "partial.yaml"
    partial.write_text("pixel_size_um: 0.08\n")
    assert load_microscope(partial) == Microscope(pixel_size_um=0.08)
    incomplete = tmp_path / "incomplete.yaml"
    incomplete.write_text("NA: 1.4\n")
    with pytest.raises(ValueError, match="lacks the required key"):
        load_microscope(incomplete)


def test_numpy_numbers_are_taken_as_numbers(tmp_path):
    """Found as a user: ``SimulationSettings(seed=rng.integers(1000))`` was refused ("must
    be a non-negative integer, got np.int64(850)"), as were np.float32 sizes. They are
    taken as Python's numbers, float32's 0.065 as 0.065, and saved as such."""
    import numpy as np

    from napari_symbac.export.dataset import ExportSettings

    rng = np.random.default_rng(0)
    simulation = SimulationSettings(seed=rng.integers(1000), n_frames=np.int64(5))
    assert (simulation.seed, simulation.n_frames) == (850, 5)
    assert type(simulation.seed) is int
    microscope = Microscope(pixel_size_um=np.float32(0.065))
    assert microscope.pixel_size_um == 0.065
    assert ExportSettings(n_items=np.int32(3)).n_items == 3
    path = tmp_path / "settings.yaml"
    save_settings(PipelineSettings(simulation=simulation, microscope=microscope), path)
    text = path.read_text()
    assert "seed: 850" in text
    assert "pixel_size_um: 0.065" in text
    with pytest.raises(ValueError, match="must be a non-negative integer, got -1"):
        SimulationSettings(seed=np.int64(-1))
