"""The diagnosis: statistics, ranking, stepwise acceptance, results (issue 11)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from napari_symbac.arguments import require_argument
from napari_symbac.diagnose.effects import CATALOGUE
from napari_symbac.diagnose.effects.base import Confirmation, Effect
from napari_symbac.diagnose.model import BaseDesign, FittedModel, build_design
from napari_symbac.diagnose.selection import ModelSpec, cross_fitted_deviance, held_out, rank
from napari_symbac.diagnose.statistics import (
    Mismatch,
    discrepancy_statistics,
    significance_words,
)
from napari_symbac.fit.inputs import as_image_stack
from napari_symbac.fit.preflight import API_CAMERA_HINT, check_fit_image
from napari_symbac.settings import Camera, Microscope, RenderSettings

__all__ = ["Diagnosis", "EffectResult", "diagnose", "diagnose_scenes"]


@dataclass
class EffectResult:
    """One candidate effect: evidence, whether accepted, fitted parameters, held-out numbers."""

    name: str
    explanation: str
    signature: str
    evidence: float
    dof: int
    accepted: bool
    params: dict[str, Any]
    held_out_before: float
    held_out_after: float
    held_out_gain_nats: float = 0.0
    null_threshold_nats: float = float("nan")
    null_replicates: int = 0
    step: int = 0
    effect_map: np.ndarray | None = field(default=None, repr=False)
    #: the effect's own check (:meth:`Effect.confirm`), when it passed the held-out one
    confirmation: Confirmation | None = None
    #: the step of the held-out check whose numbers these are: an earlier one than
    #: ``step`` when the effect's own check refused it again first (not repeated then)
    held_out_step: int = 0

    def as_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "explanation": self.explanation,
            "evidence": _finite(self.evidence),
            "accepted": self.accepted,
            "params": self.params,
            "held_out_before": _finite(self.held_out_before),
            "held_out_after": _finite(self.held_out_after),
            "held_out_gain_nats": _finite(self.held_out_gain_nats),
            "null_threshold_nats": _finite(self.null_threshold_nats),
            "null_replicates": self.null_replicates,
            "score_dof": self.dof,
            "signature": self.signature,
            "step": self.step,
            "held_out_step": self.held_out_step,
            "held_out_tested": self.held_out_step > 0,
            "confirmation": None
            if self.confirmation is None
            else {
                "confirmed": self.confirmation.confirmed,
                "reason": self.confirmation.reason,
                **self.confirmation.numbers,
            },
        }


def _finite(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


#: Reduced chi-square of a base fit above which its scene, not missing physics, is the
#: likely misfit (:meth:`Diagnosis.cautions`; the real trench's is 15.5, a dense colony
#: fitted without masks 301).
POOR_BASE_FIT_CHI2 = 50.0
#: Final reduced chi-square below which the noise model overstates the image's noise.
OVERSTATED_NOISE_CHI2 = 0.8
#: Gaussian sigma (px) of the residual maps as residuals.png and the report show them.
RESIDUAL_SMOOTHING_PX = 2.0


@dataclass
class Diagnosis:
    """Outcome of :func:`diagnose`.

    Attributes
    ----------
    base_fit, final_fit
        ``{"metric", "value", "held_out"}``: reduced chi-square on all pixels and the
        mean held-out deviance per pixel (``-2 log L``; each of four interleaved pixel
        lattices scored by the fit to the other three).
    mismatches
        Discrepancy statistics of the base fit, most significant first.
    effects
        Every candidate tested, accepted first, then by evidence.
    residual_before, residual_after
        Standardised residuals ``(T, Y, X)`` of the base and final models.
    threshold
        Evidence (``-log10 p``) a score test needs (Bonferroni over the candidates).
    skipped
        Candidates not tested (they need a time series, another modality or more cells).
    max_steps
        The most effects a diagnosis accepts: candidates above ``threshold`` that were
        never held-out tested when it stopped there are said so in the report.
    valid
        ``(T, Y, X)``: the pixels the final fit is judged on (not clipped, not masked).
    """

    base_fit: dict[str, Any]
    final_fit: dict[str, Any]
    mismatches: list[Mismatch]
    effects: list[EffectResult]
    residual_before: np.ndarray = field(repr=False)
    residual_after: np.ndarray = field(repr=False)
    final_model: FittedModel = field(repr=False)
    threshold: float = 0.0
    skipped: tuple[str, ...] = ()
    max_steps: int = 4
    valid: np.ndarray | None = field(default=None, repr=False)

    @property
    def accepted(self) -> list[EffectResult]:
        return [e for e in self.effects if e.accepted]

    def explained_fraction(self) -> float | None:
        """The share of the base fit's excess reduced chi-square (above 1, noise alone)
        that the accepted effects explain; ``None`` when the base fit has no excess."""
        before, after = self.base_fit["value"], self.final_fit["value"]
        if not before > 1:
            return None
        return (before - after) / (before - 1)

    def cautions(
        self,
        residual_hint: str = "see residuals.png",
        camera_fix: str = "give the camera (the microscope file's camera section)",
    ) -> list[str]:
        """Why the findings may not be physics, in words (found as a user: a dense
        colony whose base fit placed 2 cells for ~20, reduced chi-square 301, got four
        effects, "fixed pattern noise" among them, without a word; a bright field whose
        camera the image could not measure got effects of 0.04 % at chi-square 0.53).
        ``residual_hint`` and ``camera_fix`` say where the residual is and how to give
        the camera, in the interface's words (the command's by default)."""
        said = []
        base, final = self.base_fit["value"], self.final_fit["value"]
        if base > POOR_BASE_FIT_CHI2:
            said.append(
                f"the base fit leaves a reduced chi-square of {base:.3g} (1 is noise alone, "
                f"above {POOR_BASE_FIT_CHI2:g} the scene itself is wrong: cells missed, "
                f"merged or misplaced; {residual_hint}): effects found on top of it may "
                "stand in for what the fit missed, so check the fit before trusting them"
            )
        if self.accepted and final < OVERSTATED_NOISE_CHI2:
            said.append(
                f"the final reduced chi-square is {final:.3g}, below 1: the noise model "
                "overstates this image's noise (a camera the image could not measure), so "
                "the held-out checks are miscalibrated and effects too small to matter can "
                f"pass them; {camera_fix}"
            )
        return said

    def _untested(self, effect: EffectResult) -> bool:
        """A candidate above the evidence needed that no held-out check reached (the
        diagnosis stopped first, or tried others in its step)."""
        return (
            not effect.accepted
            and effect.held_out_step == 0
            and effect.evidence >= self.threshold
        )

    def as_dict(self) -> dict[str, Any]:
        """The ``diagnosis.json`` document of issue 11."""
        return {
            "base_fit": self.base_fit,
            "mismatches": [m.as_dict() for m in self.mismatches],
            "effects": [e.as_dict() for e in self.effects],
            "final_fit": self.final_fit,
            "evidence_threshold": self.threshold,
            "significance_units": "-log10 p",
            "held_out_units": (
                "mean -2 log-likelihood per held-out pixel (4 pixel lattices, cross-fitted)"
            ),
            "not_tested": list(self.skipped),
        }

    def report(
        self,
        residual_hint: str = "see residuals.png",
        camera_fix: str = "give the camera (the microscope file's camera section)",
    ) -> str:
        """A short plain-text report; its cautions say ``residual_hint`` and
        ``camera_fix`` in the interface's words (:meth:`cautions`)."""
        lines = [
            "Diagnosis of the mismatch between the fitted model and the recording",
            f"base fit: reduced chi-square {self.base_fit['value']:.4f}, held-out deviance "
            f"{self.base_fit['held_out']:.5f} per pixel",
            *(f"CAUTION: {caution}" for caution in self.cautions(residual_hint, camera_fix)),
            "",
            "Most significant discrepancy statistics (-log10 p; > 2 is unusual for noise):",
        ]
        for m in self.mismatches[:8]:
            lines.append(
                f"  {significance_words(m.significance):>8s}  {m.where}: {m.statistic} = "
                f"{m.value:.4g}"
            )
        lines += ["", f"Effects (score-test evidence needed: {self.threshold:.2f}):"]
        for e in self.effects:
            verdict = "ACCEPTED" if e.accepted else "not accepted"
            if self._untested(e):  # found as a user: said "not accepted" as if tested
                verdict = "not held-out tested"
            lines.append(
                f"  {e.name:28s} evidence {significance_words(e.evidence):>8s}  {verdict}"
            )
            earlier = 0 < e.held_out_step != e.step  # its own check refused it again first
            if e.accepted or math.isfinite(e.null_threshold_nats):
                lines.append(
                    f"      held-out gain {e.held_out_gain_nats:.1f} nats "
                    f"(needed: > {e.null_threshold_nats:.1f}, a gain noise alone rarely "
                    "reaches); "
                    f"deviance {e.held_out_before:.5f} -> {e.held_out_after:.5f}"
                    + (f" (step {e.held_out_step})" if earlier else "")
                )
            if e.confirmation is not None and e.confirmation.reason:
                said = f"step {e.step}: " if earlier else ""
                lines.append(f"      {said}{e.confirmation.reason}")
            if e.accepted:
                lines.append(f"      {e.explanation}")
                finding = getattr(CATALOGUE.get(e.name), "finding", None)
                said = finding(e.params) if finding is not None else ""
                if said:
                    lines.append(f"      here: {said}")
                short = {k: v for k, v in e.params.items() if not isinstance(v, (list, dict))}
                lines.append(f"      parameters: {short}")
        untested = [e.name for e in self.effects if self._untested(e)]
        if untested and len(self.accepted) >= self.max_steps:
            most = f"{self.max_steps} effect" + ("" if self.max_steps == 1 else "s")
            lines.append(
                f"  (a diagnosis accepts at most {most}: "
                f"{', '.join(untested)} stand above the evidence needed but were not "
                "held-out tested after them; --max-effects N, or the Diagnose dock's 'at "
                "most (effects)', raises it)"
            )
        if not self.accepted:
            lines += [
                "",
                "Nothing significant: no effect improved the held-out pixels beyond noise.",
            ]
        if self.skipped:
            lines.append(
                "not tested (need a time series, another modality or more cells): "
                + ", ".join(self.skipped)
            )
        lines += [
            "",
            f"final fit: reduced chi-square {self.final_fit['value']:.4f}, held-out deviance "
            f"{self.final_fit['held_out']:.5f} per pixel",
        ]
        explained = self.explained_fraction()
        if self.accepted and explained is not None:  # found as a user: only deviances
            lines.append(  # said, not how much of the misfit is left
                f"the accepted effects explain {explained:.0%} of the base fit's misfit "
                f"beyond noise (reduced chi-square {self.base_fit['value']:.3g} -> "
                f"{self.final_fit['value']:.3g}); the rest is in residuals.png (after)"
            )
        lines.append(self._largest_misfit())
        return "\n".join(lines)

    def _largest_misfit(self) -> str:
        """Where the final model misses most (found as a user: the report never pointed at
        the top cell that residuals.png showed unchanged after the effects): the peak of
        the first frame's residual smoothed as residuals.png shows it."""
        from scipy import ndimage

        residual = np.asarray(self.residual_after[0], float)
        fitted = np.isfinite(residual)  # clipped (censored) pixels are no misfit
        if self.valid is not None:
            fitted &= np.asarray(self.valid[0], bool)
        smooth = ndimage.gaussian_filter(np.where(fitted, residual, 0.0), RESIDUAL_SMOOTHING_PX)
        row, col = np.unravel_index(int(np.argmax(np.abs(smooth))), smooth.shape)
        value = float(smooth[row, col])
        side = "brighter" if value > 0 else "darker"
        return (
            f"largest remaining misfit: row {row}, column {col} of the diagnosed window "
            f"(frame 0), the image {side} than the model there ({value:+.2g} s.d. smoothed "
            f"over {RESIDUAL_SMOOTHING_PX:g} px)"
        )


def _fit_summary(
    y: np.ndarray, model: FittedModel, spec: ModelSpec, design: BaseDesign, valid: np.ndarray
) -> dict:
    chi2 = float(np.mean(((y - model.mu) ** 2 / model.var)[valid]))
    return {
        "metric": "reduced chi-square (camera variance of eq. 17)",
        "value": chi2,
        "held_out": float(cross_fitted_deviance(design, y, valid, spec).mean()),
    }


def diagnose(
    images: np.ndarray,
    design: BaseDesign,
    *,
    candidates: Sequence[str] | str | None = None,
    alpha: float = 0.01,
    n_bootstrap: int = 30,
    max_steps: int = 4,
    max_tries: int = 3,
    rng: np.random.Generator | None = None,
    valid: np.ndarray | None = None,
    progress: Callable[[int, int], None] | None = None,
    cancel: Callable[[], bool] | None = None,
) -> Diagnosis:
    """Locate, name, fit and verify the effects missing from a base fit.

    Parameters
    ----------
    images
        The recording, ``(Y, X)`` or ``(T, Y, X)`` ADU with the camera baseline.
    design
        The base model (:func:`~napari_symbac.diagnose.model.build_design`).
    candidates
        Effect names to try, or one name (default: the whole catalogue).
    alpha
        Family-wise level of the score tests (Bonferroni) and level of the bootstrap
        held-out criterion.
    n_bootstrap
        Parametric-bootstrap replicates per held-out check.
    max_steps, max_tries
        Effects accepted at most; candidates fitted per step.
    rng
        Generator of the bootstrap (same seed, same result).
    valid
        Pixels to use (False: censored); default all.
    progress
        Called with ``(held-out checks done, the most there can be)`` after each check,
        and with ``(done, done)`` when the diagnosis ends (it usually ends sooner).
    cancel
        ``cancel()`` returning True stops the diagnosis (raises ``InterruptedError``).

    Raises
    ------
    TypeError
        ``design`` or ``rng`` of the wrong kind.
    ValueError
        Images the model cannot produce (NaN, RGB, negative or normalised values) or
        not of the fitted scenes' shape, an unknown effect, ``alpha`` outside (0, 1) or
        a count below 1.

    Notes
    -----
    The BLAS library runs single-threaded inside: the diagnosis does many small matrix
    products, on which a threaded OpenBLAS spins (one loaded-machine case took 202 CPU s
    with the default threads and 3.9 s with one). The result does not depend on it.
    """
    with threadpool_limits(limits=1, user_api="blas"):
        return _diagnose(
            images,
            design,
            candidates=candidates,
            alpha=alpha,
            n_bootstrap=n_bootstrap,
            max_steps=max_steps,
            max_tries=max_tries,
            rng=rng,
            valid=valid,
            progress=progress,
            cancel=cancel,
        )


def _check_counts(alpha: float, n_bootstrap: int, max_steps: int, max_tries: int) -> None:
    """Refuse a significance level outside (0, 1) and counts below 1 (found as an API
    user: ``alpha=5`` and ``max_steps=-2`` were taken, the latter returning nothing)."""
    if isinstance(alpha, bool) or not isinstance(alpha, (int, float)) or not 0 < alpha < 1:
        raise ValueError(
            f"diagnose(alpha=...) is a significance level in (0, 1), e.g. 0.01; got {alpha!r}"
        )
    counts = {"n_bootstrap": n_bootstrap, "max_steps": max_steps, "max_tries": max_tries}
    for name, value in counts.items():
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise ValueError(
                f"diagnose({name}=...) must be a whole number of at least 1; got {value!r}"
            )


def _diagnose(
    images: np.ndarray,
    design: BaseDesign,
    *,
    candidates: Sequence[str] | None,
    alpha: float,
    n_bootstrap: int,
    max_steps: int,
    max_tries: int,
    rng: np.random.Generator | None,
    valid: np.ndarray | None,
    progress: Callable[[int, int], None] | None,
    cancel: Callable[[], bool] | None,
) -> Diagnosis:
    """The body of :func:`diagnose` (BLAS threads already limited)."""
    require_argument(design, BaseDesign, "diagnose(design=...)")
    require_argument(rng, np.random.Generator, "diagnose(rng=...)", optional=True)
    _check_counts(alpha, n_bootstrap, max_steps, max_tries)
    y = as_image_stack(images, name="images")  # found as an API user: a NaN pixel gave NaNs
    check_fit_image(y, "images", camera_hint=API_CAMERA_HINT)
    if y.shape != design.geometry.shape:
        raise ValueError(
            f"the image has shape {y.shape} but the fitted scenes {design.geometry.shape}: "
            "fit the scene of every frame"
        )
    rng = np.random.default_rng(0) if rng is None else rng
    baseline = design.camera.baseline_adu
    y = y - baseline
    valid = np.ones(y.shape, bool) if valid is None else np.broadcast_to(valid, y.shape)
    if isinstance(candidates, str):  # one effect's name (found as a user: split in letters)
        candidates = [candidates]
    names = list(CATALOGUE) if candidates is None else list(candidates)
    unknown = [n for n in names if n not in CATALOGUE]
    if unknown:
        raise ValueError(f"unknown effects {unknown}; the catalogue has {sorted(CATALOGUE)}")
    geo = design.geometry
    skipped = []
    pool: list[Effect] = []
    for n in names:
        cls = CATALOGUE[n]
        if (cls.needs_series and geo.shape[0] < 3) or geo.modality not in cls.modalities:
            skipped.append(n)
            continue
        effect = cls(geo)
        if effect.kind == "mean" and effect.n_params() == 0:
            skipped.append(n)
            continue
        pool.append(effect)
    threshold = float(-np.log10(alpha / max(len(pool), 1)))
    spec = ModelSpec()
    current = spec.fit(design, y, valid)
    base_model = current
    r0 = (y - current.mu) / np.sqrt(current.var)
    mismatches = discrepancy_statistics(r0, current.mu, geo, valid)
    base_summary = _fit_summary(y, current, spec, design, valid)
    results: dict[str, EffectResult] = {}
    done = 0
    for step in range(1, max_steps + 1):
        remaining = [e for e in pool if not (e.name in results and results[e.name].accepted)]
        if not remaining:
            break
        ranked = rank(remaining, design, y, current, valid)
        # The most held-out checks still possible: this step's tries above the
        # threshold, then every later step's, so the total only shrinks as it is learnt.
        possible_now = sum(test.evidence >= threshold for _, test in ranked[:max_tries])
        total = done + possible_now + (max_steps - step) * max_tries
        if progress is not None and done:
            progress(done, total)
        for effect, test in ranked:
            old = results.get(effect.name)
            if old is not None and _refused(old):
                # an earlier step's refusal by the effect's own check, and the held-out
                # check it had passed, stay said until new checks replace them
                results[effect.name] = dataclasses.replace(
                    old, evidence=test.evidence, dof=test.dof
                )
            elif old is None or not old.accepted:
                results[effect.name] = EffectResult(
                    effect.name,
                    effect.explanation,
                    effect.signature,
                    test.evidence,
                    test.dof,
                    False,
                    {},
                    base_summary["held_out"],
                    base_summary["held_out"],
                )
        # Strongest evidence first (``rank``). camera_noise is not moved ahead: a large
        # misfit of the mean inflates the residual variance, so its variance score is
        # significant beside every strong mean effect (it was accepted first, wrongly,
        # beside uneven_illumination, stage_drift and fixed_pattern_noise).
        accepted_now = None
        current_deviance = None  # the current model's held-out deviance, once per step
        for effect, test in ranked[:max_tries]:
            if test.evidence < threshold:
                break
            if cancel is not None and cancel():
                raise InterruptedError("diagnosis cancelled")
            res = results[effect.name]
            trial_spec = spec.with_effect(effect, y)
            trial = None
            if _refused(res):
                # Its own check refused it at an earlier step: that check is asked first
                # now (one fit, where the held-out check fits a bootstrap of dozens),
                # and only a fit that the effects accepted since let pass goes on to
                # the held-out check. A refusal costs the try, as it did before.
                trial = trial_spec.fit(design, y, valid)
                confirmation = _confirmation(effect, trial, y, valid)
                res.step = step
                if not confirmation.confirmed:
                    res.confirmation = confirmation
                    continue
            if current_deviance is None:
                current_deviance = cross_fitted_deviance(design, y, valid, spec)
            check = held_out(
                effect,
                design,
                y,
                spec,
                current,
                valid,
                rng,
                n_bootstrap=n_bootstrap,
                alpha=alpha,
                baseline_adu=baseline,
                cancel=cancel,
                current_deviance=current_deviance,
            )
            done += 1
            if progress is not None:
                progress(done, total)
            res.held_out_before, res.held_out_after = check.before, check.after
            res.held_out_gain_nats, res.null_threshold_nats = check.gain_nats, check.threshold_nats
            res.null_replicates = check.replicates
            res.step = res.held_out_step = step
            res.confirmation = None
            if not check.passed:
                continue
            # the effect's own physical check, on the fit it would be accepted with
            if trial is None:
                trial = trial_spec.fit(design, y, valid)
                confirmation = _confirmation(effect, trial, y, valid)
            res.confirmation = confirmation
            if confirmation.confirmed:
                accepted_now = effect
                break
        if accepted_now is None:
            break
        spec = trial_spec
        before_mu = current.mu
        current = trial
        res = results[accepted_now.name]
        res.accepted = True
        res.params = _params(accepted_now, current, spec, design)
        res.effect_map = (
            current.mu - before_mu
            if accepted_now.kind == "mean"
            else np.sqrt(current.var) - np.sqrt(base_model.var)
        )
    if progress is not None and done:
        progress(done, done)  # stopped before the most possible checks: done all the same
    # parameters of accepted effects after the last joint fit
    for e in spec.effects:
        results[e.name].params = _params(e, current, spec, design)
    r1 = (y - current.mu) / np.sqrt(current.var)
    valid_final = valid
    if spec.censor is not None:  # a clipped pixel's residual is its expected one
        clipped = spec.censor.mask(y)
        r1 = np.where(clipped, spec.censor.standardised_mean(current.mu, current.var), r1)
        valid_final = valid & ~clipped
    final_summary = _fit_summary(y, current, spec, design, valid)
    final_summary["value"] = float(np.mean(r1[valid_final] ** 2))
    ordered = sorted(
        results.values(), key=lambda e: (not e.accepted, e.step if e.accepted else 0, -e.evidence)
    )
    return Diagnosis(
        base_summary,
        final_summary,
        mismatches,
        ordered,
        r0,
        r1,
        current,
        threshold,
        tuple(skipped),
        max_steps,
        valid_final,
    )


def _refused(result: EffectResult) -> bool:
    """Whether the effect's own check (:meth:`Effect.confirm`) refused it last."""
    return result.confirmation is not None and not result.confirmation.confirmed


def _confirmation(
    effect: Effect, model: FittedModel, y: np.ndarray, valid: np.ndarray
) -> Confirmation:
    """:meth:`Effect.confirm` of ``effect`` as fitted in ``model``: a mean effect's
    parameters and the pixels its fit used; variance and censor effects have no mean
    parameters (the catalogue's keep the default, confirmed)."""
    if effect.kind != "mean":
        return effect.confirm(np.zeros(0), y - model.mu, valid, model.mu)
    theta = next(t for e, t in model.effects if e is effect)
    fitted = valid & ~model.censor.mask(y) if model.censor is not None else valid
    return effect.confirm(np.asarray(theta, float), y - model.mu, fitted, model.mu)


def _params(
    effect: Effect, model: FittedModel, spec: ModelSpec, design: BaseDesign
) -> dict[str, Any]:
    if effect.kind == "variance":
        return effect.summary(np.array([model.gain, model.read]), model.mu)
    if effect.kind == "censor":
        c = spec.censor
        assert c is not None
        return {
            "clip_level_adu": c.level_adu + design.camera.baseline_adu,
            "high": c.high,
        }
    index = next(i for i, (e, _) in enumerate(model.effects) if e is effect)
    theta = model.effects[index][1]
    if effect.random_field and model.shrinkage[index] > 0:
        # the fitted field is the free fit shrunk by s; its size is reported from the
        # free fit times sqrt(s), which is unbiased for the field's squared norm
        theta = theta / np.sqrt(model.shrinkage[index])
    out = effect.summary(theta, model.mu)
    if effect.name == "photobleaching":
        out["cell_intensity_adu"] = float(model.beta[0])
    return out


def diagnose_scenes(
    images: np.ndarray,
    scenes: Sequence[Any],
    microscope: Microscope,
    render: RenderSettings,
    camera: Camera,
    **kwargs: Any,
) -> Diagnosis:
    """:func:`diagnose` from fitted scenes (one per frame) and forward-model settings."""
    return diagnose(images, build_design(scenes, microscope, render, camera), **kwargs)
