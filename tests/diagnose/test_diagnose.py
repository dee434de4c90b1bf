"""The whole diagnosis: acceptance on held-out pixels, controls, outputs, settings and stages."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import yaml
from threadpoolctl import threadpool_info, threadpool_limits

from napari_symbac.diagnose import diagnose, load_extra_stages, parse_microscope, updated_settings
from napari_symbac.diagnose.concealed import _cells, _draw, base_settings, make_case
from napari_symbac.diagnose.run import _diagnose
from napari_symbac.optics import ForwardModel
from napari_symbac.settings import PipelineSettings


def test_concealed_illumination_is_accepted_and_improves_held_out_pixels():
    case = make_case("uneven_illumination", fraction_of_sd=0.5, seed=4)
    calls = []
    result = diagnose(
        case.images,
        case.design,
        n_bootstrap=20,
        rng=np.random.default_rng(0),
        progress=lambda done, total: calls.append((done, total)),
    )
    assert [e.name for e in result.accepted] == ["uneven_illumination"]
    # each held-out check counted once, against the most still possible (at most 4 steps
    # x 3 tries), a bound that only shrinks as the diagnosis learns it; the last report
    # says it is done
    checks = calls[-1][0]
    assert 1 <= checks < 12
    assert sorted({done for done, _ in calls}) == list(range(1, checks + 1))
    totals = [total for _, total in calls]
    assert totals == sorted(totals, reverse=True)
    assert totals[0] <= 12
    assert all(done <= total for done, total in calls)
    assert calls[-1] == (checks, checks)
    effect = result.accepted[0]
    assert effect.held_out_gain_nats > effect.null_threshold_nats > 0
    assert effect.held_out_after < effect.held_out_before
    assert result.final_fit["held_out"] < result.base_fit["held_out"]
    magnitude = effect.params["peak_to_peak_fraction"]
    assert magnitude == pytest.approx(case.true_magnitude, rel=0.25)
    # the accepted effects fold into settings as they are (found as an API user: only
    # (name, params) pairs were taken, "cannot unpack non-iterable EffectResult")
    folded, extra = updated_settings(PipelineSettings(), result.accepted)
    assert extra == [{"name": "uneven_illumination", "parameters": effect.params}]
    assert [stage.name for stage in folded.extra_stages] == ["uneven_illumination"]
    # a light field shows far from the cells too: the PDMS beside and above the trench
    # asks for the same surface (the check that refuses the SyMBac trench's surface)
    confirmation = effect.confirmation
    assert confirmation is not None
    assert confirmation.confirmed, confirmation.reason
    assert confirmation.reason.startswith("illumination confirmed far from cells")
    assert confirmation.reason in result.report()
    numbers = confirmation.numbers
    assert numbers["far_disagreement_beyond_noise_adu"] < 0.5 * numbers["far_change_rms_adu"]
    doc = json.loads(json.dumps(result.as_dict()))
    assert set(doc) >= {"base_fit", "mismatches", "effects", "final_fit"}
    assert doc["effects"][0]["accepted"] is True
    assert {"where", "statistic", "value", "significance"} <= set(doc["mismatches"][0])


def test_concealed_column_offsets_are_confirmed_far_from_cells():
    """Column offsets of the camera hidden at one noise s.d.: besides the held-out check,
    the fitted offsets explain the column means of the pixels far from the cells (the
    check that refuses the SyMBac trench's offsets), and the report says so."""
    case = make_case("fixed_pattern_noise", fraction_of_sd=1.0, seed=3)
    result = diagnose(case.images, case.design, n_bootstrap=10, rng=np.random.default_rng(4))
    assert [e.name for e in result.accepted] == ["fixed_pattern_noise"], result.report()
    effect = result.accepted[0]
    assert effect.params["rms_column_offset_adu"] == pytest.approx(case.true_magnitude, rel=0.2)
    confirmation = effect.confirmation
    assert confirmation is not None
    assert confirmation.confirmed
    numbers = confirmation.numbers
    assert numbers["columns_judged"] == numbers["columns"] == 46
    assert numbers["far_column_misfit_with_offsets_adu2"] < 0.5 * numbers[
        "far_column_misfit_without_offsets_adu2"
    ]
    assert numbers["far_column_mean_correlation"] > 0.7
    assert confirmation.reason in result.report()
    doc = json.loads(json.dumps(result.as_dict()))
    said = doc["effects"][0]["confirmation"]
    assert said["confirmed"] is True
    assert said["reason"].startswith("column offsets confirmed far from cells")


@pytest.mark.slow
def test_a_refused_effect_is_asked_its_own_check_first_at_later_steps(monkeypatch):
    """An effect its own check refused is tried again at later steps (the effects
    accepted since may have taken the misfit it absorbed), its own check first: a
    held-out check (a bootstrap) only when that passes. Here the check always refuses:
    the surface is asked at each of the 4 steps and checked on held-out pixels once, and
    the report gives that check's numbers with their step."""
    from napari_symbac.diagnose import run
    from napari_symbac.diagnose.effects.base import Confirmation
    from napari_symbac.diagnose.effects.uneven_illumination import UnevenIllumination

    asked, checked = [], []

    def refuse(self, theta, residual_adu, valid, mean_adu):
        asked.append(self.name)
        return Confirmation(False, "refused by the test", {"asked": float(len(asked))})

    def counted(effect, *args, **kwargs):
        checked.append(effect.name)
        return held_out(effect, *args, **kwargs)

    held_out = run.held_out
    monkeypatch.setattr(UnevenIllumination, "confirm", refuse)
    monkeypatch.setattr(run, "held_out", counted)
    case = make_case("uneven_illumination", fraction_of_sd=1.5, seed=4)
    result = diagnose(case.images, case.design, n_bootstrap=5, rng=np.random.default_rng(0))
    assert len(result.accepted) == 4, result.report()  # other effects took its misfit
    assert asked == ["uneven_illumination"] * 4
    assert checked.count("uneven_illumination") == 1
    light = next(e for e in result.effects if e.name == "uneven_illumination")
    assert not light.accepted
    assert (light.held_out_step, light.step) == (1, 4)
    assert light.held_out_gain_nats > light.null_threshold_nats > 0  # it had passed that
    assert light.confirmation.numbers["asked"] == 4
    report = result.report()
    assert f"-> {light.held_out_after:.5f} (step 1)" in report
    assert "step 4: refused by the test" in report
    said = light.as_dict()
    assert (said["held_out_step"], said["step"]) == (1, 4)


@pytest.mark.parametrize(("effect", "seed"), [(None, 31), ("uneven_illumination", 4)])
def test_bright_field_recordings_are_diagnosed(effect, seed):
    """Bright field, lens term and all (a field of cells out of focus): a control
    accepts nothing, an uneven lamp hidden at half a noise s.d. is named, and the lens
    amplitude is re-fitted where it was drawn."""
    case = make_case(effect, modality="brightfield", geometry="field", seed=seed)
    result = diagnose(case.images, case.design, n_bootstrap=10, rng=np.random.default_rng(0))
    assert [e.name for e in result.accepted] == ([effect] if effect else []), result.report()
    lens = result.final_model.beta[3]
    assert lens == pytest.approx(case.design.lens_amplitude, rel=0.1)


@pytest.mark.parametrize("seed", [31, 32])
def test_no_effect_control_accepts_nothing(seed):
    case = make_case(None, modality="fluorescence", fraction_of_sd=0.5, seed=seed)
    result = diagnose(case.images, case.design, n_bootstrap=20, rng=np.random.default_rng(seed))
    assert result.accepted == []
    assert "Nothing significant" in result.report()
    assert abs(result.base_fit["value"] - 1.0) < 0.05


def test_a_plain_effect_is_decided_early_and_alike():
    """A strong concealed effect (1.5 s.d.) passes its held-out check after a few
    bootstrap replicates (its gain far beyond the null); the full bootstrap accepts the
    same effects with the same fitted parameters."""
    from napari_symbac.diagnose import selection

    case = make_case("uneven_illumination", fraction_of_sd=1.5, seed=4)
    result = diagnose(case.images, case.design, n_bootstrap=30, rng=np.random.default_rng(0))
    effect = result.accepted[0]
    assert effect.name == "uneven_illumination"
    assert selection.MIN_REPLICATES <= effect.null_replicates < 30
    assert effect.as_dict()["null_replicates"] == effect.null_replicates
    margin = selection.EARLY_MARGIN
    selection.EARLY_MARGIN = float("inf")  # never early: every check draws all 30
    try:
        full = diagnose(case.images, case.design, n_bootstrap=30, rng=np.random.default_rng(0))
    finally:
        selection.EARLY_MARGIN = margin
    assert full.accepted[0].null_replicates == 30
    assert [e.name for e in full.accepted] == [e.name for e in result.accepted]
    assert full.accepted[0].params == effect.params
    assert effect.held_out_gain_nats > full.accepted[0].null_threshold_nats


def test_a_check_of_an_absent_effect_draws_every_replicate():
    """No effect concealed: a held-out check of one (uneven illumination) finds no
    gain beyond its null and draws the whole bootstrap, however it ends."""
    from napari_symbac.diagnose.effects import CATALOGUE
    from napari_symbac.diagnose.selection import ModelSpec, held_out

    case = make_case(None, modality="fluorescence", fraction_of_sd=0.5, seed=31)
    y = np.asarray(case.images, np.float64)
    y = (y[None] if y.ndim == 2 else y) - case.design.camera.baseline_adu
    valid = np.ones(y.shape, bool)
    spec = ModelSpec()
    current = spec.fit(case.design, y, valid)
    effect = CATALOGUE["uneven_illumination"](case.design.geometry)
    rng = np.random.default_rng(0)
    check = held_out(effect, case.design, y, spec, current, valid, rng, n_bootstrap=12)
    assert check.replicates == 12
    assert not check.passed


def test_a_gain_of_rounding_noise_is_not_accepted(monkeypatch):
    """Found as a user: per-cell brightness on a fit of one cell changed the held-out
    deviance by 6e-9 nats, its bootstrap null by nothing, and was accepted with "gain
    0.0 nats (needed: > 0.0)". The gains of that case are injected into the real check:
    it needs MIN_GAIN_NATS, and says so as its threshold (never a negative one)."""
    from napari_symbac.diagnose import selection
    from napari_symbac.diagnose.effects import CATALOGUE

    case = make_case(None, modality="fluorescence", fraction_of_sd=0.5, seed=31)
    y = np.asarray(case.images, np.float64)
    y = (y[None] if y.ndim == 2 else y) - case.design.camera.baseline_adu
    valid = np.ones(y.shape, bool)
    spec = selection.ModelSpec()
    current = spec.fit(case.design, y, valid)
    gains = iter([6.2e-9])  # the data's; every bootstrap replicate's is 0

    def injected(*args, **kwargs):
        return 1.0, 1.0, next(gains, 0.0)

    monkeypatch.setattr(selection, "_gain", injected)
    effect = CATALOGUE["cell_intensity_variability"](case.design.geometry)
    check = selection.held_out(effect, case.design, y, spec, current, valid,
                               np.random.default_rng(0), n_bootstrap=8)  # fmt: skip
    assert not check.passed
    assert check.threshold_nats == selection.MIN_GAIN_NATS


def test_same_seed_same_diagnosis():
    case = make_case("stray_light", fraction_of_sd=0.6, seed=5)
    one = diagnose(case.images, case.design, n_bootstrap=10, rng=np.random.default_rng(3))
    two = diagnose(case.images, case.design, n_bootstrap=10, rng=np.random.default_rng(3))
    assert json.dumps(one.as_dict()) == json.dumps(two.as_dict())


def test_bad_input_is_refused_in_words():
    """Found as an API user: one NaN pixel gave a diagnosis of NaNs, ``rng=0`` failed
    with "'int' object has no attribute 'standard_normal'", one scene for build_design
    with "'Scene' object is not iterable"."""
    from napari_symbac.diagnose import build_design

    case = make_case("stray_light", fraction_of_sd=0.6, seed=5)
    holed = np.array(case.images, np.float64)
    holed[0, 5, 5] = np.nan
    with pytest.raises(ValueError, match="1 NaN or infinite pixels"):
        diagnose(holed, case.design)
    with pytest.raises(ValueError, match="negative values"):
        diagnose(case.images.astype(np.float64) - 1e5, case.design)
    with pytest.raises(TypeError, match=r"pass numpy.random.default_rng\(0\)"):
        diagnose(case.images, case.design, rng=0)
    # a significance level and counts out of range (were taken: max_steps=-2 returned
    # nothing); one effect's name given alone is that effect (was split into letters)
    with pytest.raises(ValueError, match=r"alpha=\.\.\.\) is a significance level in \(0, 1\)"):
        diagnose(case.images, case.design, alpha=5)
    with pytest.raises(ValueError, match=r"max_steps=\.\.\.\) must be a whole number of at"):
        diagnose(case.images, case.design, max_steps=-2)
    with pytest.raises(ValueError, match=r"unknown effects \['glow'\]"):
        diagnose(case.images, case.design, candidates="glow")
    with pytest.raises(TypeError, match=r"diagnose\(design=...\) needs BaseDesign"):
        diagnose(case.images, None)
    microscope, render, camera = base_settings("phase")
    cells, trench, field, shape = _cells("trench", np.random.default_rng(0))
    scene = _draw(cells, trench, field, shape, microscope, render)
    with pytest.raises(TypeError, match=r"a list: pass \[scene\]"):
        build_design(scene, microscope, render, camera)
    with pytest.raises(TypeError, match=r"build_design\(camera=...\) needs Camera"):
        build_design([scene], microscope, render, None)


def test_accepted_effects_become_settings_and_stages(tmp_path):
    accepted = [
        ("uneven_illumination", {"coefficients": [0.0, 0.1, 0.0, 0.0, 0.0]}),
        ("camera_noise", {"gain_ratio": 1.2, "read_variance_ratio": 1.0}),
    ]
    settings, extra = updated_settings(PipelineSettings(), accepted)
    assert settings.camera.sensitivity_adu_per_e == pytest.approx(2.9 * 1.2)
    assert [e["name"] for e in extra] == ["uneven_illumination"]
    path = tmp_path / "extra_stages.yaml"
    path.write_text(yaml.safe_dump({"extra_stages": extra}))
    stages = load_extra_stages(path)
    microscope, render, camera = base_settings("phase")
    cells, trench, field, shape = _cells("trench", np.random.default_rng(0))
    scene = _draw(cells, trench, field, shape, microscope, render)
    plain = ForwardModel(microscope, render, camera).render_clean(scene)
    lit = ForwardModel(microscope, render, camera, extra_stages=stages).render_clean(scene)
    ratio = lit / plain
    assert ratio[0].mean() == pytest.approx(0.9, abs=0.01)
    assert ratio[-1].mean() == pytest.approx(1.1, abs=0.01)
    # every effect is a settings field or a stage the settings carry, for render and
    # export (tests/diagnose/test_drawn_stages.py), but the time-dependent ones
    from napari_symbac.diagnose.effects import CATALOGUE
    from napari_symbac.diagnose.stages import DRAWN, IN_SETTINGS, TIME_DEPENDENT, drawn_by_export

    assert set(CATALOGUE) == {*DRAWN, *IN_SETTINGS, *TIME_DEPENDENT}
    parameters = {
        "camera_noise": {"gain_ratio": 1.0, "read_variance_ratio": 1.0},
        "cell_intensity_variability": {"cv": 0.2},
        "background_texture": {"rms_fraction": 0.1},
        "cell_curvature": {"rms_bow_um": 0.05, "bow_um": {1: 0.05}},
        "envelope_stain": {"fraction": 0.4},
    }
    assert set(parameters) == set(IN_SETTINGS)
    folded, extra = updated_settings(PipelineSettings(), list(parameters.items()))
    assert extra == []
    assert folded.extra_stages == ()
    assert folded.simulation.do_transformation  # curved cells
    assert folded.render.envelope_stain_fraction == 0.4
    assert drawn_by_export(list(parameters)) == (
        f"render and export draw {', '.join(parameters)}"
    )
    assert drawn_by_export([]) == ""


def test_microscope_file_checks():
    good = {
        "modality": "phase",
        "pixel_size_um": 0.065,
        "NA": 1.45,
        "refractive_index": 1.518,
        "wavelength_um": 0.65,
        "objective": "100x oil",
        "camera": {"baseline_adu": 100, "sensitivity_adu_per_e": 0.5, "dark_noise_e": 1.5},
        "colour": "blue",
    }
    config = parse_microscope(good)
    assert config.microscope.numerical_aperture == 1.45
    assert config.microscope.magnification == 100
    assert config.camera.sensitivity_adu_per_e == 0.5
    assert any("colour" in note for note in config.notes)
    bad = dict(good)
    del bad["NA"]
    with pytest.raises(ValueError, match="NA"):
        parse_microscope(bad)
    with pytest.raises(ValueError, match="modality"):
        parse_microscope({**good, "modality": "darkfield"})
    # found as a user: a misspelled camera key was ignored with a note, exit 0
    with pytest.raises(ValueError, match=r"unknown camera key\(s\) 'baseline'; the camera takes"):
        parse_microscope({**good, "camera": {"baseline": 100}})


def test_microscope_file_of_defaults_microscope_is_read():
    """Found as a user: the file `napari-symbac defaults microscope` writes (the
    Microscope's own names) was refused by `diagnose` ("lacks NA") though `fit` read it."""
    from dataclasses import asdict

    from napari_symbac.settings import Microscope

    written = asdict(Microscope(pixel_size_um=0.08, modality="fluorescence"))
    config = parse_microscope(written)
    assert config.microscope == Microscope(pixel_size_um=0.08, modality="fluorescence")
    assert config.camera is None  # measured from the recording by the command
    assert config.notes == ()  # nothing ignored (diagnose itself says it measures the camera)
    with pytest.raises(ValueError, match=r"both NA .* and numerical_aperture"):
        parse_microscope({**written, "NA": 0.9})


@pytest.mark.parametrize(
    ("effect", "seed"), [("uneven_illumination", 1000), ("fixed_pattern_noise", 1020)]
)
def test_strong_mean_effect_is_named_before_the_variance_it_inflates(effect, seed):
    # A mean misfit inflates the residual variance, so camera_noise is significant too;
    # the stronger evidence (the mean effect) must be tried and accepted first.
    modality = "phase" if effect == "uneven_illumination" else "fluorescence"
    case = make_case(effect, modality=modality, fraction_of_sd=0.7, seed=seed)
    result = diagnose(
        case.images, case.design, n_bootstrap=10, max_steps=1, rng=np.random.default_rng(seed + 1)
    )
    assert [e.name for e in result.accepted] == [effect], result.report()


def test_blas_runs_single_threaded_inside_the_diagnosis():
    seen = []

    def progress(done, total):
        seen.extend(p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas")

    case = make_case("stray_light", fraction_of_sd=0.6, seed=5)
    limited = diagnose(
        case.images, case.design, n_bootstrap=10, rng=np.random.default_rng(3), progress=progress
    )
    assert seen
    assert set(seen) == {1}
    with threadpool_limits(limits=2, user_api="blas"):
        threaded = _diagnose(
            case.images,
            case.design,
            candidates=None,
            alpha=0.01,
            n_bootstrap=10,
            max_steps=4,
            max_tries=3,
            rng=np.random.default_rng(3),
            valid=None,
            progress=None,
            cancel=None,
        )
    assert [e.name for e in threaded.accepted] == [e.name for e in limited.accepted]
    assert threaded.base_fit["held_out"] == pytest.approx(limited.base_fit["held_out"], rel=1e-9)


def test_cautions_point_where_the_interface_shows_the_residual():
    """Found as a user: the Diagnose dock's caution said "see residuals.png", a file of
    the command's output folder; the dock names its residual layer."""
    from napari_symbac.diagnose.run import Diagnosis

    empty = np.zeros((1, 4, 4))
    result = Diagnosis(
        base_fit={"metric": "reduced chi-square", "value": 301.0, "held_out": 0.0},
        final_fit={"metric": "reduced chi-square", "value": 301.0, "held_out": 0.0},
        mismatches=[],
        effects=[],
        residual_before=empty,
        residual_after=empty,
        final_model=None,
    )
    (said,) = result.cautions()
    assert "misplaced; see residuals.png)" in said
    (said,) = result.cautions("see the layer 'diagnosis residual'", "give the camera")
    assert "misplaced; see the layer 'diagnosis residual')" in said
    assert "residuals.png" not in said


def test_the_report_prints_huge_significances_in_three_digits():
    """``-log10 p`` far in the tail (a real trench's 149969.40, whose decimals meant
    nothing) in three significant digits; usual ones with two decimals, as before."""
    from napari_symbac.diagnose.statistics import Mismatch, significance_words

    assert significance_words(2.634) == "2.63"
    assert significance_words(999.994) == "999.99"
    assert significance_words(149969.4) == "1.5e+05"
    assert significance_words(12064.02) == "1.21e+04"
    case = make_case(None, modality="fluorescence", fraction_of_sd=0.5, seed=31)
    result = diagnose(case.images, case.design, n_bootstrap=5, rng=np.random.default_rng(0))
    huge = Mismatch("media near cells", "variance excess z", 829.0, 149405.54)
    report = dataclasses.replace(result, mismatches=[huge]).report()
    assert "\n  1.49e+05  media near cells: variance excess z = 829" in report
    assert "149405" not in report


@pytest.mark.parametrize("geometry", ["field", "trench"])
def test_clipped_pixels_are_fitted_by_their_censored_likelihood(geometry):
    """A fifth of the frame clipped low (as a background subtraction's zeros): the fit
    with the clip censored finds the mean the unclipped frame gives, where leaving the
    clipped pixels out (before 2026-12-04) put it a third of a noise s.d. too bright, and
    the residual with each clipped pixel's expected one averages 0 (found as a user: a
    ColiCoords field's residual after ``saturation`` averaged -0.30 s.d.)."""
    from napari_symbac.diagnose.model import Censor, fit_model

    case = make_case(None, modality="fluorescence", geometry=geometry, fraction_of_sd=0.5, seed=31)
    y = case.images.astype(float) - case.design.camera.baseline_adu
    valid = np.ones(y.shape, bool)
    censor = Censor(float(np.floor(np.percentile(y, 20))), high=False)
    clipped = np.maximum(y, censor.level_adu)
    assert 0.15 < censor.mask(clipped).mean() < 0.3
    unclipped = fit_model(case.design, y, valid)
    censored = fit_model(case.design, clipped, valid, censor=censor)
    left_out = fit_model(case.design, clipped, valid & ~censor.mask(clipped))
    sd = np.sqrt(unclipped.var)
    assert abs(np.mean((censored.mu - unclipped.mu) / sd)) < 0.02
    assert np.mean((left_out.mu - unclipped.mu) / sd) > 0.2  # what the old fit did
    r = (clipped - censored.mu) / np.sqrt(censored.var)
    r = np.where(censor.mask(clipped), censor.standardised_mean(censored.mu, censored.var), r)
    assert abs(r.mean()) < 0.02


def test_a_clipped_pixels_expected_residual_is_the_half_normal_mean_at_the_clip():
    """Clipped exactly at its mean, a normal pixel's expected standardised residual is
    the half-normal mean, sqrt(2 / pi), above a ceiling and below a floor; with its mean
    far beyond the clip, the clip tells nothing and it tends to 0 from that side."""
    from napari_symbac.diagnose.model import Censor

    var = np.array([4.0, 4.0])
    ceiling, floor = Censor(100.0, high=True), Censor(0.0, high=False)
    half_normal = np.sqrt(2 / np.pi)
    high = ceiling.standardised_mean(np.array([99.5, 1e3]), var)
    low = floor.standardised_mean(np.array([0.5, -1e3]), var)
    np.testing.assert_allclose([high[0], low[0]], [half_normal, -half_normal], rtol=1e-12)
    assert 0 <= high[1] < 1e-12
    assert -1e-12 < low[1] <= 0
