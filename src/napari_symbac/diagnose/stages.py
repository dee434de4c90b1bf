"""Accepted effects as forward-model stages and updated settings (for render / export).

The diagnosis writes ``settings.yaml``, a :class:`~napari_symbac.settings.PipelineSettings`
that carries every accepted effect render and export can draw: those that map onto
existing settings (``camera_noise`` -> the camera, ``cell_intensity_variability`` ->
``render.cell_brightness_cv``, ``background_texture`` -> ``render.texture_amplitude``,
``cell_curvature`` -> ``simulation.do_transformation``, ``envelope_stain`` ->
``render.envelope_stain_fraction``) and the other effects of one
frame (:data:`DRAWN`) as ``extra_stages``, drawn with :func:`drawn_stages`. It also
writes ``extra_stages.yaml``: every accepted effect without a settings field, the
time-dependent ones (:data:`TIME_DEPENDENT`) included, which :func:`load_extra_stages`
turns back into :class:`~napari_symbac.optics.forward.Stage` objects for
``ForwardModel(..., extra_stages=...)``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from napari_symbac.diagnose.effects import (
    camera_noise,
    defocus_gradient,
    fixed_pattern_noise,
    halo,
    photobleaching,
    saturation,
    stage_drift,
    stray_light,
    uneven_illumination,
)
from napari_symbac.optics.forward import Stage
from napari_symbac.settings import (
    ExtraStage,
    PipelineSettings,
    RenderSettings,
    read_settings_mapping,
)

__all__ = [
    "DRAWN",
    "IN_SETTINGS",
    "TIME_DEPENDENT",
    "check_drawn_stage",
    "drawn_by_export",
    "drawn_stages",
    "load_extra_stages",
    "refitted_render",
    "stage_for",
    "updated_settings",
]

_STATIC = {
    "uneven_illumination": uneven_illumination.stage,
    "halo": halo.stage,
    "defocus_gradient": defocus_gradient.stage,
    "stray_light": stray_light.stage,
    "fixed_pattern_noise": fixed_pattern_noise.stage,
}
#: Effects that change from frame to frame of the recording: kept in extra_stages.yaml.
TIME_DEPENDENT = {"photobleaching": photobleaching.stage, "stage_drift": stage_drift.stage}
#: Effects carried by existing settings fields rather than extra stages.
IN_SETTINGS = (
    "camera_noise",
    "cell_intensity_variability",
    "background_texture",
    "cell_curvature",
    "envelope_stain",
)
#: Effects of one frame that render and export draw as ``PipelineSettings.extra_stages``.
DRAWN = (*_STATIC, "saturation")


def check_drawn_stage(name: str, parameters: dict[str, Any]) -> None:
    """Refuse an :class:`~napari_symbac.settings.ExtraStage` that render and export
    cannot draw: an unknown or time-dependent effect, or parameters its stage cannot
    be built from (a settings file edited by hand)."""
    if name in TIME_DEPENDENT:
        raise ValueError(
            f"extra stage {name!r} changes from frame to frame of the recording, so render "
            "and export do not draw it: remove it from extra_stages (diagnose keeps it in "
            "extra_stages.yaml, for ForwardModel(extra_stages=load_extra_stages(path, "
            "frame=t)))"
        )
    if name not in DRAWN:
        import difflib

        close = difflib.get_close_matches(str(name), [*DRAWN, *IN_SETTINGS], n=1)
        hint = f" (did you mean {close[0]!r}?)" if close and name not in IN_SETTINGS else ""
        raise ValueError(
            f"extra stage {name!r} is not an effect render and export draw as a stage"
            f"{hint}; the stages are {', '.join(DRAWN)} ({', '.join(IN_SETTINGS)} are "
            "settings fields, not stages)"
        )
    try:
        stage_for(name, parameters)
        five = name == "uneven_illumination" and "order" not in parameters
        if five and len(parameters["coefficients"]) != 5:
            raise ValueError("coefficients must be 5 numbers (x, y, x^2, y^2, xy)")
    except (KeyError, TypeError, ValueError) as err:
        reason = f"it lacks {err}" if isinstance(err, KeyError) else str(err)
        raise ValueError(
            f"extra stage {name!r} has parameters {parameters!r} that do not make its "
            f"stage ({reason}): copy them from diagnosis.json, or re-run the diagnosis"
        ) from None


def drawn_stages(settings: PipelineSettings) -> list[Stage]:
    """The forward-model stages of ``settings.extra_stages``, in order (render, export)."""
    return [stage_for(s.name, s.parameters) for s in settings.extra_stages]


def drawn_by_export(names: list[str]) -> str:
    """What of the accepted effects ``names`` render and export draw, in words: all but
    the time-dependent ones, whose stages are kept in ``extra_stages.yaml`` for
    ``ForwardModel(..., extra_stages=...)`` (found as a user: the Diagnose dock said
    Export takes the updated settings, and the column offsets, illumination and stray
    light it had accepted reached no exported image). Empty for no effect."""
    drawn = [n for n in names if n in IN_SETTINGS or n in DRAWN]
    kept = [n for n in names if n in TIME_DEPENDENT]
    parts = [f"render and export draw {', '.join(drawn)}"] if drawn else []
    if kept:
        parts.append(
            f"they do not draw {', '.join(kept)}, which change{'s' if len(kept) == 1 else ''}"
            " from frame to frame of the recording (kept as extra stages, for "
            "ForwardModel(extra_stages=...))"
        )
    return "; ".join(parts)


def stage_for(name: str, parameters: dict[str, Any], *, frame: int = 0) -> Stage:
    """The stage of an accepted effect (``frame`` for time-dependent effects)."""
    if name in _STATIC:
        return _STATIC[name](parameters)
    if name in TIME_DEPENDENT:
        return TIME_DEPENDENT[name](parameters, frame)
    if name == "saturation":
        return saturation.stage(parameters)
    raise ValueError(f"effect {name!r} has no stage (it is carried by the settings: {IN_SETTINGS})")


#: The base model's linear coefficients (eq. 3), in the order of ``FittedModel.beta``.
_INTENSITIES = ("cell_intensity", "media_intensity", "device_intensity")


def refitted_render(
    render: RenderSettings, model: Any, modality: str
) -> tuple[RenderSettings, str]:
    """The render settings with the intensities of the diagnosis' final model, and a
    note ("" when none). In bright field also its lens term: the fourth coefficient is
    ``kappa I_m`` (:attr:`~napari_symbac.diagnose.model.BaseDesign.lens`), so
    ``defocus_contrast_um2`` becomes it over the refitted media level.

    The diagnosis refits the base model's intensities (eq. 3, the first three of
    ``model.beta``) together with the accepted effects; the settings that draw those
    effects must carry them too. Found as a user on DeLTA's trench: settings.yaml kept
    the base fit's device at 1198 ADU while the final model, with stray light added,
    had it at 246, and the exported images came out 20 % brighter than the recording.
    The optics keep the base fit's values: the diagnosis' first-order changes of them
    are not measurements (on a synthetic trench rendered with the very optics of the
    design they came out 0.36 um of apodisation, seven times the linearisation's step).
    An intensity below 0, which the settings cannot draw, is kept at 0 and said.
    """
    changes = dict(zip(_INTENSITIES, (float(b) for b in model.beta[:3])))
    held = [f"{name} {value:.4g} ADU" for name, value in changes.items() if value < 0]
    changes = {name: max(value, 0.0) for name, value in changes.items()}
    if modality == "brightfield" and changes["media_intensity"] > 0:
        changes["defocus_contrast_um2"] = float(model.beta[3]) / changes["media_intensity"]
    note = (
        f"the final model's {', '.join(held)} is drawn as 0 (the cells are darker than "
        "the model draws them)"
        if held
        else ""
    )
    return dataclasses.replace(render, **changes), note


def updated_settings(
    settings: PipelineSettings, accepted: Sequence[Any]
) -> tuple[PipelineSettings, list[dict]]:
    """Settings with the accepted effects folded in (settings fields, and the effects
    of :data:`DRAWN` appended to ``extra_stages``), and the specs of every accepted
    effect without a settings field (for ``extra_stages.yaml``).

    ``accepted`` holds a diagnosis's accepted effects (``Diagnosis.accepted``, each
    with its ``name`` and ``params``) or ``(name, params)`` pairs. Found as an API
    user: ``updated_settings(settings, diagnosis.accepted)`` raised "cannot unpack
    non-iterable EffectResult object"."""
    simulation, render, camera = settings.simulation, settings.render, settings.camera
    drawn = list(settings.extra_stages)
    extra: list[dict] = []
    pairs = [(e.name, e.params) if hasattr(e, "params") else tuple(e) for e in accepted]
    for name, params in pairs:
        if name == "camera_noise":
            camera = camera_noise.updated_camera(camera, params)
        elif name == "cell_intensity_variability":
            render = dataclasses.replace(render, cell_brightness_cv=float(params["cv"]))
        elif name == "background_texture":
            render = dataclasses.replace(render, texture_amplitude=float(params["rms_fraction"]))
        elif name == "envelope_stain":  # the stain's fraction in the cell envelope
            fraction = min(max(float(params["fraction"]), 0.0), 1.0)
            render = dataclasses.replace(render, envelope_stain_fraction=fraction)
        elif name == "cell_curvature":  # bent cells: eq. 1's curvature when drawn
            simulation = dataclasses.replace(simulation, do_transformation=True)
        else:
            extra.append({"name": name, "parameters": params})
            if name in DRAWN:
                drawn.append(ExtraStage(name, dict(params)))
    updated = dataclasses.replace(
        settings, simulation=simulation, render=render, camera=camera, extra_stages=tuple(drawn)
    )
    return updated, extra


def load_extra_stages(path: str | Path, *, frame: int = 0) -> list[Stage]:
    """Stages from an ``extra_stages.yaml`` written by ``napari-symbac diagnose``."""
    data = read_settings_mapping(path)
    specs = data.get("extra_stages", []) if isinstance(data, dict) else None
    if not isinstance(specs, list):
        raise ValueError(f"{path} must hold 'extra_stages: [{{name, parameters}}, ...]'")
    return [stage_for(s["name"], s["parameters"], frame=frame) for s in specs]
