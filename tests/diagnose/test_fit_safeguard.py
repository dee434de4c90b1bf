"""The diagnosis fit never runs away: a Gauss-Newton step that does not lower the
weighted cost is halved (issue 11; a background-subtracted ColiCoords field sent the
texture fit to overflow and the whole diagnosis ended in "SVD did not converge")."""

from __future__ import annotations

import numpy as np

from napari_symbac.diagnose.concealed import make_case
from napari_symbac.diagnose.effects.base import Effect
from napari_symbac.diagnose.model import deviance, fit_model


def _case(seed: int):
    case = make_case(None, modality="fluorescence", fraction_of_sd=0.5, seed=seed)
    y = case.images.astype(np.float64) - case.design.camera.baseline_adu
    ramp = np.linspace(-1.0, 1.0, y.shape[1])[None, :, None] * np.ones(y.shape)
    return case.design, y, ramp


class _Ramp(Effect):
    """``mu + scale theta^power ramp``: linear for ``power = 1``; for ``power = 3``
    deliberately ill-posed (its Jacobian at ``theta = 0`` is nearly zero and kept
    over the fit's rounds, so the undamped step lands far out)."""

    name = "ramp"

    def __init__(self, geometry, ramp, power: int, scale: float) -> None:
        super().__init__(geometry)
        self.ramp, self.power, self.scale = ramp, power, scale

    def n_params(self) -> int:
        return 1

    def steps(self, theta: np.ndarray) -> np.ndarray:
        return np.full(1, 1e-2)

    def mean(self, theta, mu, parts, geo):
        return mu + self.scale * theta[0] ** self.power * self.ramp


def _planted(design, y, ramp, amplitude_adu: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    mask = np.ones(y.shape, bool)
    base = fit_model(design, y, mask)
    noise = np.random.default_rng(seed).normal(0.0, np.sqrt(base.var))
    return base.mu + amplitude_adu * ramp + noise, mask


def test_an_ill_posed_effect_keeps_the_fit_finite_and_better():
    design, y, ramp = _case(7)
    data, mask = _planted(design, y, ramp, 25.0, 9)
    without = fit_model(design, data, mask)
    cubic = _Ramp(design.geometry, ramp, power=3, scale=1e3)
    fitted = fit_model(design, data, mask, [(cubic, np.zeros(1))])
    theta = fitted.effects[0][1]
    assert np.all(np.isfinite(fitted.mu))
    assert np.all(np.isfinite(theta))
    assert 0.0 < theta[0] < 1.0  # 1e3 theta^3 = 25 at theta 0.29; the raw first step is 250
    assert deviance(data, fitted, mask).sum() < deviance(data, without, mask).sum()


def test_a_linear_effect_takes_the_full_step():
    """For linear effects (the catalogue's) the full Gauss-Newton step lowers the cost
    and is taken: the planted amplitude is recovered."""
    design, y, ramp = _case(8)
    data, mask = _planted(design, y, ramp, 25.0, 9)
    linear = _Ramp(design.geometry, ramp, power=1, scale=1.0)
    fitted = fit_model(design, data, mask, [(linear, np.zeros(1))])
    assert abs(fitted.effects[0][1][0] - 25.0) < 1.0


class _Float32Ramp(_Ramp):
    """A linear ramp whose mean is rounded to float32, as the rendered components are:
    its finite-difference Jacobian carries rounding noise of ~1e-4."""

    def steps(self, theta: np.ndarray) -> np.ndarray:
        return np.full(1, 1e-3)

    def mean(self, theta, mu, parts, geo):
        return (mu + theta[0] * self.ramp).astype(np.float32).astype(np.float64)


def test_collinear_effects_with_a_rounded_jacobian_still_fit():
    """Two effects with the same pattern (as a texture's column modes and per-column
    offsets nearly are), Jacobian by finite differences of float32 means: the undamped
    step is wild along their common direction and every joint fit ended at its start
    (the ColiCoords field: 1.1 nats per pixel worse than either effect alone); damped
    steps fit the data as well as one effect does."""
    design, y, ramp = _case(8)
    data, mask = _planted(design, y, ramp, 25.0, 9)
    one = _Float32Ramp(design.geometry, ramp, power=1, scale=1.0)
    twin = _Float32Ramp(design.geometry, ramp, power=1, scale=1.0)
    alone = fit_model(design, data, mask, [(one, np.zeros(1))])
    both = fit_model(design, data, mask, [(one, np.zeros(1)), (twin, np.zeros(1))])
    assert np.all(np.isfinite(both.mu))
    assert deviance(data, both, mask).sum() <= deviance(data, alone, mask).sum() + 1.0
    assert abs(sum(t[0] for _, t in both.effects) - 25.0) < 1.0


def test_the_jacobian_reapplies_only_the_effects_from_the_one_it_differentiates():
    """``_jacobian`` differences each effect from the mean entering it (issue 11's
    speed): the same columns, bit for bit, as differences of whole predictions,
    for a chain whose effects act on what comes before them (illumination times
    the mean, stray light and fixed-pattern offsets added)."""
    from napari_symbac.diagnose.effects import CATALOGUE
    from napari_symbac.diagnose.model import _jacobian, predict

    design, y, _ = _case(3)
    beta = fit_model(design, y, np.ones(y.shape, bool)).beta
    rng = np.random.default_rng(0)
    effects = []
    for name in ("uneven_illumination", "stray_light", "fixed_pattern_noise"):
        effect = CATALOGUE[name](design.geometry)
        effects.append((effect, 0.01 * rng.standard_normal(effect.n_params())))
    mu = predict(design, beta, effects)
    expected = []
    for i, (effect, theta) in enumerate(effects):
        for k, step in enumerate(effect.steps(theta)):
            up, down = theta.copy(), theta.copy()
            up[k] += step
            down[k] -= step
            chain_up = [*effects[:i], (effect, up), *effects[i + 1 :]]
            chain_down = [*effects[:i], (effect, down), *effects[i + 1 :]]
            expected.append(
                (predict(design, beta, chain_up) - predict(design, beta, chain_down)) / (2 * step)
            )
    columns = _jacobian(design, beta, effects, mu)
    assert columns.shape[0] == len(beta) + len(expected)
    np.testing.assert_array_equal(columns[len(beta) :], np.stack(expected))
    assert np.abs(columns[len(beta) :]).max() > 0
