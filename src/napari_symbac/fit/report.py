"""What a scene fit writes: the cells table, a plain-words report, and an atomic folder.

Works with any :class:`~napari_symbac.fit.SceneFit`: standard errors, warnings and
parameters at bounds are reported when the result carries them (``getattr``).
"""

from __future__ import annotations

import math
import os
import shutil
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "CLI_CAMERA_FIX",
    "COLONY_NOTE",
    "OPEN_PHASE_NOTE",
    "UNMEASURED_READ_NOISE",
    "UNRESOLVED_READ_NOISE",
    "camera_text",
    "cells_counted",
    "cells_records",
    "colony_gains_text",
    "colony_noise_text",
    "fit_notes",
    "fit_problems",
    "mask_labels",
    "model_free_camera_check",
    "parameter_table",
    "read_noise_note",
    "report_problems",
    "report_text",
    "write_atomically",
]

#: Reduced chi-square above which the report says the model misses structure.
CHI2_MISFIT = 2.0
#: Reduced chi-square below which the report says the noise model is too wide (a fit's
#: is 1 +- sqrt(2 / pixels) when the camera is right: 0.5 is far outside for any image).
CHI2_NOISE_TOO_WIDE = 0.5
#: Said of every phase-contrast fit of an open field (CLI report, GUI Auto-fit).
OPEN_PHASE_NOTE = (
    "phase contrast is fitted here with the linear (weak-phase) kernel of eq. 7-14, "
    "which cannot make the bright halos and gaps of dense colonies on a pad "
    "(docs/rendering.md); given instance masks of such a colony, "
    "`napari-symbac fit IMAGE --masks M` fits the partially coherent phase model instead"
)
#: Said of a phase-contrast colony fitted from its masks (:func:`~napari_symbac.fit.fit_colony`).
COLONY_NOTE = (
    "dense colony: the cells are the masks' (not refitted; no standard errors) and the "
    "partially coherent phase model (halo, bright seams) is fitted to them pixel by "
    "pixel, with Gaussian noise of the background's pixel noise (docs/fitting.md)"
)



def cells_counted(n: int) -> str:
    """``"1 cell"``, ``"3 cells"``: a count of cells in a sentence."""
    return f"{n} cell" if n == 1 else f"{n} cells"

def _plain(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def unmeasured_noise_adu(camera: Any) -> float | None:
    """The constant noise (ADU s.d.) of a camera whose gain could not be measured (the
    fit's placeholder gain, :data:`~napari_symbac.fit.scene_fit.UNMEASURED_GAIN_ADU_PER_E`,
    with the read noise carrying all of it), else ``None``."""
    from napari_symbac.fit.scene_fit import UNMEASURED_GAIN_ADU_PER_E

    if camera.sensitivity_adu_per_e != UNMEASURED_GAIN_ADU_PER_E:
        return None
    return camera.sensitivity_adu_per_e * camera.dark_noise_e


def camera_text(camera: Any) -> str:
    """A camera in words with units; one whose gain could not be measured as the constant
    noise it draws (found as a user: "sensitivity 0.001 ADU/e-, dark noise 2.77e+04 e-"
    of a bright-field fit read as a camera)."""
    if (sd := unmeasured_noise_adu(camera)) is not None:
        return (
            f"no gain measurable: a constant noise of {sd:.3g} ADU s.d., baseline "
            f"{camera.baseline_adu:.1f} ADU, {camera.bit_depth} bits"
        )
    return (
        f"sensitivity {camera.sensitivity_adu_per_e:.3g} ADU/e-, baseline "
        f"{camera.baseline_adu:.1f} ADU, dark noise {camera.dark_noise_e:.3g} e-, "
        f"{camera.bit_depth} bits"
    )


def cells_records(result: Any) -> list[dict[str, Any]]:
    """One dict per cell: id, centre, length, width, angle, curvature and every other
    per-cell column of ``result.cells_table()`` (standard errors when it has them)."""
    table = result.cells_table()
    ids = list(table.get("ids", []))
    records = []
    for index, cell_id in enumerate(ids):
        record: dict[str, Any] = {"id": _plain(cell_id)}
        for key, column in table.items():
            if key != "ids" and len(column) == len(ids):
                record[key] = _plain(column[index])
        records.append(record)
    return records


def mask_labels(result: Any, masks: np.ndarray) -> list[int | None]:
    """Per fitted cell (in :func:`cells_records` order), the label of ``masks`` that
    covers most of its camera pixels (a 0/1 mask's connected regions numbered as
    ``scipy.ndimage.label`` numbers them), or None where no mask covers it (a cell the
    fit added). Found as a user: the fit's ids (1..N) named no label of the masks given,
    after the moves had split one of them."""
    from napari_symbac.fit.preflight import as_instance_ids

    instances = np.asarray(as_instance_ids(masks)[0])
    labels = np.asarray(result.scene.camera_labels())
    ids = list(result.cells_table().get("ids", []))
    if labels.shape != instances.shape:
        return [None] * len(ids)
    found: list[int | None] = []
    for cell_id in ids:
        under = instances[(labels == cell_id) & (instances > 0)]
        found.append(int(np.bincount(under).argmax()) if under.size else None)
    return found


def parameter_table(result: Any) -> list[dict[str, Any]]:
    """``[{name, value, se}]`` of the fitted parameters, empty when the result has none."""
    names = tuple(getattr(result, "parameter_names", ()) or ())
    values = getattr(result, "parameters", None)
    errors = getattr(result, "standard_errors", None)
    if not names or values is None:
        return []
    values = np.asarray(values, float)
    errors = np.full(values.shape, np.nan) if errors is None else np.asarray(errors, float)
    return [
        {"name": name, "value": _plain(float(v)), "se": _plain(float(e))}
        for name, v, e in zip(names, values, errors, strict=False)
    ]


#: Said when a camera measured from the image came out with no read noise.
UNMEASURED_READ_NOISE = (
    "the read noise is too small to measure from this image (the noise variance at the "
    "baseline is at or below zero after the shot noise): 0 e- is used; give the camera "
    "(or dark frames) when it matters, e.g. for dim fluorescence"
)
#: Said when it came out with the read noise of an image whose levels lie between whole
#: electrons (:func:`~napari_symbac.fit.camera_estimate.with_unresolved_dark_noise`).
UNRESOLVED_READ_NOISE = (
    "the read noise is too small to measure from this image (the noise variance at the "
    "baseline is at or below zero after the shot noise), but the image holds levels "
    "between whole electrons, so it is not 0: 0.5 e- is used (with none, synthetic pixels "
    "would step by the sensitivity); give the camera (or dark frames) when it matters"
)


def read_noise_note(camera: Any) -> str | None:
    """What to say of a measured camera's read noise: :data:`UNMEASURED_READ_NOISE` for 0,
    :data:`UNRESOLVED_READ_NOISE` for the unresolved one, else None (measured)."""
    from napari_symbac.fit.camera_estimate import MIN_UNRESOLVED_DARK_NOISE_E

    if camera.dark_noise_e == 0:
        return UNMEASURED_READ_NOISE
    if camera.dark_noise_e == MIN_UNRESOLVED_DARK_NOISE_E:
        return UNRESOLVED_READ_NOISE
    return None


#: Lag-2 / lag-1 variance ratio of an image's noise above which it is said to be
#: correlated between neighbours (1 for white noise).
CORRELATED_NOISE_RATIO = 1.1


def neighbour_variance_ratio(frame: Any, camera: Any) -> float:
    """The lag-2 / lag-1 variance ratio of ``frame``'s noise (1 for white noise; a
    resampled or filtered image's is larger), from its photon transfer
    (:func:`~napari_symbac.fit.camera_estimate.estimate_camera`).

    Raises
    ------
    ValueError
        When the image's photon transfer cannot be measured.
    """
    from napari_symbac.fit.camera_estimate import estimate_camera

    estimate = estimate_camera(frame, camera=camera, bit_depth=camera.bit_depth)
    return float(estimate.neighbour_variance_ratio)


#: How ``napari-symbac diagnose`` tells of a camera to give instead of one measured.
CLI_CAMERA_GIVEN = (
    "give the camera (a camera section in the microscope file), e.g. the one "
    "`napari-symbac fit IMAGE --dark DARK.tif` writes to its settings.yaml"
)


def measured_camera_note(
    frame: Any, camera: Any, *, give_camera: str = CLI_CAMERA_GIVEN
) -> tuple[str, float | None]:
    """What the base fit of ``diagnose`` (the command and the dock) measured of the camera,
    and what the image's own photon transfer says of it (correlated noise, or an image
    that is not raw camera counts, whose "camera" is the residual's variance: found as a
    user, the dock said "camera measured from the recording (0.001 ADU/e-, read noise
    3.14e+04 e-)" of ColiCoords' flattened bright field, and no more).

    Returns the note, and the noise's neighbour variance ratio
    (:func:`neighbour_variance_ratio`; ``None`` when the image's photon transfer cannot
    be measured), which the chi-square's caution uses too. ``give_camera`` is how the
    user gives a camera, in the command's or the dock's words."""
    if (sd := unmeasured_noise_adu(camera)) is not None:
        note = (
            "camera not measurable from the recording (its levels span too little, or it "
            f"is not raw counts): a constant noise of {sd:.3g} ADU s.d., baseline "
            f"{camera.baseline_adu:.4g} ADU"
        )
    else:
        note = (
            f"camera measured from the recording: {camera.sensitivity_adu_per_e:.3g} "
            f"ADU/e-, read noise {camera.dark_noise_e:.3g} e-, baseline "
            f"{camera.baseline_adu:.4g} ADU"
        )
    if said := read_noise_note(camera):  # said, as `fit` and Auto-fit say it
        note += f" ({said})"
    if np.asarray(frame).dtype == np.uint8:  # found as a user: an 8-bit PNG of the trench
        # was "measured" at 0.0689 ADU/e-, read noise 15.9 e-, with no word
        note += (
            "; an 8-bit image is mostly a display export scaled from the camera's counts, "
            "whose gain and read noise are of that scaling, not the camera's: give the raw "
            "recording, or the camera"
        )
    try:
        ratio = neighbour_variance_ratio(frame, camera)
    except ValueError as err:
        return f"{note}; the image's own photon transfer: {err}", None
    if ratio > CORRELATED_NOISE_RATIO:
        # the ratio alone: the estimate's whole summary repeated the read noise's note
        # (found as a user: a note of 750 characters, parentheses three deep)
        note += (
            "; its noise is correlated between neighbours (lag-2 / lag-1 variance "
            f"{ratio:.2f}, 1 for white noise), so a gain measured "
            "from one image is biased by about that factor, and camera_noise and the "
            f"held-out gains assume independent pixels: {give_camera}"
        )  # found as a user: "or dark frames", which diagnose does not take
    return note, ratio


def colony_noise_text(result: Any) -> str:
    """The noise of a colony fit (:class:`~napari_symbac.fit.ColonyFit`) in words: the
    image's measured pixel noise and the noise drawn (at least
    :data:`~napari_symbac.fit.colony.MIN_NOISE_ADU`)."""
    measured, drawn = result.measured_noise_adu, result.render.gaussian_noise_sd_adu
    text = f"{measured:.3g} ADU measured from the image's pixel differences"
    if measured == 0:
        text += " (below one grey level: the likelihood's variance is the quantisation's)"
    if drawn > measured:
        text += f"; drawn with {drawn:.3g} ADU, the least, so that synthetic pixels scatter"
    return text


def colony_gains_text(result: Any) -> str | None:
    """Each cell's own optical path of a colony fit in words (None when not fitted)."""
    gains = np.array(list(getattr(result, "cell_gains", {}).values()))
    if not gains.size:
        return None
    low, high = np.percentile(gains, [5, 95])
    return (
        f"each cell's own optical path fitted after the optics: gains {low:.2f}-{high:.2f} "
        f"of the fitted phase (5-95 %), their spread drawn as cell_brightness_cv "
        f"{result.render.cell_brightness_cv:.2f}"
    )


def fit_notes(modality: str, geometry: str, colony: bool = False) -> list[str]:
    """What a fit of this modality and geometry cannot do (said with every such fit);
    ``colony``: a colony fitted from its masks (:func:`~napari_symbac.fit.fit_colony`)."""
    if colony:
        return [COLONY_NOTE]
    return [OPEN_PHASE_NOTE] if modality == "phase" and geometry == "open" else []


#: Cell widths (um) of rod-shaped bacteria: a fit's median outside them most likely
#: comes from a wrong pixel size (E. coli 0.5-1.5 um; ColiCoords' fitted 1.36 um).
BACTERIAL_WIDTH_UM = (0.4, 1.6)


def unusual_width_words(width_um: float) -> str | None:
    """``"unusual for bacteria (0.4-1.6 um): check the pixel size"`` when ``width_um`` is
    outside :data:`BACTERIAL_WIDTH_UM`, else ``None`` (the fit's report and
    ``calibrate``'s warning say it of their cells)."""
    low, high = BACTERIAL_WIDTH_UM
    if low <= width_um <= high:
        return None
    return f"unusual for bacteria ({low:g}-{high:g} um): check the pixel size"


def fit_problems(
    result: Any,
    residual_hint: str = "see residual.tif; `napari-symbac diagnose` looks for it",
) -> list[str]:
    """What did not converge, what sits at a bound, and a fit worse than its start.

    ``residual_hint`` says where the user sees the residual (the CLI's file, the
    GUI's layer) when the model misses structure. The engine's warning of a camera it
    could not measure is left out: the CLI and the docks check the camera themselves
    (:func:`model_free_camera_check`) and say what to do in their own terms.
    """
    from napari_symbac.fit.scene_fit import UNMEASURED_CAMERA

    warnings = [
        str(w) for w in getattr(result, "warnings", ()) or ()
        if not str(w).startswith(UNMEASURED_CAMERA)
    ]
    before, after = result.objective_before, result.objective_after
    misfit = math.isfinite(after) and after > CHI2_MISFIT
    # the engine's own misfit warning is said once, below, with where to look
    problems = [
        f"warning: {w}" for w in warnings if not (misfit and w.startswith("reduced chi-square"))
    ]
    at_bounds = tuple(getattr(result, "at_bounds", ()) or ())
    if at_bounds and not any("bound" in w for w in warnings):
        problems.append(
            "at a bound (its value is a limit, not a measurement; its standard error means "
            f"nothing): {', '.join(at_bounds)}"
        )
    render = getattr(result, "render", None)
    if render is not None and len(getattr(result, "cells", ())) and render.cell_intensity <= 0:
        # the intensities are solved in closed form, never below 0: no engine bound says
        # it (found as a user on DeLTA's normalised trench: "cell_intensity 0 +- 1.97")
        problems.append(
            "at a bound: cell_intensity is 0 ADU, the least the model allows (the cells are "
            "darker than its kernel draws them; a limit, not a measurement)"
        )
    widths = np.asarray(getattr(getattr(result, "cells", None), "width_um", ()), float)
    unusual = unusual_width_words(float(np.median(widths))) if widths.size else None
    if unusual:
        # found as a user: 0.13 um/px for a 0.065 um/px trench fitted 1.8 um wide, 9-10 um
        # long cells at the chi-square of the right pixel size, and nothing said it
        problems.append(
            f"the cells' median width, {np.median(widths):.2f} um, is {unusual} (the fit "
            "measures widths in pixels and converts them with it)"
        )
    worse = math.isfinite(before) and math.isfinite(after) and after > before
    if worse and not any("worse than its start" in w for w in warnings):
        problems.append(
            f"the fit ended worse than its start (chi-square {before:.3g} -> {after:.3g})"
        )
    if math.isfinite(after) and after < CHI2_NOISE_TOO_WIDE:
        # found as a user: a joint fit of ColiCoords ds3, which kept its camera offset
        # (1717 ADU and up), took a 100 ADU baseline, 0.22-0.25, and said nothing
        camera = getattr(result, "camera", None)
        used = (
            f" (baseline {camera.baseline_adu:.4g} ADU, {camera.sensitivity_adu_per_e:.3g} "
            f"ADU/e-, read noise {camera.dark_noise_e:.3g} e-)"
            if camera is not None
            else ""
        )
        problems.append(
            f"reduced chi-square {after:.3g} < {CHI2_NOISE_TOO_WIDE:g}: the camera noise "
            f"the fit used{used} is wider than the image's, so the standard errors are too "
            "large and a dataset rendered with this camera is too noisy; check the "
            "camera's baseline (the level of no light) and gain"
        )
    if misfit:
        errors = getattr(result, "standard_errors", None) is not None
        problems.append(
            f"reduced chi-square {after:.3g} > {CHI2_MISFIT:g}: the model misses structure "
            "beyond the camera noise" + (", so the standard errors are too small" * errors)
            + f" ({residual_hint})"
        )
    return problems


def base_fit_problems(result: Any, microscope: Any, residual_hint: str) -> list[str]:
    """What :func:`fit_problems` and :func:`lens_problem` say of a diagnosis' base fit,
    less its misfit (the diagnosis is there to explain it: a reduced chi-square above
    :data:`CHI2_MISFIT`, a spatially correlated residual). Found as a user: a trench
    diagnosed at twice its pixel size fitted cells 1.81 um wide, which `fit` says and
    `diagnose` did not."""
    problems = [
        p.removeprefix("warning: ") for p in fit_problems(result, residual_hint)
        if "misses structure" not in p and "spatially correlated" not in p
    ]  # fmt: skip
    return problems + ([p] if (p := lens_problem(result.render, microscope)) else [])


def lens_problem(render: Any, microscope: Any) -> str | None:
    """A sentence when a bright-field fit's lens term lies beyond what a cell out of
    focus gives, else None.

    ``kappa = z lambda phi / (2 pi n)`` with the focal plane at most two depths of field
    away (``|z| <= 2 lambda n / NA^2``, as ``focus_offset_um``'s bound) and a cell's phase
    at most 2.1 rad (``cell_phase_rad``'s) gives ``|kappa| <= 2.1 lambda^2 / (pi NA^2)``
    (0.10 um^2 at 0.55 um and NA 1.4; ColiCoords' crop fits 0.015). Beyond it the
    Laplacian stands for something else: another modality, or a wrong pixel size,
    wavelength or NA (docs/physics.md, "Bright field")."""
    from napari_symbac.fit.parameters import parameter_bounds

    if getattr(microscope, "modality", None) != "brightfield":
        return None
    kappa = float(render.defocus_contrast_um2)
    focus_um = parameter_bounds("focus_offset_um", microscope)[1]
    phase_rad = parameter_bounds("cell_phase_rad", microscope)[1]
    n = microscope.refractive_index
    bound = focus_um * microscope.wavelength_um * phase_rad / (2 * math.pi * n)
    if abs(kappa) <= bound:
        return None
    return (
        f"the lens term, kappa = {kappa:+.3g} um^2, is beyond what a cell out of focus "
        f"gives (|kappa| <= {bound:.3g} um^2 within two depths of field): check that the "
        "image is bright field, and the pixel size, wavelength and NA"
    )


#: Ratio of the fit's gain to the model-free gain above which the report warns.
GAIN_RATIO = 1.5
#: How a command-line user fixes the camera (``model_free_camera_check``'s ``fix``).
CLI_CAMERA_FIX = "pass --camera or --dark to fix the camera"


def model_free_camera_check(
    frame: np.ndarray, fitted: Any, fix: str
) -> tuple[str, str | None]:
    """The high-pass photon-transfer gain beside the one a fit measured: ``(text,
    problem)``, the problem ``None`` when they agree.

    Where the fit fell back to its residual (levels spanning too little for photon
    transfer), structure the model lacks inflates the gain, and then a reduced
    chi-square near 1 says nothing; the model-free estimate does not see the model at
    all. ``fit`` is the fitted :class:`~napari_symbac.settings.Camera`; ``fix`` ends
    a problem with what the user can do (the CLI's options, the GUI's way).
    """
    from napari_symbac.fit.camera_estimate import estimate_camera

    try:
        estimate = estimate_camera(frame, camera=fitted, bit_depth=fitted.bit_depth)
    except ValueError as err:
        # found as a user: an 8-bit phase colony fitted without masks placed 8 cells beside
        # its 116, with a camera of 0.001 ADU/e- and 1360 e- read noise that took up the
        # misfit, and PROBLEMS said nothing of it (reduced chi-square near 1)
        gain, noise = fitted.sensitivity_adu_per_e, fitted.dark_noise_e
        words = f"{gain:.3g} ADU/e-, read noise {noise:.3g} e-"
        if (sd := unmeasured_noise_adu(fitted)) is not None:
            words = f"no gain, a constant noise of {sd:.3g} ADU s.d."
        return f"not available ({err})", (
            f"the fit's camera ({words}) cannot be checked against the image's own "
            f"photon transfer ({err}); fitted to the residual, a camera takes up structure "
            "the model lacks, so a chi-square near 1 does not mean the model explains the "
            f"image: check the figure, and {fix}"
        )
    free, fit = estimate.camera.sensitivity_adu_per_e, fitted.sensitivity_adu_per_e
    text = f"sensitivity {free:.3g} +- {estimate.sensitivity_se_adu_per_e:.2g} ADU/e-"
    correlation = estimate.neighbour_variance_ratio
    if correlation > 1:  # correlated noise biases the model-free gain low by about this
        text += f" (noise correlated between neighbours: up to {free * correlation:.3g})"
        free *= correlation
    if fit > GAIN_RATIO * free:
        return text, (
            f"the fit's camera gain ({fit:.3g} ADU/e-) is {fit / free:.1f}x the model-free "
            f"estimate ({free:.3g}): the residual holds structure the model lacks, so a "
            f"chi-square near 1 does not mean the model explains the image; {fix}"
        )
    return text, None


def report_problems(result: Any, extra_problems: Sequence[str] = ()) -> list[str]:
    """The problems report.txt lists under PROBLEMS: :func:`fit_problems`, then the
    caller's ``extra_problems`` (e.g. a camera check)."""
    problems = [*fit_problems(result), *extra_problems]
    if not hasattr(result, "warnings"):
        problems.append(
            "this fit engine reports no convergence diagnostics (no warnings / at_bounds): "
            "check the figure and the residual by eye"
        )
    return problems


def report_text(
    result: Any, facts: Mapping[str, str], extra_problems: Sequence[str] = ()
) -> str:
    """report.txt: the inputs as used, the camera, the outcome, then the problems plainly.

    ``extra_problems`` are findings of the caller (e.g. a camera check) listed with
    those of :func:`fit_problems`.
    """
    lines = ["napari-symbac fit report", ""]
    width = max(len(k) for k in facts) if facts else 0
    lines += [f"{key:<{width}}  {value}" for key, value in facts.items()]
    lines += [
        "",
        f"cells fitted: {len(result.cells)}",
        *_choices(tuple(getattr(result, "moves", ()) or ())),
        "pixel chi-square (reduced; 1 = fitted to the noise): "
        f"{result.objective_before:.4g} (start) -> {result.objective_after:.4g} (fit)",
    ]
    for term, (before, after) in getattr(result, "terms", {}).items():
        lines.append(f"  {term}: {before:.4g} -> {after:.4g}")
    lines += ["", "PROBLEMS"]
    problems = report_problems(result, extra_problems)
    lines += [f"- {p}" for p in problems] if problems else ["none: converged, nothing at a bound"]
    parameters = parameter_table(result)
    if parameters:
        lines += ["", "PARAMETERS (value +- standard error)"]
        for row in parameters:
            se = "n/a" if row["se"] is None else f"{row['se']:.3g}"
            lines.append(f"  {row['name']}: {row['value']:.6g} +- {se}")
    return "\n".join(lines) + "\n"


def _choices(moves: tuple[str, ...]) -> list[str]:
    """report.txt's lines of what the fit chose, under a heading that says what they are
    (found as a user: bare "merged cells at y = ..." lines read as a problem), the
    trench's closed end named only where the fit chose one (found as a user: named for a
    closed end out of view)."""
    if not moves:
        return []
    chose_its_end = any(move.startswith("closed end") for move in moves)
    closed_end = "the trench's closed end; " if chose_its_end else ""
    heading = (
        f"  what the fit chose ({closed_end}cells added, removed, split or merged where the "
        "likelihood asked for it, BIC):"
    )
    return [heading, *(f"    {move}" for move in moves)]


def write_atomically(
    out: str | Path,
    writers: Mapping[str, Callable[[Path], None]],
    replaced: Sequence[Path] = (),
) -> list[Path]:
    """Write every file into a hidden folder beside ``out``, then move them all in.

    ``writers`` maps a relative path to a function that writes it. If any writer fails,
    nothing lands in ``out`` (a folder that did not exist is not created) and nothing is
    removed; else the ``replaced`` files and folders (an earlier run's,
    :func:`~napari_symbac.export.atomic.earlier_run`) are removed before the new ones
    move in.

    Returns
    -------
    list of Path
        The files written, in ``out``.
    """
    from napari_symbac.export.atomic import remove_earlier_run, staging_folder

    out = Path(out)
    staging = staging_folder(out)
    try:
        for name, write in writers.items():
            target = staging / name
            target.parent.mkdir(parents=True, exist_ok=True)
            write(target)
        remove_earlier_run(list(replaced))
        out.mkdir(exist_ok=True)
        written = []
        for name in writers:
            final = out / name
            final.parent.mkdir(parents=True, exist_ok=True)
            os.replace(staging / name, final)
            written.append(final)
        return written
    finally:
        shutil.rmtree(staging, ignore_errors=True)
