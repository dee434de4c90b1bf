"""Detection power of the diagnosis at concealed amplitudes (issue 11): the bend of a
cell in phase contrast, the cross-fitted held-out check and the empirical-Bayes fit
of a random field."""

from __future__ import annotations

import numpy as np
import pytest

from napari_symbac.diagnose.concealed import make_case
from napari_symbac.diagnose.effects import CATALOGUE
from napari_symbac.diagnose.effects.base import Effect
from napari_symbac.diagnose.model import deviance, fit_model
from napari_symbac.diagnose.run import _params
from napari_symbac.diagnose.selection import (
    N_FOLDS,
    ModelSpec,
    checkerboard,
    cross_fitted_deviance,
    folds,
    rank,
)


def _pool(geo, modality):
    return [
        cls(geo)
        for cls in CATALOGUE.values()
        if modality in cls.modalities and not cls.needs_series
    ]


def test_bent_cells_in_phase_are_named_and_the_bend_recovered():
    # the trench walls sit a few pixels beside the cells: a bend model that moved the
    # whole image moved the walls too and lost most of the signal in phase contrast
    case = make_case("cell_curvature", modality="phase", fraction_of_sd=0.5, seed=17)
    y = case.images.astype(float) - case.design.camera.baseline_adu
    valid = np.ones(y.shape, bool)
    pool = _pool(case.design.geometry, "phase")
    current = fit_model(case.design, y, valid)
    ranked = rank(pool, case.design, y, current, valid)
    best, test = ranked[0]
    assert best.name == "cell_curvature", [(e.name, round(t.evidence, 1)) for e, t in ranked]
    assert test.evidence > -np.log10(0.01 / len(pool))
    spec = ModelSpec().with_effect(best, y)
    params = _params(best, spec.fit(case.design, y, valid), spec, case.design)
    assert params["rms_bow_um"] == pytest.approx(case.true_magnitude, rel=0.25)


def test_folds_partition_the_pixels_into_interleaved_lattices():
    shape = (2, 6, 5)
    parts = folds(shape)
    assert len(parts) == N_FOLDS == 4
    np.testing.assert_array_equal(np.sum(parts, axis=0), np.ones(shape, int))
    for fold in parts:
        # no two pixels of a fold touch (4-neighbourhood): each is scored by a fit
        # to all of its neighbours
        assert not (fold[:, 1:] & fold[:, :-1]).any()
        assert not (fold[:, :, 1:] & fold[:, :, :-1]).any()
        assert not (fold[:, 1:, 1:] & fold[:, :-1, :-1]).any()
    np.testing.assert_array_equal(folds(shape, 2), checkerboard(shape))
    with pytest.raises(ValueError, match="n_folds"):
        folds(shape, 3)


def test_cross_fitted_deviance_scores_each_pixel_by_the_other_folds():
    case = make_case(None, modality="fluorescence", fraction_of_sd=0.5, seed=41)
    y = case.images.astype(float) - case.design.camera.baseline_adu
    valid = np.ones(y.shape, bool)
    valid[:, :5] = False
    spec = ModelSpec()
    got = cross_fitted_deviance(case.design, y, valid, spec)
    want = np.zeros(y.shape)
    for fold in folds(y.shape):
        test = fold & valid
        want[test] = deviance(y, spec.fit(case.design, y, valid & ~fold), test)
    np.testing.assert_array_equal(got, want[valid])
    assert got.size == int(valid.sum())


class _Ripple(Effect):
    """``mu + sum_k theta_k B_k``: a few fixed cosine ripples (linear in theta)."""

    name = "ripple"

    def __init__(self, geometry, random_field: bool) -> None:
        super().__init__(geometry)
        rows, cols = geometry.shape[1:]
        y = np.arange(rows)[:, None] / rows
        self.basis = np.stack([np.cos(np.pi * k * y) * np.ones((1, cols)) for k in (5, 7, 9, 11)])
        self.random_field = random_field

    def n_params(self) -> int:
        return len(self.basis)

    def mean(self, theta, mu, parts, geo):
        return mu + np.tensordot(theta, self.basis, axes=1)[None]


def _ripple_fits(seed: int, amplitude_adu: float):
    case = make_case(None, modality="fluorescence", fraction_of_sd=0.5, seed=seed)
    geo = case.design.geometry
    truth = np.array([1.0, -0.5, 0.8, 0.3]) * amplitude_adu
    y = case.images.astype(float) - case.design.camera.baseline_adu
    y = y + _Ripple(geo, False).mean(truth, np.zeros(y.shape), None, geo)
    valid = np.ones(y.shape, bool)
    free, shrunk = _Ripple(geo, False), _Ripple(geo, True)
    fit_free = fit_model(case.design, y, valid, [(free, free.null())])
    fit_shrunk = fit_model(case.design, y, valid, [(shrunk, shrunk.null())])
    return fit_free.effects[0][1], fit_shrunk.effects[0][1]


def test_random_field_is_the_free_fit_shrunk_towards_zero():
    free, shrunk = _ripple_fits(seed=43, amplitude_adu=1.2)
    factor = float(shrunk @ free / (free @ free))
    assert 0.2 < factor < 0.98  # shrunk, by one common factor (Zellner's g-prior)
    np.testing.assert_allclose(shrunk, factor * free, rtol=0.02, atol=1e-3)


def test_random_field_without_signal_stays_at_zero():
    hits = 0
    for seed in (44, 45, 46, 47):
        free, shrunk = _ripple_fits(seed=seed, amplitude_adu=0.0)
        assert np.all(np.abs(free) > 0)
        # |z|^2 / k <= 1 happens about half the time under no effect; then theta = 0
        hits += int(np.all(np.abs(shrunk) < 1e-6 * np.abs(free).max()))
        assert np.linalg.norm(shrunk) < np.linalg.norm(free)
    assert hits >= 1
