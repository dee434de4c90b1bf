"""Accepted effects as forward-model stages and updated settings (for render / export).

The diagnosis writes ``settings.yaml`` (a :class:`~napari_symbac.settings.PipelineSettings`
whose render and camera carry the effects that map onto existing settings:
``camera_noise`` -> the camera, ``cell_intensity_variability`` ->
``render.cell_brightness_cv``, ``background_texture`` -> ``render.texture_amplitude``)
and ``extra_stages.yaml`` (the other accepted effects, by name and parameters).
:func:`load_extra_stages` turns the latter back into
:class:`~napari_symbac.optics.forward.Stage` objects for
``ForwardModel(..., extra_stages=...)``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import yaml

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
from napari_symbac.settings import PipelineSettings

__all__ = ["drawn_by_export", "load_extra_stages", "stage_for", "updated_settings"]

_STATIC = {
    "uneven_illumination": uneven_illumination.stage,
    "halo": halo.stage,
    "defocus_gradient": defocus_gradient.stage,
    "stray_light": stray_light.stage,
    "fixed_pattern_noise": fixed_pattern_noise.stage,
}
_PER_FRAME = {"photobleaching": photobleaching.stage, "stage_drift": stage_drift.stage}
#: Effects carried by existing settings fields rather than extra stages.
IN_SETTINGS = ("camera_noise", "cell_intensity_variability", "background_texture")


def drawn_by_export(names: list[str]) -> str:
    """What of the accepted effects ``names`` render and export draw, in words: those
    carried by settings (:data:`IN_SETTINGS`, folded in by :func:`updated_settings`), and
    not yet the others, whose stages are written to ``extra_stages.yaml`` for
    ``ForwardModel(..., extra_stages=...)`` (found as a user: the Diagnose dock said
    Export takes the updated settings, and the column offsets, illumination and stray
    light it had accepted reached no exported image). Empty for no effect."""
    drawn = [n for n in names if n in IN_SETTINGS]
    staged = [n for n in names if n not in IN_SETTINGS]
    parts = [f"render and export draw {', '.join(drawn)} (settings)"] if drawn else []
    if staged:
        parts.append(
            f"they do not draw {', '.join(staged)}: no pipeline stage of "
            f"{'it' if len(staged) == 1 else 'them'} yet (their fitted parameters are kept "
            "as extra stages, for ForwardModel(extra_stages=...))"
        )
    return "; ".join(parts)


def stage_for(
    name: str, parameters: dict[str, Any], *, frame: int = 0, baseline_adu: float = 0.0
) -> Stage:
    """The stage of an accepted effect (``frame`` for time-dependent effects)."""
    if name in _STATIC:
        return _STATIC[name](parameters)
    if name in _PER_FRAME:
        return _PER_FRAME[name](parameters, frame)
    if name == "saturation":
        return saturation.stage(parameters, baseline_adu)
    raise ValueError(f"effect {name!r} has no stage (it is carried by the settings: {IN_SETTINGS})")


def updated_settings(
    settings: PipelineSettings, accepted: list[tuple[str, dict]]
) -> tuple[PipelineSettings, list[dict]]:
    """Settings with the accepted effects folded in, and the extra-stage specs."""
    render, camera = settings.render, settings.camera
    extra: list[dict] = []
    for name, params in accepted:
        if name == "camera_noise":
            camera = camera_noise.updated_camera(camera, params)
        elif name == "cell_intensity_variability":
            render = dataclasses.replace(render, cell_brightness_cv=float(params["cv"]))
        elif name == "background_texture":
            render = dataclasses.replace(render, texture_amplitude=float(params["rms_fraction"]))
        else:
            extra.append({"name": name, "parameters": params})
    return dataclasses.replace(settings, render=render, camera=camera), extra


def load_extra_stages(
    path: str | Path, *, frame: int = 0, baseline_adu: float = 0.0
) -> list[Stage]:
    """Stages from an ``extra_stages.yaml`` written by ``napari-symbac diagnose``."""
    data = yaml.safe_load(Path(path).read_text(encoding="utf-8")) or {}
    specs = data.get("extra_stages", []) if isinstance(data, dict) else None
    if not isinstance(specs, list):
        raise ValueError(f"{path} must hold 'extra_stages: [{{name, parameters}}, ...]'")
    return [
        stage_for(s["name"], s["parameters"], frame=frame, baseline_adu=baseline_adu) for s in specs
    ]
