"""background_texture fits only the modes its media support can tell apart (issue 11)."""

from __future__ import annotations

import numpy as np

from napari_symbac.diagnose.concealed import make_case
from napari_symbac.diagnose.effects.background_texture import (
    MAX_TERMS,
    MIN_NEW_FRACTION,
    PIXELS_PER_MODE,
    BackgroundTexture,
    support_modes,
    texture_basis,
)
from napari_symbac.diagnose.run import diagnose


def _new_fractions(basis: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """Share of each mode's weighted norm not explained by the modes before it."""
    a = (basis[:, weight > 0.5] * weight[weight > 0.5]).T
    _, r = np.linalg.qr(a)
    return np.abs(np.diag(r)) / np.linalg.norm(a, axis=0)


def test_open_field_keeps_every_mode():
    basis = texture_basis((144, 144), 0.065)
    kept = support_modes(basis, np.ones((144, 144)))
    assert len(kept) == MAX_TERMS
    assert np.array_equal(kept, np.arange(MAX_TERMS))  # lowest frequencies first


def test_thin_strip_keeps_few_independent_modes():
    weight = np.zeros((256, 46))
    weight[:, 20:23] = 1.0  # a 3-px strip of media along a trench
    basis = texture_basis(weight.shape, 0.065)
    kept = support_modes(basis, weight)
    assert 0 < len(kept) <= (256 * 3) // PIXELS_PER_MODE
    assert np.all(_new_fractions(basis[kept], weight) >= MIN_NEW_FRACTION - 1e-9)


def test_no_media_support_means_no_parameters():
    basis = texture_basis((64, 46), 0.065)
    assert len(support_modes(basis, np.zeros((64, 46)))) == 0


def test_trench_modes_follow_the_media_of_the_design():
    case = make_case("background_texture", modality="fluorescence", fraction_of_sd=0.7, seed=3)
    effect = BackgroundTexture(case.design.geometry)
    media = case.design.geometry.media_fraction
    assert media is not None
    assert media.shape == case.design.geometry.shape
    support = int((media[0] > 0.5).sum())
    assert 0 < effect.n_params() <= support // PIXELS_PER_MODE < MAX_TERMS


def test_texture_in_a_trench_is_named_and_its_control_is_clean():
    found = make_case(
        "background_texture", modality="fluorescence", fraction_of_sd=0.7, seed=1014
    )
    result = diagnose(
        found.images, found.design, max_steps=1, n_bootstrap=15, rng=np.random.default_rng(1015)
    )
    assert [e.name for e in result.accepted] == ["background_texture"], result.report()
    texture = result.accepted[0]
    assert texture.params["rms_fraction"] > 0
    assert texture.held_out_after < texture.held_out_before
    control = make_case(None, modality="fluorescence", fraction_of_sd=0.7, seed=5014)
    clean = diagnose(
        control.images, control.design, max_steps=1, n_bootstrap=15, rng=np.random.default_rng(5015)
    )
    assert clean.accepted == [], clean.report()
