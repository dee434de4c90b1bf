"""The ``napari-symbac fit`` command: checks, fit, outputs (cli.py parses the arguments).

Everything the user passed is checked before the fit starts, and the outputs are written
into ``--out`` only once all of them are ready, so a refusal or a failure leaves nothing
half-written.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import re
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from napari_symbac._timing import StepTimer, progress_bar
from napari_symbac.io import CountsMapping

__all__ = [
    "counts_record",
    "counts_units_mark",
    "counts_units_note",
    "number_runs",
    "parse_frames",
    "read_recording",
    "run_fit",
]

_GEOMETRIES = {"trench": "trench", "field": "open"}


def parse_frames(spec: str | None, n_frames: int, name: str) -> list[int]:
    """``"3"``, ``"0,2,5"`` or ``"0-3"`` (inclusive) -> frame indices, checked."""
    if spec is None:
        if n_frames > 1:
            last = n_frames - 1
            pair = "0,1" if n_frames == 2 else f"0,{last // 2}"
            raise ValueError(  # examples that exist (found as a user: 0-3 of 3 frames)
                f"{name} has {n_frames} frames: pass --frames to pick them (e.g. --frames 0, "
                f"--frames {pair} or --frames 0-{last})"
            )
        return [0]
    frames: list[int] = []
    try:
        for part in spec.split(","):
            if "-" in part.strip()[1:]:
                first, last = part.split("-", 1)
                frames += range(int(first), int(last) + 1)
            else:
                frames.append(int(part))
    except ValueError:
        raise ValueError(
            f"--frames {spec!r} is not a frame list: write e.g. 0, 0,2,5 or 0-3"
        ) from None
    if not frames:
        raise ValueError(
            f"--frames {spec!r} names no frame: write a range from low to high, e.g. 0-3"
        )
    bad = sorted({f for f in frames if not 0 <= f < n_frames})
    if bad:
        has = (
            f"{name} has 1 frame (frame 0)" if n_frames == 1 else
            f"{name} has {n_frames} frames, numbered 0-{n_frames - 1}"
        )
        raise ValueError(f"--frames {spec!r}: frame(s) {number_runs(bad)} do not exist: {has}")
    return sorted(set(frames))


def number_runs(numbers: list[int]) -> str:
    """Sorted whole numbers with their runs compressed: ``[1, 3, 4, 5]`` -> ``"1, 3-5"``."""
    runs: list[list[int]] = []
    for number in numbers:
        if runs and number == runs[-1][-1] + 1:
            runs[-1].append(number)
        else:
            runs.append([number])
    return ", ".join(f"{r[0]}-{r[-1]}" if len(r) > 1 else f"{r[0]}" for r in runs)


def _explicit_keys(config: str | None) -> dict[str, Any]:
    """The raw mapping of a config file, to know which settings the user actually gave."""
    if config is None:
        return {}
    from napari_symbac.settings import read_settings_mapping

    data = read_settings_mapping(config)
    return data if isinstance(data, dict) else {}


#: What ``fit`` writes directly in its --out: a frame's files, and a series' folder per
#: frame, ``series.json`` and ``ctc/``.
_FIT_OUTPUTS = frozenset(
    {"settings.yaml", "cells.json", "residual.tif", "before_after.png", "report.txt",
     "series.json", "ctc"}
)  # fmt: skip


def _polarity_said(polarity: str, modality: str = "phase") -> str:
    """What the image shows, for report.txt's modality line (found as a user: "image
    polarity: unclear" for a plain phase trench read as the tool doubting it)."""
    if polarity == "unclear":
        look = (
            "bright-field cells out of focus are (dark rims, bright centres)"
            if modality == "brightfield"
            else "phase contrast's halos are"
        )
        return f"image polarity: both darker and brighter than its background, as {look}"
    return f"image polarity: {polarity}"


def _given_trench(keys: dict[str, Any]) -> dict[str, Any]:
    """The trench settings a config file gives (its ``simulation.trench`` mapping)."""
    simulation = keys.get("simulation") or {}
    trench = simulation.get("trench") if isinstance(simulation, dict) else None
    return trench if isinstance(trench, dict) else {}


#: Frames larger than this (pixels) are announced as slow before the fit (``fit``).
LARGE_FRAME_PX = 2 * 512**2


def _closed_end_said(result, options: dict[str, Any]) -> str:
    """The fitted trench's closed end, and who chose it; none in view when it lies above
    the image, round end and all (found as a user: a crop below the closed end said
    "square, chosen by the fit")."""
    trench = result.trench
    if trench.top_um + trench.width_um / 2 <= 0:
        return "above the image, not in view"
    end = trench.closed_end
    return f"{end}, from --config" if "closed_end" in options else f"{end}, chosen by the fit"


def _fit_writes(name: str) -> bool:
    """Whether ``fit`` writes an entry of this name directly in its --out."""
    return name in _FIT_OUTPUTS or re.fullmatch(r"frame_\d{4,}", name) is not None


def _config_note(config: str | None, keys: dict[str, Any], geometry: str) -> str:
    """Which parts of --config the fit used, and which it could not."""
    if config is None:
        return "none (built-in defaults for the starting render settings)"
    used = ["render settings as the start" if "render" in keys else "default render start"]
    if "camera" in keys:
        used.append("camera")
    if geometry == "trench" and "closed_end" in _given_trench(keys):
        used.append("trench closed end")
    ignored = []
    if "microscope" in keys:
        ignored.append("its microscope (--microscope wins)")
    simulation = keys.get("simulation") or {}
    if set(simulation) - {"trench", "geometry"} or set(simulation.get("trench") or {}) - {
        "closed_end"
    }:
        ignored.append(
            "its other simulation settings in the fit (the fit finds trench and cells; the "
            "rest is kept in settings.yaml)"
        )
    note = f"{config}: used {', '.join(used)}"
    return note + (f"; not used: {'; '.join(ignored)}" if ignored else "")


def read_recording(
    path: str, what: str = "IMAGE", *, counts: bool = True, channel: int | None = None
):
    """The recording at ``path`` (:func:`napari_symbac.io.read_image`, a normalised image
    as counts when ``counts``; channel ``channel`` of a TIFF of several, which without
    it is refused naming ``--channel``), its reading note ("read as counts ...") said on
    stderr."""
    from napari_symbac.io import ChannelsError, read_image

    try:
        recording = read_image(path, what, counts=counts, channel=channel)
    except ChannelsError as err:  # --channel picks the IMAGE's; masks are one channel
        fix = (
            f", and a recording is one channel: choose it with --channel K "
            f"(0..{err.n_channels - 1})"
            if what == "IMAGE"
            else f": save the channel of {what} to use as its own TIFF"
        )
        raise ValueError(err.cause + fix) from err
    if recording.note:
        print(f"note: {Path(path).name}: {recording.note}", file=sys.stderr)
    return recording


def in_read_units(camera, mapping: CountsMapping | None):
    """The camera that wrote an image beyond 16 bits (``--camera``, a microscope file's)
    in the units the image was read in, divided as it was
    (:meth:`~napari_symbac.io.CountsMapping.camera`); else as it is (a normalised
    image's divisor is unknown: its camera is measured)."""
    return mapping.camera(camera) if mapping is not None and mapping.divides else camera


def _read_stack(path: str, what: str) -> np.ndarray:
    return np.asarray(read_recording(path, what, counts=False).data)


def _per_frame(array: np.ndarray | None, frame: int, n_frames: int, shape: tuple) -> Any:
    """A 2D label/mask for every frame, or a (T, Y, X) one indexed like the image."""
    if array is None:
        return None
    if array.ndim == 3 and array.shape[0] == n_frames and array.shape[1:] == shape:
        return array[frame]
    return array


class _Stages:
    """Progress: a tqdm bar on a terminal; when piped, one line per stage and a line of
    the steps done every :data:`~napari_symbac._timing.PIPED_PROGRESS_INTERVAL_S`."""

    def __init__(self, stream=None) -> None:
        self.stream = sys.stderr if stream is None else stream
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())

    def stage(self, text: str) -> None:
        if not self.tty:
            print(f"napari-symbac fit: {text}", file=self.stream, flush=True)

    def bar(self, desc: str) -> tuple[Callable[[int, int], None], Callable[[], None]]:
        # piped: a line every few seconds, so that a long fit is not silent in a log; the
        # total is the engine's upper bound (found as a user: "1 of 7614 steps", then
        # "2521 of 2521 steps")
        update, handle = progress_bar(desc, None, "steps", self.stream, bound=True)
        return update, handle.close


def _camera_for(
    args: argparse.Namespace,
    frame: np.ndarray,
    base_camera,
    config_has_camera: bool,
):
    """The camera to pass to the fit and a sentence saying where it came from."""
    from napari_symbac.fit.camera_estimate import (
        censored_pixels,
        estimate_camera,
        image_bit_depth,
    )
    from napari_symbac.settings import Camera, load_settings

    bit_depth = image_bit_depth(frame)
    mapping = getattr(args, "counts_mapping", None)  # how the image was read
    if args.camera is not None:
        from napari_symbac.fit.preflight import camera_recording_problem

        camera = in_read_units(load_settings(args.camera, Camera), mapping)
        problem = camera_recording_problem(camera, frame)
        if problem is not None:
            raise ValueError(f"--camera {args.camera}: {problem}")
        return camera, f"from --camera {args.camera}"
    if args.dark is not None:
        dark = _read_stack(args.dark, "--dark")
        if mapping is not None and mapping.divides:  # divided as the image was
            dark = mapping.counts_adu(dark)
        name = Path(args.dark).name
        if dark.ndim not in (2, 3):
            raise ValueError(
                f"--dark {name} has shape {dark.shape}: give one dark frame or a (T, Y, X) "
                "stack of them"
            )
        if dark.min() == dark.max():
            raise ValueError(
                f"--dark {name} has no noise (every pixel is {dark.flat[0]}): raw dark "
                "frames of a camera scatter by its read noise; give the camera's raw dark "
                "frames (lens capped, same exposure and gain), or --camera C.yaml"
            )
        valid = ~censored_pixels(frame)
        estimate = estimate_camera(frame, valid=valid, dark_frames=dark, bit_depth=bit_depth)
        note = f"{estimate.summary()} (--dark {args.dark}"
        if dark.shape[-2:] != frame.shape:  # only their statistics are used: any region
            note += f"; {dark.shape[-2]} x {dark.shape[-1]} px frames, another region"
        return estimate.camera, note + ")"
    if getattr(args, "microscope_camera", None) is not None:
        camera = in_read_units(args.microscope_camera, mapping)
        return camera, f"from the camera section of --microscope {args.microscope}"
    if config_has_camera:  # napari-symbac's own settings: in the units it read
        return base_camera, f"from --config {args.config}"
    return None, (
        "estimated from the image by the fit: photon transfer of its high-pass part, or "
        "the model's residual where the levels span too little (no --camera, --dark or "
        "config camera)"
    )


def _cell_problems(
    result, shape: tuple[int, int], pixel_um: float, masks, colony: bool = False
) -> list[str]:
    """Cells wholly outside the image, and a count that differs from the masks given (a
    colony's cells are its masks: those too small to measure are said instead). A cell
    centred outside but drawn into the image is cut by its edge, as cells leave a
    trench's open end: no problem (found as a user: a routine trench fit listed one)."""
    problems = []
    cells = result.cells
    scene = getattr(result, "scene", None)
    drawn = set() if scene is None else set(np.unique(scene.camera_labels()).tolist())
    height_um, width_um = shape[0] * pixel_um, shape[1] * pixel_um
    for cell_id, x, y in zip(cells.ids, cells.x_um, cells.y_um, strict=True):
        inside = 0 <= x <= width_um and 0 <= y <= height_um
        if not inside and int(cell_id) not in drawn:
            problems.append(
                f"cell {int(cell_id)} lies outside the image (centre x {x:.2f} um, "
                f"y {y:.2f} um; the image is {width_um:.2f} x {height_um:.2f} um, and no "
                "pixel of it is drawn): a spurious cell; check the figure"
            )
    if masks is not None:
        n_masks = int(np.count_nonzero(np.unique(masks)))
        if colony:
            if len(cells) < n_masks:
                problems.append(
                    f"{n_masks - len(cells)} of the {n_masks} masks are too small to measure "
                    "(under 6 px or 0.25 um^2; cut by the image's edge?): drawn in the "
                    "fitted image, not listed in cells.json"
                )
        elif len(cells) != n_masks:
            problems.append(
                f"the fit ended with {len(cells)} cells from the {n_masks} of --masks (its "
                "moves added or removed cells): check the figure, or pass --keep-cells to "
                "fit the masks' cells only"
            )
    return problems


@dataclasses.dataclass
class _Prepared:
    """One frame checked and ready to fit: what the fit takes and what the report says."""

    masks: Any
    labels: Any
    camera: Any
    camera_note: str
    options: dict[str, Any]
    censor_note: str
    notes: list[str]
    polarity: str
    colony: bool = False  # a phase colony fitted from its masks (fit_colony)


def refuse_lying_trench(args: argparse.Namespace, shape: tuple[int, ...], modality: str) -> None:
    """Refuse (``fit`` and ``diagnose``) a frame shaped like a trench on its side
    (:func:`~napari_symbac.fit.preflight.lying_trench_problem`) unless ``--geometry
    field`` says it is an open field."""
    from napari_symbac.fit.preflight import lying_trench_problem

    problem = lying_trench_problem(shape, modality, Path(args.image).name)
    if args.geometry != "field" and problem:
        raise ValueError(f"{problem}; or pass --geometry field for an open field")


def check_stain_flags(args, modality: str) -> None:
    """``--envelope-stain`` and ``--depth-layers`` (of ``fit`` and ``calibrate``) refused,
    the flag named, for a recording that is not fluorescence, and slabs out of range."""
    from napari_symbac.settings import MAX_DEPTH_LAYERS

    envelope, layers = getattr(args, "envelope_stain", False), getattr(args, "depth_layers", 0)
    for flag, asked, what in (
        ("--envelope-stain", envelope, "fits where a fluorescence stain sits in the cells"),
        ("--depth-layers", layers, "images a fluorescence stain slab by slab"),
    ):
        if asked and modality != "fluorescence":
            raise ValueError(f"{flag} {what}; this image is {modality}: leave {flag} out")
    if not 0 <= layers <= MAX_DEPTH_LAYERS:
        raise ValueError(
            f"--depth-layers {layers} is not a number of slabs: pass 1-{MAX_DEPTH_LAYERS} "
            "(5 fit ColiCoords ds2 as well as 15), or 0 for the 2-D projection"
        )


def _model_options(args, modality: str) -> dict[str, Any]:
    """The scene model's optional terms asked for on the command line (fit_scene's
    ``per_cell_brightness``, ``width_sd_um``, ``illumination_order``, the envelope's
    fraction of the stain and the depth-resolved image's focal plane among the fitted
    optics), checked."""
    options: dict[str, Any] = {}
    check_stain_flags(args, modality)
    if getattr(args, "envelope_stain", False):
        from napari_symbac.fit.scene_fit import ENVELOPE_FIT_OPTICS

        options["fit_optics"] = ENVELOPE_FIT_OPTICS
    if getattr(args, "depth_layers", 0):
        from napari_symbac.fit.scene_fit import depth_fit_optics

        options["fit_optics"] = depth_fit_optics(options.get("fit_optics"))
    if args.cell_brightness is not None:
        options["per_cell_brightness"] = args.cell_brightness == "per-cell"
    if not (np.isfinite(args.width_sd_um) and 0.0 <= args.width_sd_um <= 1.0):
        raise ValueError(
            f"--width-sd-um {args.width_sd_um} is not a width s.d. in um: pass 0 for one "
            "shared width, or e.g. 0.1 (at most 1) for a width per cell"
        )
    if args.width_sd_um > 0:
        options["width_sd_um"] = args.width_sd_um
    from napari_symbac.fit.illumination import MAX_ORDER

    if not 0 <= args.illumination_order <= MAX_ORDER:
        raise ValueError(
            f"--illumination-order {args.illumination_order} is not a surface degree: pass 0 "
            f"(flat illumination) or 1-{MAX_ORDER}"
        )
    if args.illumination_order > 0:
        options["illumination_order"] = args.illumination_order
    return options


def _trench_as_field(named: str, shape: tuple[int, ...], microscope) -> str | None:
    """A phase or bright-field frame shaped like a trench but fitted as a field, said
    (found as a user: DeLTA's 256 x 32 px trench with --geometry field ended with 2 rods
    laid along its walls, exit 0, and no word of the geometry)."""
    from napari_symbac.fit.preflight import default_geometry

    if named != "field" or default_geometry(shape, microscope.modality) != "trench":
        return None
    return (
        f"the image is {shape[0]} x {shape[1]} px, narrow and tall as a mother-machine "
        "trench, and was fitted as an open field (--geometry field): its walls and PDMS "
        "are taken for cells and media there; leave --geometry out (or pass --geometry "
        "trench) to fit the trench"
    )


def _prepare_one(args, frame, labels, masks, microscope, base, keys):
    """Check one frame and its labels/masks; choose its camera and fit options."""
    from napari_symbac.fit.camera_estimate import censored_pixels
    from napari_symbac.fit.preflight import (
        as_instance_ids,
        check_class_labels,
        check_instance_masks,
        check_modality,
        modality_doubt,
    )
    from napari_symbac.fit.report import fit_notes

    # the frame itself was checked by run_fit (check_fit_image, refuse_constant)
    if labels is not None:
        check_class_labels(labels, frame.shape, f"--labels {Path(args.labels).name}")
    notes = []
    if masks is not None:
        check_instance_masks(masks, frame.shape, f"--masks {Path(args.masks).name}")
        masks, n_regions = as_instance_ids(masks)
        if n_regions is not None:  # a binary mask: one id per component
            notes.append(
                f"--masks held one value only (a binary mask): its {n_regions} connected "
                "regions are the cells"
            )
    polarity = check_modality(frame, microscope.modality, labels=labels, masks=masks)
    if (note := modality_doubt(frame, microscope.modality)) is not None:
        notes.append(note)

    camera, camera_note = _camera_for(args, frame, base.camera, "camera" in keys)
    censored = censored_pixels(frame, camera)
    geometry = _GEOMETRIES[args.geometry]
    options: dict[str, Any] = {"geometry": geometry, "labels": labels}
    if geometry == "trench" and "closed_end" in _given_trench(keys):
        options["closed_end"] = base.simulation.trench.closed_end  # else the fit chooses
    if args.max_iterations is not None:
        options["max_iterations"] = args.max_iterations
    if getattr(args, "keep_cells", False):  # found as a user: no way to keep the masks'
        options["moves"] = False  # cell set (ds2 00066: 6 masked cells fitted as 10)
    model_options = _model_options(args, microscope.modality)
    options.update(model_options)
    from napari_symbac.fit.colony import is_dense_colony

    colony = geometry == "open" and is_dense_colony(masks, microscope.modality)
    notes += fit_notes(microscope.modality, geometry, colony=colony)
    if colony and (model_options or args.max_iterations is not None or args.config):
        notes.append(
            "--cell-brightness, --width-sd-um, --illumination-order, --max-iterations and "
            "--config's render settings belong to the scene fit: the colony fit starts "
            "from its own optics and does not use them"
        )
    if colony and "moves" in options:
        notes.append("--keep-cells: a colony's cells are its masks' already (no moves)")
    if "illumination_order" in options and not colony:
        notes.append(
            f"an illumination surface of degree {options['illumination_order']} is fitted "
            "(parameters illumination.*); settings.yaml draws it (extra stage "
            "uneven_illumination), so render and export images have the recording's light"
        )
    if options.get("per_cell_brightness") and microscope.modality != "fluorescence":
        notes.append(
            f"--cell-brightness per-cell in {microscope.modality}: each cell's intensity is "
            "fitted, but settings.yaml draws the cells alike (a cell's level there is its "
            "optical path, which differs little between cells; the fitted cells' own "
            "intensities take up the fit's misfit)"
        )
    if masks is not None:
        options["masks"] = masks
    options["valid"] = ~censored
    censor_note = (
        f"{int(censored.sum())} ({100 * censored.mean():.2f} %) left out of the likelihood"
    )
    return _Prepared(
        masks, labels, camera, camera_note, options, censor_note, notes, polarity, colony
    )


def _fit_one(args, frame, index, labels, masks, microscope, pixel_note, base, keys, stages, timer):
    """Check, fit and prepare the outputs of one frame: returns (writers, result,
    problems) as :func:`_outputs_one`."""
    from napari_symbac.fit import fit_colony, fit_scene
    from napari_symbac.fit.preflight import BRIGHT_FIELD_NOTE, PHASE_NOTE
    from napari_symbac.fit.report import OPEN_PHASE_NOTE
    from napari_symbac.fit.start import WideStartError

    prepared = _prepare_one(args, frame, labels, masks, microscope, base, keys)
    for note in prepared.notes:  # before a fit that may take minutes, not after
        if note in (OPEN_PHASE_NOTE, BRIGHT_FIELD_NOTE, PHASE_NOTE):
            print(f"napari-symbac fit: note: {note}", file=stages.stream, flush=True)
    what = "colony from its masks, partially coherent phase model, " * prepared.colony
    stages.stage(f"fitting frame {index} ({what}{frame.shape[0]} x {frame.shape[1]} px)")
    update, close = stages.bar(f"fit frame {index}")
    with timer.step(f"fit frame {index}"):
        try:
            if prepared.colony:
                result = fit_colony(
                    frame, microscope, prepared.masks, prepared.camera, progress=update
                )
            else:
                result = fit_scene(
                    frame, microscope, _start_render(args, base.render), prepared.camera,
                    progress=update,
                    **prepared.options,
                )
        except WideStartError as err:  # a trench fitted as a field: the geometry's fix
            if (problem := _trench_as_field(args.geometry, frame.shape, microscope)) is None:
                raise
            raise ValueError(f"{err.cause}: {problem}") from err
        finally:
            close()
    return _outputs_one(args, frame, index, prepared, result, microscope, pixel_note, base, keys)


def _outputs_one(
    args, frame, index, prepared, result, microscope, pixel_note, base, keys, track_ids=None
):
    """The files of one fitted frame: returns (writers, result, problems), ``problems``
    those report.txt lists. ``track_ids``: each cell's track in a series (``track`` in
    cells.json)."""
    import tifffile

    from napari_symbac.export.atomic import tiff_metadata
    from napari_symbac.fit.figure import before_after_figure
    from napari_symbac.fit.fitted_settings import fitted_pipeline
    from napari_symbac.fit.preflight import camera_pixel_problem
    from napari_symbac.fit.report import (
        CLI_CAMERA_FIX,
        camera_text,
        cells_records,
        colony_gains_text,
        colony_noise_text,
        lens_problem,
        mask_labels,
        model_free_camera_check,
        parameter_table,
        read_noise_note,
        report_problems,
        report_text,
    )
    from napari_symbac.settings import save_settings

    masks, labels, camera = prepared.masks, prepared.labels, prepared.camera
    camera_note, options, notes = prepared.camera_note, prepared.options, list(prepared.notes)
    censor_note, polarity = prepared.censor_note, prepared.polarity
    geometry = _GEOMETRIES[args.geometry]
    given = keys.get("simulation") or {}
    keep = {*given, *(f"agar_pad.{k}" for k in (given.get("agar_pad") or {}))}
    settings, said = fitted_pipeline(result, frame, microscope, camera, base=base, keep=keep)
    notes += said
    if (gains_note := colony_gains_text(result)) is not None:
        notes.append(f"{gains_note} in settings.yaml; each cell's: optical_path_gain, cells.json")
    camera_used = getattr(result, "camera", None) or camera or base.camera  # as fitted

    records = cells_records(result)
    if masks is not None and not prepared.colony:  # which of the user's masks each is
        for record, label in zip(records, mask_labels(result, masks), strict=True):
            record["mask_label"] = label
    if track_ids is not None:
        for record, track in zip(records, np.asarray(track_ids).tolist(), strict=True):
            record["track"] = int(track)
    table = {
        "cells": records,
        "coordinates": "um from the top-left corner of the image; angle in radians",
        "trench": None if result.trench is None else dataclasses.asdict(result.trench),
        "parameters": parameter_table(result),
        "terms": {k: list(v) for k, v in result.terms.items()},
    }
    facts = {
        "image": f"{args.image} (frame {index}, {frame.shape[0]} x {frame.shape[1]} px)",
        "modality": f"{microscope.modality} ({_polarity_said(polarity, microscope.modality)})",
        "geometry": args.geometry + (
            f" (closed end: {_closed_end_said(result, options)})" if geometry == "trench" else ""
        ),
        "start": "painted labels" if labels is not None else (
            "instance masks" if masks is not None else "automatic segmentation"
        ),
        "pixel size": pixel_note,
        "config": _config_note(args.config, keys, geometry),
        "camera": camera_note,
        "camera used": camera_text(camera_used),
        "censored pixels": censor_note,
    }
    problems = _cell_problems(
        result, frame.shape, microscope.pixel_size_um, masks, prepared.colony
    )
    problems += [p] if (p := camera_pixel_problem(microscope)) else []
    problems += [p] if (p := lens_problem(result.render, microscope)) else []
    problems += [p] if (p := _trench_as_field(args.geometry, frame.shape, microscope)) else []
    if prepared.colony:
        facts["start"] = "instance masks (the cells as given; the optics fitted to them)"
        facts["camera"] = (
            f"not fitted: Gaussian noise, {colony_noise_text(result)}, baseline "
            f"{camera_used.baseline_adu:g} ADU" + (" (--camera)" if args.camera else "")
        )
        del facts["camera used"]
    elif camera is None:  # the engine estimated it: check it model-free
        if said := read_noise_note(camera_used):
            notes.append(said)
        check, problem = model_free_camera_check(frame, camera_used, CLI_CAMERA_FIX)
        facts["camera (model-free)"] = check
        if problem and check.startswith("not available") and masks is None and (
            labels is None and microscope.modality == "phase" and geometry != "trench"
        ):
            problem += (
                " (a dense phase-contrast colony is fitted from its instance masks: pass "
                "--masks, and the partially coherent model draws its halo and seams)"
            )
        problems += [problem] if problem else []
    if args.counts_mapping is not None:
        facts = _said_in_read_counts(facts, args.counts_mapping)
        notes.append(counts_units_note(args.counts_mapping))
    report = report_text(result, facts, problems)
    if notes:
        report += "\nNOTES\n" + "".join(f"- {n}\n" for n in notes)
    figure = before_after_figure(
        frame, result.synthetic, result.residual, getattr(result, "synthetic_before", None)
    )

    def write_png(path: Path) -> None:
        import imageio.v3 as iio

        iio.imwrite(path, figure)

    residual = np.asarray(result.residual, np.float32)  # at the recording's scale (found
    # as a user: Fiji and napari opened it in pixels)
    scaled = tiff_metadata(residual, pixel_size_um=microscope.pixel_size_um)
    writers = {
        "settings.yaml": lambda p: save_settings(settings, p),
        "cells.json": lambda p: p.write_text(json.dumps(table, indent=2, default=float)),
        "residual.tif": lambda p: tifffile.imwrite(p, residual, **scaled),
        "before_after.png": write_png,
        "report.txt": lambda p: p.write_text(report),
    }
    return writers, result, report_problems(result, problems)


def _start_render(args, render):
    """The render settings a fit starts from: with ``--envelope-stain``,
    :func:`~napari_symbac.fit.scene_fit.envelope_stain_start`'s; with ``--depth-layers``,
    :func:`~napari_symbac.fit.scene_fit.depth_start`'s."""
    from napari_symbac.fit.scene_fit import depth_start, envelope_stain_start

    if getattr(args, "envelope_stain", False):
        render = envelope_stain_start(render)
    layers = getattr(args, "depth_layers", 0)
    return depth_start(render, layers) if layers else render


def _problems_said(index: int, problems: list[str]) -> str:
    """Each problem of a frame's report.txt on stderr, as a warning, and the end of the
    frame's line on stdout that counts them (found as a user: a 10x pixel-size slip gave
    35 cells at their bounds, and stdout said only "fitted 35 cells")."""
    for problem in problems:
        said = problem.removeprefix("warning: ")
        print(f"napari-symbac fit: frame {index}: problem: {said}", file=sys.stderr)
    n = len(problems)
    return f"; {n} problem{'s' * (n != 1)}, see report.txt" if n else ""


def counts_units_mark(mapping: CountsMapping) -> str:
    """Appended to a line that quotes ADU when the image was read as counts: its ADU are
    the map's, not a camera's."""
    return f" [{mapping.what}, {mapping.formula}: not a real camera's units]"


def counts_units_note(mapping: CountsMapping, where: str = "this report") -> str:
    """A note of ``where`` (a report, a file) when the image was read as counts: every
    ADU and e- in it is the map's."""
    return (
        f"every ADU and e- in {where} is of the {mapping.what}, "
        f"{mapping.formula}: not of a real camera (its gain, baseline and noise in those "
        "units)"
    )


def counts_record(mapping: CountsMapping | None) -> dict[str, Any] | None:
    """series.json's and diagnosis.json's ``counts_mapping``: how a normalised image was
    read as counts (``counts_adu = (value + shift) * adu_per_unit``) and that the file's
    camera and intensities are in those units, as each report.txt says; ``None`` for an
    image of counts."""
    if mapping is None:
        return None
    return {
        **dataclasses.asdict(mapping),
        "read_as": mapping.formula,
        "note": counts_units_note(mapping, "this file"),
    }


def _said_in_read_counts(facts: dict[str, str], mapping: CountsMapping) -> dict[str, str]:
    """report.txt's facts for a normalised image read as counts: the reading said after
    the image, and each camera line that quotes ADU marked as in those units, so that
    its gain is not taken for a real camera's (found as a user: DeLTA's trench, 0.015
    ADU/e-, 531 e-)."""
    said: dict[str, str] = {}
    for key, value in facts.items():
        quotes_adu = key.startswith("camera") and "ADU" in value
        said[key] = value + counts_units_mark(mapping) if quotes_adu else value
        if key == "image":
            said["image values"] = mapping.note
    return said


def _fit_frames_jointly(
    args, stack, frames, labels, masks, microscope, pixel_note, base, keys, stages, timer
):
    """Several frames: one joint fit (:func:`~napari_symbac.fit.fit_series`), optics and
    camera shared, cells per frame; each frame's files in ``frame_NNNN/``, the shared
    parameters (joint and frame by frame) and the cells' tracks in ``series.json``, and
    the tracks as a Cell Tracking Challenge result in ``ctc/01_RES/`` (``mask{TTT}.tif``
    with track ids, ``res_track.txt``; CTC frame ``k`` is the ``k``-th fitted frame)."""
    from napari_symbac.fit import fit_series
    from napari_symbac.fit.report import cells_counted, read_noise_note

    n_frames = stack.shape[0]
    prepared = [
        _prepare_one(
            args,
            stack[index],
            _per_frame(labels, index, n_frames, stack.shape[1:]),
            _per_frame(masks, index, n_frames, stack.shape[1:]),
            microscope,
            base,
            keys,
        )
        for index in frames
    ]
    if masks is not None and any(p.colony for p in prepared):
        return _fit_colony_frames(
            args, stack, frames, prepared, microscope, pixel_note, base, keys, stages, timer
        )
    first = prepared[0]
    camera = first.camera
    if camera is None:
        note = "measured once from the pooled frames by photon transfer (fit_series)"
        prepared = [dataclasses.replace(p, camera_note=note) for p in prepared]
    options = {k: v for k, v in first.options.items() if k not in ("labels", "masks", "valid")}
    if args.max_iterations is not None:  # the joint refinement's as well as each frame's
        options["joint_iterations"] = args.max_iterations
    per_frame = {
        key: np.stack([p.options[key] for p in prepared]) if first.options.get(key) is not None
        else None
        for key in ("labels", "masks", "valid")
    }
    shape = stack.shape[1:]
    stages.stage(
        f"fitting frames {', '.join(map(str, frames))} jointly ({shape[0]} x {shape[1]} px)"
    )
    update, close = stages.bar("fit frames")
    with timer.step("fit frames jointly"):
        try:
            series = fit_series(
                stack[frames], microscope, _start_render(args, base.render), camera,
                progress=update, frame_numbers=frames,
                **options, **per_frame,
            )
        finally:
            close()
    writers: dict[str, Callable[[Path], None]] = {}
    summaries = []
    lineage = series.lineage
    for k, (index, ready, result) in enumerate(zip(frames, prepared, series.frames, strict=True)):
        if camera is None:
            # the pooled frames' camera, or, where their photon transfer measured none (a
            # normalised series: found as a user, a traceback), this frame's own
            used = series.camera if series.camera is not None else result.camera
            measured = [said] if (said := read_noise_note(used)) else []
            ready = dataclasses.replace(ready, camera=used, notes=[*ready.notes, *measured])
        # found as a user: the shared optics' line read "defocus_sigma_um: 0.354 +- 0.00302"
        # here, an SE series.json holds nowhere; the joint fit's are named with its problems
        joint = [
            f"{name} is shared by the frames and fitted jointly: {value:.4g} +- {se:.2g} "
            "(series.json 'shared': the value to use; PARAMETERS below are this frame's)"
            for name, (value, se) in series.shared().items()
        ]
        joint += [f"joint fit: {warning}" for warning in series.warnings]
        ready = dataclasses.replace(ready, notes=[*ready.notes, *joint])
        writers_one, _, problems = _outputs_one(
            args, stack[index], index, ready, result, microscope, pixel_note, base, keys,
            track_ids=lineage.track_ids[k],
        )
        writers.update({f"frame_{index:04d}/{k}": v for k, v in writers_one.items()})
        carried = f" (from frame {frames[k - 1]}'s cells)" if series.carried[k] else ""
        summaries.append(
            f"frame {index}: fitted {cells_counted(len(result.cells))}{carried}; pixel chi2 "
            f"{result.objective_before:.3g} -> {result.objective_after:.3g}"
            + _problems_said(index, problems)
        )
    table = {
        "frames": frames,
        "shared": {
            name: {
                "value": float(value),
                "se": float(se),
                "frame_by_frame": [
                    {"frame": f, "value": float(v), "se": float(e)}
                    for f, v, e in zip(
                        frames, series.frame_values[:, k], series.frame_standard_errors[:, k]
                    )
                ],
            }
            for k, (name, value, se) in enumerate(
                zip(series.shared_names, series.shared_values, series.shared_standard_errors)
            )
        },
        "camera": None if series.camera is None else dataclasses.asdict(series.camera),
        "counts_mapping": counts_record(args.counts_mapping),
        "warnings": list(series.warnings),
        "joint_iterations": series.iterations,  # at most --max-iterations when given
        "started_from_previous_frame": dict(zip(map(str, frames), series.carried)),
        # with the previous frame where they overlap, registered (null for the first)
        "correlation_with_previous_frame": {
            str(f): (round(c, 4) if np.isfinite(c) else None)
            for f, c in zip(frames, series.frame_correlation, strict=True)
        },
        "lineage": _lineage_record(lineage, frames),
    }
    if np.any(np.diff(frames) != 1):
        table["lineage"]["note"] = GAPPED_FRAMES_NOTE
    writers["series.json"] = lambda p: p.write_text(json.dumps(table, indent=2))
    writers.update(_ctc_result(series, frames, microscope.pixel_size_um))
    summaries += [
        f"shared {name}: {value:.4g} +- {se:.2g} (joint)"
        for name, (value, se) in series.shared().items()
    ]
    summaries.append(_tracks_line(lineage, frames))
    # found as a user: the joint fit's "stopped at the iteration limit" and the gapped
    # frames' note were only inside series.json (a gap linked a division's daughters wrong)
    summaries += [f"PROBLEM (joint fit): {warning}" for warning in series.warnings]
    summaries += [f"NOTE (tracks): {GAPPED_FRAMES_NOTE}"] * ("note" in table["lineage"])
    return writers, summaries


def _fit_colony_frames(
    args, stack, frames, prepared, microscope, pixel_note, base, keys, stages, timer
):
    """A phase colony's time-lapse with its masks (:func:`~napari_symbac.fit.fit_colony_series`):
    the optics fitted on all frames jointly (started from the frame whose masks cover
    most), every frame drawn from its masks with its own media level; the masks' cells
    tracked. Files as :func:`_fit_frames_jointly` writes them."""
    from napari_symbac.fit import fit_colony_series
    from napari_symbac.fit.report import COLONY_NOTE, OPEN_PHASE_NOTE

    # frames of a colony too young to be dense are drawn alike (the model is the same)
    prepared = [
        dataclasses.replace(
            p, colony=True, notes=[n for n in p.notes if n not in (OPEN_PHASE_NOTE, COLONY_NOTE)]
            + [COLONY_NOTE]
        )
        for p in prepared
    ]
    shape = stack.shape[1:]
    stages.stage(
        f"fitting frames {', '.join(map(str, frames))} (colony from its masks, partially "
        f"coherent phase model, optics fitted jointly; {shape[0]} x {shape[1]} px)"
    )
    update, close = stages.bar("fit frames")
    with timer.step("fit frames"):
        try:
            series = fit_colony_series(
                stack[frames], microscope, [p.masks for p in prepared], prepared[0].camera,
                progress=update,
            )
        finally:
            close()
    writers: dict[str, Callable[[Path], None]] = {}
    summaries = []
    lineage = series.lineage
    reference = frames[series.reference]
    for k, (index, ready, result) in enumerate(zip(frames, prepared, series.frames, strict=True)):
        ready.notes.append(
            "the optics are fitted on all frames jointly (started from frame "
            f"{reference}'s own fit: its masks cover most); the media level is this frame's "
            "(fit_colony_series; series.json)"
        )
        writers_one, _, problems = _outputs_one(
            args, stack[index], index, ready, result, microscope, pixel_note, base, keys,
            track_ids=lineage.track_ids[k],
        )
        writers.update({f"frame_{index:04d}/{k}": v for k, v in writers_one.items()})
        summaries.append(
            f"frame {index}: {len(result.cells)} cells from the masks; pixel chi2 "
            f"{result.objective_before:.3g} -> {result.objective_after:.3g}"
            + _problems_said(index, problems)
        )
    before, after = series.joint_objective
    table = {
        "frames": frames,
        "optics_started_on_frame": reference,
        "joint_chi2": {"start": before, "end": after},
        "shared": {
            name: {"value": value, "se": se} for name, (value, se) in series.shared().items()
        },
        "media_intensity": [
            {"frame": f, "value": float(v)} for f, v in zip(frames, series.media_levels())
        ],
        "counts_mapping": counts_record(args.counts_mapping),
        "warnings": list(series.warnings),
        "lineage": {
            **_lineage_record(lineage, frames),
            "cell_ids": "each frame's cells.json ids are its masks' labels",
        },
    }
    writers["series.json"] = lambda p: p.write_text(json.dumps(table, indent=2))
    writers.update(_ctc_result(series, frames, microscope.pixel_size_um))
    summaries.append(
        f"optics fitted on frames {', '.join(map(str, frames))} jointly (started from frame "
        f"{reference}'s fit): pixel chi2 over all frames {before:.4g} -> {after:.4g}"
    )
    summaries += [
        f"shared {name}: {value:.4g} +- {se:.2g}" for name, (value, se) in series.shared().items()
    ]
    summaries.append(_tracks_line(lineage, frames))
    summaries += [f"PROBLEM (joint fit): {warning}" for warning in series.warnings]
    return writers, summaries


#: Said of a series fitted from frames that are not consecutive (series.json and stdout).
GAPPED_FRAMES_NOTE = (
    "the frames are not consecutive: the links assume one growth and drift per step "
    "between the frames given, so a division or a cell that left between them can be "
    "linked wrong; fit consecutive frames (e.g. --frames 0-3) to track cells"
)


def _lineage_record(lineage, frames: list[int]) -> dict:
    """series.json's ``lineage``: the tracks, each frame's track ids, the growth and drift
    the links found, and where the CTC result is."""
    return {
        "tracks": lineage.table(frames),
        "track_ids": {str(f): ids.tolist() for f, ids in zip(frames, lineage.track_ids)},
        "growth_per_frame": lineage.growth_per_frame,
        # null between frames that share no cell: nothing measured the field's shift
        "drift_um": [
            shift if t >= len(lineage.link_costs) or np.isfinite(lineage.link_costs[t]).any()
            else None
            for t, shift in enumerate(lineage.drift_um.tolist())
        ],
        "ctc": "ctc/01_RES: mask{TTT}.tif (track ids) and res_track.txt (L B E P); "
        "CTC frame k is the k-th of 'frames'",
    }


def _tracks_line(lineage, frames: list[int]) -> str:
    """The summary line of a series' tracks."""
    return (
        f"tracks: {len(lineage.tracks)} over {len(frames)} frames, "
        f"{len(lineage.divisions())} division(s) (series.json 'lineage', "
        "ctc/01_RES/res_track.txt)"
    )


def _ctc_result(series, frames: list[int], pixel_size_um: float) -> dict:
    """Writers of ``ctc/01_RES/``: one track-id mask per fitted frame and ``res_track.txt``."""
    from napari_symbac.export.atomic import write_tiff

    lineage = series.lineage
    digits = max(3, len(str(len(frames) - 1)))
    writers: dict[str, Callable[[Path], None]] = {}
    for k, result in enumerate(series.frames):
        mask = lineage.track_mask(k, result.scene.camera_labels(), result.cells.ids)
        writers[f"ctc/01_RES/mask{k:0{digits}d}.tif"] = lambda p, m=mask: write_tiff(
            p, m, pixel_size_um=pixel_size_um, kind="labels"
        )
    text = lineage.ctc_text()
    writers["ctc/01_RES/res_track.txt"] = lambda p: p.write_text(text)
    return writers


def run_fit(args: argparse.Namespace) -> int:
    """Run ``napari-symbac fit`` with parsed arguments; returns the exit code."""
    from napari_symbac.diagnose.config import load_microscope_file
    from napari_symbac.export.atomic import earlier_run
    from napari_symbac.fit.preflight import (
        camera_pixel_problem,
        check_fit_image,
        default_geometry,
        refuse_constant,
        resolve_pixel_size,
    )
    from napari_symbac.fit.report import cells_counted, write_atomically
    from napari_symbac.settings import (
        PipelineSettings,
        load_settings,
        microscope_sets_pixel_size,
    )

    earlier = earlier_run(args.out, "fit", _fit_writes)
    timer = StepTimer()
    stages = _Stages()
    stages.stage("loading inputs")
    with timer.step("load"):
        recording = read_recording(args.image, channel=args.channel)
        args.counts_mapping = recording.counts_mapping  # report.txt says the reading too
        data = np.asarray(recording.data)
        name = Path(args.image).name
        if data.ndim not in (2, 3):
            raise ValueError(f"{name} must be one 2D frame or a (T, Y, X) series, got {data.shape}")
        stack = data if data.ndim == 3 else data[None]
        frames = parse_frames(args.frames, stack.shape[0], name)
        for index in frames:  # negative values first: a constant negative image has them
            frame_name = name + (f" frame {index}" if len(stack) > 1 else "")
            check_fit_image(stack[index], frame_name)
            refuse_constant(stack[index], frame_name)
        if args.max_iterations is not None and args.max_iterations < 1:
            raise ValueError(f"--max-iterations must be at least 1, got {args.max_iterations}")
        base = PipelineSettings() if args.config is None else load_settings(
            args.config, PipelineSettings
        )
        keys = _explicit_keys(args.config)  # after load_settings: its refusals name the file
        # found as a user: the camera section the help names was refused here ("unknown
        # field(s) camera in Microscope") while diagnose read it
        microscope_file = load_microscope_file(args.microscope)
        microscope, args.microscope_camera = microscope_file.microscope, microscope_file.camera
        if "frame_interval_min" not in (keys.get("simulation") or {}):  # the config's wins
            timed = microscope_file.timed(base.simulation, recording.frame_interval_s)
            base = dataclasses.replace(base, simulation=timed)
        modality = args.modality or recording.modality or microscope.modality
        if modality != microscope.modality:
            microscope = dataclasses.replace(microscope, modality=modality)
        microscope, pixel_note = resolve_pixel_size(
            recording.pixel_size_um,
            microscope,
            microscope_gives_it=microscope_sets_pixel_size(args.microscope),
            flag_pixel_um=args.pixel_size_um,
        )
        # found as a user: unknown keys ignored unsaid
        for note in microscope_file.notes_for(microscope.modality):
            print(f"napari-symbac fit: note: {note}", file=sys.stderr)
        if problem := camera_pixel_problem(microscope):  # before the fit, not after it
            print(f"napari-symbac fit: warning: {problem}", file=sys.stderr)
        refuse_lying_trench(args, stack.shape, microscope.modality)
        if args.geometry is None:
            configured = (keys.get("simulation", {}) or {}).get("geometry")
            args.geometry = default_geometry(stack.shape, microscope.modality, configured)
        elif args.geometry == "trench" and microscope.modality == "fluorescence":
            raise ValueError(
                "a fluorescence image shows no trench walls to find (the PDMS is as dark as "
                "the media): pass --geometry field, which fits the cells as in an open field"
            )
        if (pixels := stack.shape[-2] * stack.shape[-1]) > LARGE_FRAME_PX:
            print(  # found as a user: a 2048 x 2048 field ran past 15 min, unannounced
                f"napari-symbac fit: note: a frame of {stack.shape[-2]} x {stack.shape[-1]} "
                f"px, {pixels / 512**2:.0f} times a 512 x 512 field (2-3 min on 2 cores with "
                "100 cells, docs/fitting.md): the fit takes about that many times as long "
                "or more, and GBs of memory; a crop of the region of interest fits faster",
                file=sys.stderr,
            )
        labels = None if args.labels is None else _read_stack(args.labels, "--labels")
        masks = None if args.masks is None else _read_stack(args.masks, "--masks")

    writers: dict[str, Callable[[Path], None]] = {}
    summaries = []
    if len(frames) > 1 and args.illumination_order > 0:
        raise ValueError(
            "--illumination-order is fitted for single frames only (the joint fit of a "
            "series does not take the surface yet): fit one frame (--frames N) or leave it out"
        )
    if len(frames) > 1:
        writers, summaries = _fit_frames_jointly(
            args, stack, frames, labels, masks, microscope, pixel_note, base, keys, stages, timer
        )
    for index in frames if len(frames) == 1 else []:
        frame = stack[index]
        writers_one, result, problems = _fit_one(
            args,
            frame,
            index,
            _per_frame(labels, index, stack.shape[0], frame.shape),
            _per_frame(masks, index, stack.shape[0], frame.shape),
            microscope,
            pixel_note,
            base,
            keys,
            stages,
            timer,
        )
        writers.update(writers_one)
        summaries.append(
            f"frame {index}: fitted {cells_counted(len(result.cells))}; pixel chi2 "
            f"{result.objective_before:.3g} -> {result.objective_after:.3g}"
            + _problems_said(index, problems)
        )
    first = f"frame_{frames[0]:04d}/settings.yaml"
    if len(frames) > 1 and first in writers:  # found as a user: `export --config
        writers["settings.yaml"] = writers[first]  # OUT/settings.yaml` of a series failed
    stages.stage("writing outputs")
    with timer.step("write"):
        write_atomically(args.out, writers, replaced=earlier)
    print("\n".join(summaries))
    print(_written_text(writers, args.out, frames[0]))
    print(timer.report())
    return 0


def _written_text(writers: dict[str, Any], out: str, first_frame: int) -> str:
    """The files ``fit`` wrote, in words: a series' folders by name, and what each holds."""
    top = sorted({name.split("/")[0] + ("/" if "/" in name else "") for name in writers})
    per_frame = sorted(
        {name.split("/", 1)[1] for name in writers if name.startswith("frame_")}
    )
    text = f"wrote {', '.join(top)} to {out}"
    if per_frame:
        text += (
            f" (each frame_NNNN/ holds {', '.join(per_frame)}; settings.yaml is frame "
            f"{first_frame}'s)"
        )
    return text
