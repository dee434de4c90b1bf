"""The diagnosis names a stain in the cell envelope and measures its fraction."""

from __future__ import annotations

import numpy as np
import pytest

from napari_symbac.diagnose import diagnose
from napari_symbac.diagnose.concealed import make_case
from napari_symbac.diagnose.effects import CATALOGUE
from napari_symbac.diagnose.effects.envelope_stain import EnvelopeStain
from napari_symbac.diagnose.stages import updated_settings
from napari_symbac.settings import PipelineSettings


def test_an_envelope_stain_is_named_and_its_fraction_recovered():
    """A fluorescence field with 20 % of the stain in the envelope (the change peaks at 2
    noise s.d.): accepted first, fraction within 0.03, carried into the settings."""
    case = make_case(
        "envelope_stain", modality="fluorescence", geometry="field", fraction_of_sd=2.0, seed=11
    )
    assert 0.15 < case.true_magnitude < 0.25
    result = diagnose(case.images, case.design, n_bootstrap=10, rng=np.random.default_rng(0))
    names = [e.name for e in result.accepted]
    assert names[0] == "envelope_stain", result.report()
    effect = result.accepted[0]
    assert effect.params["fraction"] == pytest.approx(case.true_magnitude, abs=0.03)
    assert effect.held_out_after < effect.held_out_before
    settings, _ = updated_settings(PipelineSettings(), [("envelope_stain", effect.params)])
    assert settings.render.envelope_stain_fraction == pytest.approx(effect.params["fraction"])


@pytest.mark.parametrize("seed", [31, 32])
def test_a_volume_stain_names_no_envelope(seed):
    case = make_case(None, modality="fluorescence", geometry="field", seed=seed)
    result = diagnose(case.images, case.design, n_bootstrap=10, rng=np.random.default_rng(seed))
    assert "envelope_stain" not in [e.name for e in result.accepted]
    tested = [e for e in result.effects if e.name == "envelope_stain"]
    assert tested
    assert tested[0].evidence < -np.log10(0.01 / len(CATALOGUE))


def test_phase_contrast_has_no_envelope_stain():
    case = make_case(None, modality="phase", seed=1)
    assert case.design.geometry.envelope_component is None
    assert "fluorescence" in EnvelopeStain.modalities
    assert EnvelopeStain(case.design.geometry).n_params() == 0


def test_a_base_model_with_an_envelope_stain_reports_the_whole_fraction():
    """Diagnosing a scene fit that drew 10 % of the stain in the envelope (fit
    --envelope-stain's settings) against a recording drawn with 20 %: the base model
    draws its 10 % (build_design stains the scenes as the pipeline does) and the
    effect reports the whole fraction, not its change."""
    import dataclasses

    from napari_symbac.diagnose.concealed import _cells, _draw, base_settings
    from napari_symbac.diagnose.model import build_design, deviance, fit_model
    from napari_symbac.diagnose.selection import ModelSpec

    case = make_case(
        "envelope_stain", modality="fluorescence", geometry="field", fraction_of_sd=2.0, seed=11
    )
    microscope, render, camera = base_settings("fluorescence")
    cells, trench, field, shape = _cells("field", np.random.default_rng(11))
    scene = _draw(cells, trench, field, shape, microscope, render)
    drawn = dataclasses.replace(render, envelope_stain_fraction=0.1)
    design = build_design([scene], microscope, drawn, camera)
    assert design.geometry.envelope_fraction == 0.1
    assert not np.allclose(design.components[0], case.design.components[0])
    y = case.images.astype(float) - camera.baseline_adu
    valid = np.ones(y.shape, bool)
    effect = EnvelopeStain(design.geometry)
    spec = ModelSpec().with_effect(effect, y)
    fitted = spec.fit(design, y, valid)
    theta = fitted.effects[0][1]
    assert effect.summary(theta, fitted.mu)["fraction"] == pytest.approx(
        case.true_magnitude, abs=0.03
    )
    assert deviance(y, fit_model(design, y, valid), valid).sum() > deviance(
        y, fitted, valid
    ).sum()
