"""The simulation and render settings a fit implies: what ``render`` and ``export`` draw so
that a dataset matches the fitted recording, written by ``napari-symbac fit`` into its
settings.yaml and taken by the Tune dock's Auto-fit for Export."""

from __future__ import annotations

import dataclasses
from collections.abc import Collection
from typing import Any

import numpy as np

from napari_symbac.settings import (
    Camera,
    ExtraStage,
    Microscope,
    PipelineSettings,
    RenderSettings,
    SimulationSettings,
)

__all__ = [
    "MIN_CELLS_FOR_SPREAD",
    "colony_drawn",
    "drawn_colony_phase",
    "fitted_pipeline",
    "fitted_render",
    "fitted_simulation",
    "with_illumination",
]

#: Fitted cells needed to take their brightness spread as the population's.
MIN_CELLS_FOR_SPREAD = 3


def fitted_render(result: Any, modality: str) -> RenderSettings:
    """``result.render`` with the spread of the fitted cells' own intensities as
    ``cell_brightness_cv`` (section 13.2.2: cells differ in fluorophore content), when the
    fit gave each cell its own intensity (fluorescence by default) and has at least
    :data:`MIN_CELLS_FOR_SPREAD` cells, the gains bounded by the brightest fitted cell
    (``cell_brightness_max_gain``: a spread measured on a few cells has a long tail);
    else as it is. (Found as a user: the fit measured
    each cell's brightness, CV 0.43 on ColiCoords field 1, and its settings.yaml drew every
    cell alike; ``calibrate`` measures 0.47 from the masks.)

    Fluorescence only (``modality``): a phase-contrast or bright-field cell's level is
    its optical path, which differs little between cells, and the intensities a fit
    gives each cell there take up its misfit (the real trench's 4 cells: 347-1741 ADU,
    CV 0.67; drawn, some exported cells came out almost as light as the medium).
    """
    if modality != "fluorescence":
        return result.render
    names = list(getattr(result, "parameter_names", ()))
    keys = [f"cell{int(i)}.dbrightness" for i in result.cells.ids]
    if len(keys) < MIN_CELLS_FOR_SPREAD or not set(keys) <= set(names):
        return result.render
    values = dict(zip(names, np.asarray(result.parameters, np.float64)))
    gains = 1.0 + np.array([values[key] for key in keys])
    if np.mean(gains) <= 0:
        return dataclasses.replace(result.render, cell_brightness_cv=0.0)
    cv = float(np.std(gains, ddof=1) / np.mean(gains))
    return dataclasses.replace(
        result.render,
        cell_brightness_cv=min(max(cv, 0.0), 2.0),
        cell_brightness_max_gain=max(float(gains.max() / gains.mean()), 1.0),
    )


def with_illumination(stages: Collection[ExtraStage], result: Any) -> tuple[ExtraStage, ...]:
    """``stages`` with the illumination surface ``result`` fitted (``--illumination-order``)
    as their ``uneven_illumination`` stage, in place of any they had, before a clip of
    the recorded values (``saturation``). (Found as a user:
    settings.yaml left it out, and the fit's intensities, found under the surface, drew
    exported trenches at 5000-6000 ADU against the recording's 1600-4700.)"""
    stage = ExtraStage(
        "uneven_illumination",
        {
            "coefficients": [float(c) for c in np.asarray(result.illumination)],
            "order": int(result.illumination_order),
        },
    )
    others = [s for s in stages if s.name != "uneven_illumination"]
    clips = [s for s in others if s.name == "saturation"]  # the recorded values: last
    return (*(s for s in others if s.name != "saturation"), stage, *clips)


def fitted_simulation(
    simulation: SimulationSettings,
    result: Any,
    image_shape: tuple[int, int],
    pixel_size_um: float,
    keep: Collection[str] = (),
) -> SimulationSettings:
    """``simulation`` with what ``result`` (a scene or colony fit) found in the recording.

    - A trench fit: the fitted trench, sized so a rendered frame has the recording's
      ``image_shape`` (``result.trench_geometry``).
    - A field fit: an agar pad laid out as the recording (``calibrate.core.pad_layout``):
      its size, one colony per cluster of touching fitted cells, each grown from one
      founder to the clusters' mean size (a field of scattered cells gives scattered
      cells, not one colony of the defaults' size).
    - Fitted cells: their median width, and the sizer division length (and its
      variance) that makes the fitted lengths' median that of an asynchronous
      exponential population (``calibrate.core.division_length_um``, as
      ``calibrate``), at least 1.3 widths.

    Parameters
    ----------
    keep
        Fields the user set, left as they are: simulation field names, and
        ``agar_pad.NAME`` for a field of the pad.

    Raises
    ------
    ValueError
        If the settings this makes are invalid (e.g. a trench the cells do not fit in).
    """
    # every change in one replace: the settings are checked as a whole (found as a user:
    # the fitted 1.15 um trench was checked against the defaults' 1 um cells before the
    # fitted 0.79 um cells replaced them, and the whole fit was dropped)
    changes: dict[str, Any] = {}
    if len(result.cells):
        from napari_symbac.calibrate.core import division_length_um

        width = float(np.median(result.cells.width_um))
        division, variance = division_length_um(np.asarray(result.cells.length_um))
        sizes = {
            "cell_width_um": width,
            "cell_max_length_um": max(division, 1.3 * width),
            "max_length_var_um2": variance,
        }
        changes.update({k: v for k, v in sizes.items() if k not in keep})
    if result.trench is not None:
        changes["trench"] = result.trench_geometry(image_shape, pixel_size_um)
    elif len(result.cells):
        grown = {  # the cells the pad's colonies grow (not a whole settings: see above)
            "division_length_um": changes.get("cell_max_length_um", simulation.cell_max_length_um),
            "width_um": changes.get("cell_width_um", simulation.cell_width_um),
        }
        changes.update(
            _pad_as_fitted(simulation, result, image_shape, pixel_size_um, keep, **grown)
        )
    return dataclasses.replace(simulation, **changes)


def fitted_or_kept(
    simulation: SimulationSettings, result: Any, image_shape: tuple[int, int], pixel_size_um: float
) -> tuple[SimulationSettings, str]:
    """:func:`fitted_simulation` and ``""``; ``simulation`` as it was and the reason
    when the fitted settings would be invalid (``napari-symbac diagnose`` and the
    Diagnose dock say it, and the export keeps the settings it had)."""
    try:
        return fitted_simulation(simulation, result, image_shape, pixel_size_um), ""
    except ValueError as err:
        return simulation, str(err)


def _pad_as_fitted(
    simulation: SimulationSettings,
    result: Any,
    image_shape: tuple[int, int],
    pixel_size_um: float,
    keep: Collection[str],
    *,
    division_length_um: float,
    width_um: float,
) -> dict[str, Any]:
    """The fields that lay ``simulation`` out as an agar pad like the fitted field's cells
    (colonies of cells of ``division_length_um`` and ``width_um`` grown to the clusters'
    size)."""
    from napari_symbac.calibrate.core import pad_layout
    from napari_symbac.calibrate.measure import cluster_sizes

    sizes = cluster_sizes(result.scene.camera_labels())
    fields, _note = pad_layout(
        image_shape,
        pixel_size_um,
        sizes.size,
        float(np.mean(sizes)),
        division_length_um=division_length_um,
        width_um=width_um,
    )
    mine = {k.removeprefix("agar_pad.") for k in keep if k.startswith("agar_pad.")}
    if mine:
        kept = {k: getattr(simulation.agar_pad, k) for k in mine}
        fields["agar_pad"] = dataclasses.replace(fields["agar_pad"], **kept)
    return {k: v for k, v in fields.items() if k not in keep}


def drawn_colony_phase(settings: PipelineSettings) -> tuple[PipelineSettings, str]:
    """Settings whose drawn cells carry the phase fitted to the masks' scene, and a note.

    The phase ``phi = 2 pi (n_cell - n_media) s / lambda`` (eq. OPL2) is fitted per unit
    of material on :func:`~napari_symbac.scene.scene_from_masks`, whose material is the
    chord over the cell's own width (1 on a cell's centre line). A drawn agar pad holds
    the chord over the pad's optical depth ``D`` (``TrenchGeometry.depth_um``), so a
    cell of width ``w`` peaks at ``w / D``: the same cells carry the same optical path
    only with ``phi_drawn = phi_fit D / w``.
    """
    simulation, render = settings.simulation, settings.render
    depth, width = simulation.trench.depth_um, simulation.cell_width_um
    phase = render.cell_phase_rad * depth / width
    render = dataclasses.replace(render, cell_phase_rad=phase)
    return dataclasses.replace(settings, render=render), (
        f"phase per unit of drawn material {phase:.2f} rad = fitted "
        f"{settings.render.cell_phase_rad:.2f} rad x pad depth {depth:.2f} um / cell width "
        f"{width:.2f} um (the masks' scene holds chord / width, the drawn pad chord / depth)"
    )


def colony_drawn(
    settings: PipelineSettings, result: Any, keep: Collection[str] = (), cancel: Any = None
) -> tuple[PipelineSettings, list[str]]:
    """``settings`` (the fitted simulation's pad) made to draw the colony fit ``result``
    as it was recorded, as ``calibrate`` draws a dense colony, and a note on each step:

    - the cells' phase per unit of drawn material (:func:`drawn_colony_phase`);
    - colonies packed as tightly as the fitted cells (gravity towards each colony's
      centre, :func:`~napari_symbac.calibrate.compaction.compacted`) and as long.

    (Found as a user: the settings.yaml of ``fit --masks`` on Omnipose's Sample000252
    drew colonies of loosely touching cells, 0.83 of each colony's area cells against
    the recording's 0.94, at the masks' phase: the exported cells' normalised median
    0.17-0.23 against the recording's 0.33.)

    Parameters
    ----------
    keep
        Simulation fields the user set: with ``gravity`` among them the packing is
        theirs.
    cancel
        Asked before each simulated colony; ``True`` raises
        :class:`~napari_symbac.fit.FitCancelled`.
    """
    from napari_symbac.calibrate.compaction import compacted
    from napari_symbac.calibrate.measure import lengths_px, measure_packing

    settings, phase_note = drawn_colony_phase(settings)
    labels = result.scene.camera_labels()
    packing = measure_packing(labels)
    if not packing.n_colonies or "gravity" in keep:
        return settings, [phase_note]
    length_px = float(np.median(lengths_px(labels)))  # as the trials measure theirs
    settings, _trials, packing_note = compacted(settings, packing, length_px, cancel)
    return settings, [phase_note, packing_note]


def fitted_pipeline(
    result: Any,
    image: np.ndarray,
    microscope: Microscope,
    camera: Camera | None = None,
    *,
    base: PipelineSettings | None = None,
    keep: Collection[str] = (),
) -> tuple[PipelineSettings, list[str]]:
    """The settings that draw data matched to a fitted recording: what ``napari-symbac
    fit`` writes as settings.yaml, for :func:`~napari_symbac.sim.simulate`,
    :func:`~napari_symbac.pipeline.render_simulation` and
    :func:`~napari_symbac.export.export_of` in Python.

    Found as an API user: ``PipelineSettings(render=fit.render, camera=fit.camera)``
    drew every cell alike, in the default trench, and only the command line's private
    code made the rest.

    Parameters
    ----------
    result
        A :class:`~napari_symbac.fit.SceneFit` or :class:`~napari_symbac.fit.ColonyFit`.
    image
        The frame that was fitted (its shape sizes the trench or pad; in fluorescence
        its clipped background is drawn as recorded).
    microscope
        The microscope it was fitted with.
    camera
        The camera given to the fit, if any (else the fit's own estimate is used).
    base
        Settings to start from (default :class:`PipelineSettings`'s).
    keep
        Simulation fields the user set, left as they are (:func:`fitted_simulation`).

    Returns
    -------
    settings, notes
        The settings, and sentences on what was kept or drawn as recorded.
    """
    from napari_symbac.fit.clipped_background import drawn_clipped, fitted_clip
    from napari_symbac.fit.colony import ColonyFit

    base = PipelineSettings() if base is None else base
    image = np.asarray(image)
    colony = isinstance(result, ColonyFit)  # its render is the fitted one as it is
    render = result.render if colony else fitted_render(result, microscope.modality)
    camera_used = getattr(result, "camera", None) or camera or base.camera
    settings = dataclasses.replace(base, microscope=microscope, render=render, camera=camera_used)
    notes = []
    try:
        simulation = fitted_simulation(
            base.simulation, result, image.shape[-2:], microscope.pixel_size_um, keep
        )
        settings = dataclasses.replace(settings, simulation=simulation)
        if colony:  # the fitted pad, drawn as the colony was recorded
            settings, said = colony_drawn(settings, result, keep)
            notes.extend(said)
    except ValueError as err:
        notes.append(f"simulation settings kept from the config: {err}")
    if getattr(result, "illumination_order", 0):  # drawn as fitted (before any clip)
        settings = dataclasses.replace(
            settings, extra_stages=with_illumination(settings.extra_stages, result)
        )
    if not colony:
        clipped = fitted_clip(image, result.scene, camera, microscope.modality)
        if clipped is not None:  # the recording's clipped background
            settings, sentence = drawn_clipped(settings, clipped, noise=camera is None)
            notes.append(sentence)
    return settings, notes
