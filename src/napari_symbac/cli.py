"""The ``napari-symbac`` command: every step of the pipeline, headless.

Run ``napari-symbac --help`` or ``napari-symbac COMMAND --help``.
"""

from __future__ import annotations

import argparse
import contextlib
import difflib
import os
import re
import shutil
import signal
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from napari_symbac import __version__
from napari_symbac._timing import StepTimer, progress_bar

if TYPE_CHECKING:
    import numpy as np

    from napari_symbac.io import CountsMapping

__all__ = ["interrupted_text", "main"]


def _tqdm_progress(
    desc: str, total: int | None = None, unit: str = "frames", *, bound: bool = False
) -> tuple[Callable[[int, int], None], object]:
    """``(update, handle)``: a tqdm bar on a terminal, lines when piped (stderr;
    :func:`~napari_symbac._timing.progress_bar`; ``bound``: the total is an upper bound)."""
    return progress_bar(desc, total, unit, sys.stderr, bound=bound)


def _whole_number(minimum: int) -> Callable[[str], int]:
    """argparse type: an integer >= ``minimum``, else a usage error naming the option
    (argparse puts it first) and what was given."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"must be a whole number >= {minimum}, got {text!r}"
            ) from None
        if value < minimum:
            least = f"at least {minimum}" if minimum else f"{minimum} or more"
            raise argparse.ArgumentTypeError(f"must be {least}, got {value}")
        return value

    return parse


#: An integer >= 1 (counts: frames, items, workers).
_at_least_one = _whole_number(1)
#: A seed, an integer >= 0 (numpy's seeds). Found as a user: `diagnose --seed -3` said
#: "expected non-negative integer", naming no option, after its 11 s base fit, and
#: `calibrate --seed -4` refused only after its fit.
_seed = _whole_number(0)


def _geometry_word(text: str) -> str:
    """``--geometry``'s value: ``open`` (the Python API's word) is ``field``."""
    return "field" if text == "open" else text


def _count(n: int, noun: str) -> str:
    """``n`` and ``noun``, plural unless ``n`` is 1 ("1 cell", "5 frames")."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def _output_folder(path: str | Path, option: str = "--out", *, staged: bool = False) -> Path:
    """``path`` as a folder to write into, checked before any work is done
    (:func:`~napari_symbac.export.atomic.check_output_folder`)."""
    from napari_symbac.export.atomic import check_output_folder

    return check_output_folder(path, option, staged=staged)


#: Effects a diagnosis accepts at most unless ``--max-effects`` says otherwise: the
#: ``max_steps`` of :func:`napari_symbac.diagnose.diagnose` (not imported here, so that
#: ``--help`` stays fast). Found as a user: on ColiCoords' crop 01 the envelope stain
#: (evidence 133) was never held-out tested after four effects, with no way to ask.
DIAGNOSE_MAX_EFFECTS = 4

#: Simulated plus rendered frames above which a run needs ``--yes``.
LARGE_RUN_FRAMES = 100_000
#: Frames per second assumed for the estimate in the ``--yes`` message (simulation and
#: rendering on a 2-core machine run at about 50-70 frames/s).
_FRAMES_PER_S = 50.0


def _confirm_large_run(frames: int, what: str, yes: bool) -> None:
    """Refuse a run of more than :data:`LARGE_RUN_FRAMES` frames unless ``--yes`` is given."""
    if frames <= LARGE_RUN_FRAMES or yes:
        return
    hours = frames / _FRAMES_PER_S / 3600
    raise ValueError(
        f"{what} is roughly {hours:,.1f} h of work ({frames:,} frames to simulate or render "
        f"at ~{_FRAMES_PER_S:g} frames/s on a 2-core machine): add --yes to start it "
        "anyway, or lower the number of frames"
    )


def _local_workers(workers: int | None) -> int | None:
    """``--workers``, capped to the cores of this machine (with a note when capped)."""
    import os

    cores = os.cpu_count() or 1
    if workers is not None and workers > cores:
        print(
            f"napari-symbac export: note: --workers {workers} capped to {cores}, the cores "
            "of this machine (use --scheduler to run on more machines)",
            file=sys.stderr,
        )
        return cores
    return workers


# --------------------------------------------------------------------------------------
# Commands
# --------------------------------------------------------------------------------------


def _load_pipeline(config: str | None):
    from napari_symbac.settings import PipelineSettings, load_settings

    if config is None:
        return PipelineSettings()
    settings = load_settings(config, PipelineSettings)
    _check_config_pixel_size(settings, config)
    return settings


def _check_config_pixel_size(pipeline, config: str) -> None:
    """A settings file's pixel size no bacterial micrograph has, refused naming the file
    and the field (found as a user: 65, nm for um, gave "the field of view is smaller
    than one camera pixel (65.0 um)" from render and export)."""
    from napari_symbac.fit.preflight import check_pixel_size

    check_pixel_size(
        pipeline.microscope.pixel_size_um, f"microscope.pixel_size_um of settings file {config}"
    )


def _cmd_simulate(args: argparse.Namespace) -> int:
    import dataclasses

    from napari_symbac.settings import SimulationSettings, load_simulation_settings
    from napari_symbac.sim import simulate

    settings = (
        SimulationSettings()
        if args.config is None
        else load_simulation_settings(args.config)
    )
    overrides = {k: v for k, v in (("n_frames", args.frames), ("seed", args.seed)) if v is not None}
    out = _output_folder(args.out or settings.save_dir or "simulation")
    n_frames = overrides.get("n_frames", settings.n_frames)
    _confirm_large_run(n_frames, f"simulating {n_frames:,} frames", args.yes)
    # simulate() saves to save_dir itself, atomically, once the run is complete.
    settings = dataclasses.replace(settings, **overrides, save_dir=str(out))
    replaced = (out / "simulation.json").is_file()
    before = sorted(p.name for p in out.iterdir()) if out.is_dir() else []
    timer = StepTimer()
    update, bar = _tqdm_progress("simulate", settings.n_frames)
    with timer.step("simulate and save"):
        simulation = simulate(settings, progress=update)
    bar.close()
    print(
        f"wrote simulation of {_count(settings.n_frames, 'frame')}, "
        f"{_count(len(simulation.lineage), 'cell')} to {out}"
    )
    if replaced:  # said as render says it (found as a user: replaced without a word,
        # and the earlier simulation's renders removed with it unsaid)
        gone = [name for name in before if not (out / name).exists()]
        removed = f", and removed what it held beside it ({', '.join(gone)})" if gone else ""
        print(
            f"napari-symbac simulate: note: replaced the simulation that {out} "
            f"held{removed} (simulate to another --out to keep both)",
            file=sys.stderr,
        )
    print(timer.report())
    return 0


def _backend(args: argparse.Namespace) -> str:
    """``--backend`` and ``--device`` as one resolved name (``"torch:cuda"``, ...)."""
    from napari_symbac.optics.batched import resolve_backend

    return resolve_backend(args.backend, args.device)


#: ``--backend`` and ``--device`` choices (those of :mod:`napari_symbac.optics.batched`,
#: not imported here so that ``--help`` stays fast).
_BACKENDS = ("scipy", "torch", "cupy")
_DEVICES = ("auto", "cpu", "cuda")


def _add_backend_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--backend",
        choices=_BACKENDS,
        default="scipy",
        help="render on the CPU with scipy (default, the reference), in batches on a torch "
        "device (every stage from the scene's components to the uint16 image; another "
        "noise stream) or convolve on a CUDA GPU with cupy",
    )
    parser.add_argument(
        "--device",
        choices=_DEVICES,
        help="torch device (default: auto, cuda when torch sees a GPU, else cpu)",
    )


def _cmd_render(args: argparse.Namespace) -> int:
    import dataclasses

    from napari_symbac.export.atomic import write_tiff
    from napari_symbac.export.dataset import dark_fluorescence
    from napari_symbac.pipeline import render_simulation
    from napari_symbac.sim import load_simulation

    timer = StepTimer()
    with timer.step("load"):
        settings = _load_pipeline(args.config)
        dark_cells = dark_fluorescence(settings)
        if dark_cells is not None:  # found as a user: export refused it, render drew it
            raise ValueError(f"--config {args.config}: {dark_cells}")
        simulation = load_simulation(args.simulation)
        settings = dataclasses.replace(settings, simulation=simulation.settings)
    out = _output_folder(args.out)
    backend = _backend(args)
    if args.config is None:  # found as a user: a simulation of a fitted fluorescence
        # field rendered as the built-in phase contrast at 0.065 um/px, unsaid
        mic = settings.microscope
        print(
            "napari-symbac render: note: no --config: the built-in microscope renders it "
            f"({mic.modality}, {mic.pixel_size_um:g} um/px); pass the settings.yaml of "
            "your fit or calibrate (--config) to render it as your recording",
            file=sys.stderr,
        )
    update, bar = _tqdm_progress("render", len(simulation.frames))
    with timer.step(f"render ({backend})"):
        series = render_simulation(simulation, settings, progress=update, backend=backend)
    bar.close()
    calibration = {
        "pixel_size_um": settings.microscope.pixel_size_um,
        "frame_interval_min": settings.simulation.frame_interval_min,
        "compression": "zlib",
    }
    arrays = {"images": series.images, "labels": series.labels, "semantic": series.semantic}
    replaced = [f"{name}.tif" for name in arrays if (out / f"{name}.tif").exists()]
    created = not out.exists()
    with timer.step("write"):
        # each file atomically: a full disk leaves no partial file, and names the path
        try:
            for name, array in arrays.items():
                kind = "image" if name == "images" else name
                write_tiff(out / f"{name}.tif", array, kind=kind, **calibration)
        except BaseException:
            if created:  # found as a user: a full disk left an empty --out, or images
                shutil.rmtree(out, ignore_errors=True)  # without their labels
            raise
    print(f"wrote images.tif, labels.tif, semantic.tif {series.images.shape} to {out}")
    _say_extra_stages(settings)
    if replaced:
        print(
            f"napari-symbac render: note: replaced the {', '.join(replaced)} that {out} "
            "held (render to another --out to keep both)",
            file=sys.stderr,
        )
    print(timer.report())
    return 0


def _cmd_export(args: argparse.Namespace) -> int:
    import dataclasses

    from napari_symbac.export import export_dataset, load_export_settings
    from napari_symbac.export.dataset import (
        default_first_frame,
        no_validation_note,
        short_run_note,
    )

    settings = load_export_settings(args.config)
    _check_config_pixel_size(settings.pipeline, args.config)
    flags = {"n-items": args.n_items, "n-frames": args.n_frames}
    flags |= {"formats": args.formats, "kind": args.kind}  # set together: ctc needs both
    flags = {flag: value for flag, value in flags.items() if value is not None}
    fields = {key.replace("-", "_"): value for key, value in flags.items()}
    try:  # all at once (found as a user: --kind timeseries --n-frames 10 was refused for
        # first_frame, checked against the shorter run before the kind was set)
        if (n_frames := fields.pop("n_frames", None)) is not None:  # found as a user: a
            pipeline = settings.pipeline  # field fit's settings.yaml holds 1 frame
            simulation = dataclasses.replace(pipeline.simulation, n_frames=n_frames)
            fields["pipeline"] = dataclasses.replace(pipeline, simulation=simulation)
            if settings.first_frame == default_first_frame(pipeline.simulation):  # not
                # the file's own: drawn from the run as it now is (found as a user:
                # --n-frames 10 refused for the first_frame 16 of the default 50 frames)
                fields["first_frame"] = default_first_frame(simulation)
        settings = dataclasses.replace(settings, **fields)
    except ValueError as err:
        named = " ".join(f"--{flag} {value!r}" for flag, value in flags.items())
        raise ValueError(f"{named}: {err}") from None
    short = n_frames is not None and settings.kind == "frames"
    if short and (note := short_run_note(settings.pipeline.simulation, settings.first_frame)):
        print(f"napari-symbac export: note: --n-frames {n_frames}: {note}", file=sys.stderr)
    out = _output_folder(args.out)
    backend = _backend(args)
    sim_frames = settings.pipeline.simulation.n_frames
    n_simulated = sim_frames * (
        settings.n_items if settings.kind == "timeseries" else settings.n_simulations
    )
    _confirm_large_run(
        n_simulated + settings.n_images, f"exporting {settings.n_images:,} images", args.yes
    )
    workers = None
    if args.scheduler is not None and args.workers is not None:
        print(  # found as a user: --workers 5 beside --scheduler was ignored unsaid
            f"napari-symbac export: note: --workers {args.workers} is not used with "
            "--scheduler: the scheduler's workers do the work (start more with `dask "
            f"worker {args.scheduler}`)",
            file=sys.stderr,
        )
    elif args.scheduler is None:
        workers = _local_workers(args.workers)
    timer = StepTimer()
    update, bar = _tqdm_progress("export", settings.n_images, "images")
    with timer.step("export"):
        report = export_dataset(
            settings,
            out,
            workers=workers,
            scheduler=args.scheduler,
            progress=update,
            backend=backend,
        )
    bar.close()
    print(report)
    if workers is not None and report.workers < workers and not report.cancelled:
        print(  # found as a user: --workers 2 ran with 1 and only the report's count said it
            f"napari-symbac export: note: {workers} workers allowed (--workers "
            f"{args.workers}), {report.workers} used: an export this short finishes in "
            "this process before worker processes would have started (docs/export.md)",
            file=sys.stderr,
        )
    _say_extra_stages(settings.pipeline)
    if note := no_validation_note(settings):
        print(f"napari-symbac export: note: {note}", file=sys.stderr)
    print(timer.report())
    return 0


def _say_extra_stages(pipeline) -> None:
    """Name the diagnosed effects drawn as extra stages (found as a user: diagnose said
    export draws them, and export's own lines did not say it had)."""
    if pipeline.extra_stages:
        names = ", ".join(stage.name for stage in pipeline.extra_stages)
        print(f"drawn with the settings' extra stages: {names}")


def _cmd_fit(args: argparse.Namespace) -> int:
    from napari_symbac._cli_fit import run_fit

    _output_folder(args.out, staged=True)  # before the fit, not after it
    return run_fit(args)


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from napari_symbac._cli_calibrate import run_calibrate

    # its items at least, before the fit (found as a user: --n-items 1000000 fitted, then
    # started days of export without a word)
    _confirm_large_run(args.n_items, f"a dataset of {args.n_items:,} items", args.yes)
    _output_folder(args.out, staged=True)  # before the fit, not after it
    return run_calibrate(args)


#: What a poor base fit of a phase-contrast field means when it is a dense colony.
DIAGNOSE_COLONY_NOTE = (
    "a dense phase-contrast colony's halo and bright seams are drawn by the colony fit "
    "(`napari-symbac fit IMAGE --masks MASKS`, the partially coherent model), not by "
    "diagnose's scene of separate rods: diagnose a window of separate cells"
)

#: Where ``diagnose`` takes the camera (it has no ``--camera``), for its refusals.
_DIAGNOSE_CAMERA_HINT = (
    "in the microscope file's camera section (camera: {baseline_adu: ..., "
    "sensitivity_adu_per_e: ..., dark_noise_e: ...})"
)


#: What ``diagnose`` writes in its --out, besides ``effect_<name>.png`` per accepted effect.
_DIAGNOSE_OUTPUTS = frozenset(
    {"diagnosis.json", "report.txt", "residuals.png", "settings.yaml", "extra_stages.yaml"}
)


def _diagnose_masks(path: str, stack_shape: tuple[int, ...]) -> np.ndarray:
    """``diagnose --masks``: instance ids ``(T, Y, X)``, one frame of them for each frame
    of the recording (a single frame's masks stand for every frame), checked as `fit`
    checks them (the image's shape, integer ids, some cells and some background; a
    binary mask's regions are the cells)."""
    import numpy as np

    from napari_symbac._cli_fit import _read_stack
    from napari_symbac.fit.preflight import as_instance_ids, check_instance_masks

    name = f"--masks {Path(path).name}"
    masks = _read_stack(path, "--masks")  # as `fit --masks` reads them
    n_frames, shape = stack_shape[0], tuple(stack_shape[1:])
    per_frame = masks.ndim == 3 and masks.shape[0] == n_frames and masks.shape[1:] == shape
    out = []
    for frame in masks if per_frame else [masks]:
        check_instance_masks(frame, shape, name)  # says which shape it should have
        out.append(as_instance_ids(frame)[0])
    return np.stack(out) if per_frame else np.repeat(out[0][None], n_frames, axis=0)


def _diagnose_writes(name: str) -> bool:
    """Whether ``diagnose`` writes an entry of this name in its --out."""
    return name in _DIAGNOSE_OUTPUTS or re.fullmatch(r"effect_\w+\.png", name) is not None


def _diagnose_report(
    report: str,
    mapping: CountsMapping | None,
    out: Path,
    context: list[str],
    problems: list[str],
) -> str:
    """diagnose's report.txt: what was diagnosed (``context``: the window, pixel size,
    camera and the base fit's cells) and the base fit's ``problems`` (found as a user:
    none of them was in the report, which named the window only on the terminal), the
    diagnosis, what to do next with its settings (found as a user: only the terminal
    said it), and for a normalised image read as counts
    (:class:`~napari_symbac.io.CountsMapping`), what its values are first and a note that
    every ADU and e- of the report is of that map, as ``fit``'s report says."""
    head = "".join(f"{line}\n" for line in context)
    if problems:
        head += (
            "\nBASE FIT PROBLEMS (as `napari-symbac fit` reports them; the findings below "
            "stand on this fit, so check these first)\n"
            + "".join(f"- {p}\n" for p in problems)
        )
    report = f"{head}\n{report}"
    next_steps = (
        "\n\nNEXT\n"
        f"- {out / 'settings.yaml'} holds the fitted settings with the accepted effects: "
        f"`napari-symbac export --config {out / 'settings.yaml'} --out DATASET` draws a "
        "training dataset with them (`napari-symbac render SIMULATION --config ...` one "
        "simulation)\n"
        "- residuals.png shows where the model still differs (after: what the effects left)"
    )
    if mapping is None:
        return report + next_steps + "\n"
    from napari_symbac._cli_fit import counts_units_note

    return (
        f"image values: {mapping.note}\n\n{report}{next_steps}\n\nNOTES\n"
        f"- {counts_units_note(mapping)}\n"
    )


def _cmd_diagnose(args: argparse.Namespace) -> int:
    import dataclasses
    import json

    import numpy as np
    import yaml

    from napari_symbac._cli_fit import (
        counts_record,
        counts_units_mark,
        in_read_units,
        number_runs,
        parse_frames,
        read_recording,
        refuse_lying_trench,
    )
    from napari_symbac.diagnose.config import NO_CAMERA_NOTE, load_microscope_file
    from napari_symbac.diagnose.figures import write_figures
    from napari_symbac.diagnose.model import build_design
    from napari_symbac.diagnose.region import CELLS, parse_region, placement, simulated_shape
    from napari_symbac.diagnose.run import diagnose
    from napari_symbac.diagnose.stages import drawn_by_export, refitted_render, updated_settings
    from napari_symbac.export.atomic import earlier_run, remove_earlier_run
    from napari_symbac.fit import fit_scene
    from napari_symbac.fit.clipped_background import drawn_clipped, fitted_clip
    from napari_symbac.fit.colony import is_dense_colony
    from napari_symbac.fit.fitted_settings import fitted_or_kept
    from napari_symbac.fit.preflight import (
        camera_pixel_problem,
        check_class_labels,
        check_fit_image,
        check_modality,
        default_geometry,
        refuse_constant,
        resolve_pixel_size,
    )
    from napari_symbac.fit.report import (
        CORRELATED_NOISE_RATIO,
        base_fit_problems,
        camera_text,
        measured_camera_note,
    )
    from napari_symbac.fit.start import WideStartError
    from napari_symbac.io import read_image
    from napari_symbac.settings import (
        PipelineSettings,
        RenderSettings,
        SimulationSettings,
        microscope_sets_pixel_size,
        save_settings,
    )

    out = _output_folder(args.out)
    earlier = earlier_run(out, "diagnose", _diagnose_writes)
    timer = StepTimer()
    with timer.step("load"):
        recording = read_recording(args.image, channel=args.channel)
        mapping = recording.counts_mapping  # a normalised image read as counts, or None
        config = load_microscope_file(args.microscope)
        # the modality as fit takes it: the flag, the file's own, the microscope file's
        modality = args.modality or recording.modality or config.microscope.modality
        microscope, pixel_note = resolve_pixel_size(
            recording.pixel_size_um,
            dataclasses.replace(config.microscope, modality=modality),
            microscope_gives_it=microscope_sets_pixel_size(args.microscope),
            flag_pixel_um=args.pixel_size_um,
        )
        if slip := camera_pixel_problem(microscope):  # before the fit, as fit says it
            print(f"napari-symbac diagnose: warning: {slip}", file=sys.stderr)
        image = np.asarray(recording.data)
        if image.ndim not in (2, 3):
            raise ValueError(
                f"{args.image} must be one frame (Y, X) or a series (T, Y, X), got {image.shape}"
            )
        stack = image[None] if image.ndim == 2 else image
        recorded = len(stack)
        # found as a user: ColiCoords ds3's four fields in one file could be diagnosed
        # only together, as a time series, or cut into a TIFF of their own
        numbers = list(range(recorded)) if args.frames is None else parse_frames(
            args.frames, recorded, Path(args.image).name
        )
        stack = stack[numbers]
        for k, frame in enumerate(stack):  # the fit's refusals (negative values: not counts)
            name = Path(args.image).name + (f" frame {numbers[k]}" if recorded > 1 else "")
            check_fit_image(frame, name, camera_hint=_DIAGNOSE_CAMERA_HINT)
            refuse_constant(frame, name)
        labels = None
        if args.labels is not None:  # fit's checks, over the whole file: a window may
            # hold only ids 1-3 of an instance mask's cells
            labels = np.asarray(read_image(args.labels, "--labels").data)
            check_class_labels(labels, stack.shape[-2:], f"--labels {Path(args.labels).name}")
        frame_shape = stack.shape[-2:]
        masks = None
        if args.masks is not None:  # one per recorded frame, or one for all
            masks = _diagnose_masks(args.masks, (recorded, *frame_shape))[numbers]
        asked = CELLS if args.region is None else args.region
        region = parse_region(asked, stack, masks=masks)
        y0, y1, x0, x1 = region
        if region != (0, frame_shape[0], 0, frame_shape[1]):
            stack = stack[:, y0:y1, x0:x1]
            labels = None if labels is None else labels[y0:y1, x0:x1]
            masks = None if masks is None else masks[:, y0:y1, x0:x1]
            if (how := placement(asked)) != "chosen":
                # the window's place is the program's choice: say where it is
                if how == "centre":
                    which = "the centre one"
                else:
                    which = "the one holding the most whole cells"
                    which += "" if masks is None else " of --masks"
                    which += " in every frame" if len(stack) > 1 else ""
                print(
                    f"note: diagnosing rows {y0}:{y1}, columns {x0}:{x1} of the "
                    f"{frame_shape[0]} x {frame_shape[1]} frame, {which} ({stack[0].size:,} "
                    f"of {frame_shape[0] * frame_shape[1]:,} pixels: a diagnosis's time and "
                    "memory grow faster than its pixels); --region Y0:Y1,X0:X1 picks "
                    "another window, --region full the whole frame",
                    file=sys.stderr,
                )
        for k, frame in enumerate(stack):  # what fit refuses, diagnose refuses too (found
            # as a user: a fluorescence field diagnosed as phase ended in advice about
            # wide cells)
            frame_masks = None if masks is None else masks[k]
            if frame_masks is not None and not frame_masks.any():
                raise ValueError(
                    f"--masks {Path(args.masks).name} hold no cell in "
                    f"{f'frame {numbers[k]}, ' if recorded > 1 else ''}rows {y0}:{y1}, "
                    f"columns {x0}:{x1} (the window diagnosed): pass --region Y0:Y1,X0:X1 "
                    "for a window with cells, or --region full"
                )
            if is_dense_colony(frame_masks, microscope.modality):
                raise ValueError(
                    f"--masks {Path(args.masks).name} hold a dense colony of touching cells "
                    f"in the window diagnosed: {DIAGNOSE_COLONY_NOTE}"
                )
            check_modality(frame, microscope.modality, labels=labels, masks=frame_masks)
        refuse_lying_trench(args, stack.shape, microscope.modality)
        named = args.geometry or default_geometry(stack.shape, microscope.modality)
        geometry = "open" if named == "field" else named  # `fit`'s rule and words
        if microscope.modality == "phase" and geometry == "open" and stack[0].size > 2 * 96**2:
            print(  # found as a user: a colony's default window ran past 10 min, unannounced
                f"note: a phase-contrast field of {stack[0].size:,} pixels takes tens of "
                "minutes to diagnose on a few cores (a dense colony's 256 x 256 px window: "
                "over 25 min; 96 x 96 px: under a minute; docs/diagnosis.md); --region "
                "Y0:Y1,X0:X1 picks a smaller window",
                file=sys.stderr,
            )
        elif stack.size > 256**2:  # found as a user: 4 frames of 512 x 512 px, 9 min for
            # 2 of 11 checks, nothing said
            print(
                f"note: diagnosing {stack.size:,} pixels ({len(stack)} x {stack.shape[1]} x "
                f"{stack.shape[2]}) takes long: its time grows faster than its pixels (a "
                "256 x 256 px fluorescence window: about 3 min on 2 cores; the whole 512 x "
                "512 px field: over 12 min; docs/diagnosis.md); --region Y0:Y1,X0:X1 picks a "
                "smaller window",
                file=sys.stderr,
            )
        file_notes = [*config.notes_for(modality), *[NO_CAMERA_NOTE] * (config.camera is None)]
        for note in file_notes:  # once the inputs are taken (found as a user: "no camera
            # given" said before refusals that had nothing to do with the camera)
            print(f"note: {note}", file=sys.stderr)
    start = RenderSettings()
    if microscope.modality == "fluorescence":
        start = RenderSettings(cell_intensity=2000.0, media_intensity=200.0, device_intensity=200.0)
    # named as the diagnose command's (piped, it said "napari-symbac fit: 1 of 1 frames")
    update, bar = _tqdm_progress("diagnose", unit="frames fitted")
    scenes = []
    n_cells: list[int] = []
    problems: list[str] = [slip] if slip else []
    # the microscope file's camera, divided as an image beyond 16 bits was
    camera = None if config.camera is None else in_read_units(config.camera, mapping)
    noise_ratio = 1.0  # of a measured camera: its noise's lag-2 / lag-1 variance ratio
    first_fit = None
    with timer.step("base fit"):
        render = start
        for k, frame in enumerate(stack):
            # Without a camera in the file the first frame's fit measures it (gain and
            # read noise from the image, as `napari-symbac fit` does); the other frames
            # and the diagnosis use that camera.
            try:
                fit = fit_scene(
                    frame, microscope, render, camera, labels=labels, geometry=geometry,
                    masks=None if masks is None else masks[k],
                )
            except WideStartError as err:
                raise ValueError(f"{err.cause}; {DIAGNOSE_WIDE_START_FIX}") from err
            except ValueError as err:
                if "no cells" not in str(err):
                    raise
                advice = _no_cells_advice(err, numbers[k], len(stack), region, frame_shape)
                raise ValueError(advice) from err
            if first_fit is None:  # the settings' simulation is fitted to frame 0
                first_fit = fit
            if camera is None:
                camera = fit.camera
                measured_note, ratio = measured_camera_note(frame, camera)
                if ratio is not None:  # else said in the note
                    noise_ratio = ratio
                if mapping is not None:  # its ADU and e- are the map's, not a camera's
                    measured_note += counts_units_mark(mapping)
                print(f"note: {measured_note}", file=sys.stderr)
            scenes.append(fit.scene)
            n_cells.append(len(fit.cells))
            of = f"frame {numbers[k]}: " if len(stack) > 1 else ""
            problems += [
                of + p for p in base_fit_problems(fit, microscope, "see residuals.png")
            ]
            render = fit.render
            update(k + 1, len(stack))
    bar.close()
    # the total is the most checks still possible, and shrinks (found as a user: the
    # lines read "1 of 12 held-out checks", then "6 of 6")
    update, bar = _tqdm_progress("diagnose", unit="held-out checks", bound=True)
    with timer.step("diagnose"):
        design = build_design(scenes, microscope, render, camera)
        result = diagnose(
            stack,
            design,
            max_steps=args.max_effects,
            rng=np.random.default_rng(args.seed),
            progress=update,
        )
    bar.close()
    remove_earlier_run(earlier)
    out.mkdir(parents=True, exist_ok=True)
    with timer.step("write"):
        doc = result.as_dict()
        doc["notes"] = [*file_notes, pixel_note]
        if config.camera is None:
            doc["notes"].append(measured_note)
        doc["camera"] = dataclasses.asdict(camera)
        doc["counts_mapping"] = counts_record(mapping)
        doc["region"] = {"rows": [y0, y1], "columns": [x0, x1]}
        doc["frames"] = numbers  # of the recording, diagnosed together
        doc["start"] = {  # what the base fit started from, and the cells it ended with
            "from": "instance masks" if masks is not None else
            "painted labels" if labels is not None else "automatic segmentation",
            "cells_per_frame": n_cells,
        }  # fmt: skip
        doc["base_fit_problems"] = problems
        layout = simulated_shape(region, frame_shape, first_fit.trench is not None)
        # the simulation `fit` would write, so that an export matches the recording
        simulation, invalid = fitted_or_kept(
            config.timed(SimulationSettings(), recording.frame_interval_s),
            first_fit,
            layout,
            microscope.pixel_size_um,
        )
        if invalid:
            doc["notes"].append(f"settings.yaml simulates the defaults: {invalid}")
        # the intensities refitted with the accepted effects (the optics stay the fit's)
        final_render, held = refitted_render(
            render, result.final_model, config.microscope.modality
        )
        if held:
            doc["notes"].append(held)
            print(f"note: {held}", file=sys.stderr)
        base = PipelineSettings(simulation, microscope, final_render, camera)
        settings, extra = updated_settings(base, result.accepted)
        clipped = fitted_clip(stack[0], first_fit.scene, camera, microscope.modality)
        if clipped is not None:  # the recording's clipped background, as fit draws it
            settings, sentence = drawn_clipped(settings, clipped, noise=config.camera is None)
            doc["notes"].append(f"settings.yaml: {sentence}")
        (out / "diagnosis.json").write_text(json.dumps(doc, indent=2, default=float))
        start = doc["start"]["from"] + (f" ({Path(args.masks).name})" if masks is not None else "")
        context = [
            f"recording: {Path(args.image).name}, rows {y0}:{y1}, columns {x0}:{x1} of the "
            f"{frame_shape[0]} x {frame_shape[1]} px frame"
            + (f", frames {number_runs(numbers)} of {recorded}" if recorded > 1 else ""),
            f"{pixel_note}; modality: {microscope.modality}",
            f"camera: {camera_text(camera)}"
            + (" (measured from the recording)" if config.camera is None else ""),
            f"base fit: started from {start}; cells fitted per frame: "
            f"{', '.join(map(str, n_cells))}",
        ]
        (out / "report.txt").write_text(
            _diagnose_report(result.report(), mapping, out, context, problems)
        )
        figures = write_figures(result, stack, out, name=Path(args.image).name)
        save_settings(settings, out / "settings.yaml")
        stages_text = yaml.safe_dump({"extra_stages": extra}, sort_keys=False)
        (out / "extra_stages.yaml").write_text(stages_text)
    for problem in problems[1 if slip else 0 :]:  # as fit says them (found as a user: 0.8
        # um for 0.08 um, cells 2.5 um wide drawn at 0 ADU, exit 0 without a word); the
        # camera pixel's slip was said before the fit
        print(f"napari-symbac diagnose: warning: base fit: {problem}", file=sys.stderr)
    for caution in result.cautions():  # said where it is seen, not only in report.txt
        if caution.startswith("the base fit") and microscope.modality == "phase" and (
            geometry == "open" and labels is None and masks is None
        ):
            caution += f"; {DIAGNOSE_COLONY_NOTE}"
        if caution.startswith("the base fit") and noise_ratio > CORRELATED_NOISE_RATIO:
            # found as a user: DeLTA's resampled trench, 7 cells for 7 seen, was told
            # of cells missed while the camera note said its noise was correlated
            caution += (
                "; here the noise is correlated between neighbours (lag ratio "
                f"{noise_ratio:.3g}: a resampled or filtered image, not raw camera counts), "
                "which alone raises the chi-square far above 1: if the fitted cells are "
                "the cells seen (residuals.png), that, not the scene, is the likely cause"
            )
        print(f"napari-symbac diagnose: warning: {caution}", file=sys.stderr)
    accepted_names = [e.name for e in result.accepted]
    names = ", ".join(accepted_names) or "nothing significant"
    print(
        f"accepted: {names}; held-out deviance {result.base_fit['held_out']:.4f} -> "
        f"{result.final_fit['held_out']:.4f}; wrote diagnosis.json, report.txt, "
        f"{', '.join(figures)}, settings.yaml, extra_stages.yaml to {out}"
    )
    if accepted_names:
        print(f"with settings.yaml, {drawn_by_export(accepted_names)}")
    if layout != tuple(frame_shape):  # found as a user: a 256 x 256 export of a 512 x 512
        print(  # field, said nowhere
            f"settings.yaml simulates the diagnosed {y1 - y0} x {x1 - x0} px window, not the "
            f"{frame_shape[0]} x {frame_shape[1]} frame (--region full diagnoses the whole "
            "frame)"
        )
    print(timer.report())
    return 0


def _cmd_demo(args: argparse.Namespace) -> int:
    from napari_symbac.demo import run_demo

    _output_folder(args.out)
    _confirm_large_run(2 * args.frames, f"a demo of {args.frames:,} frames", args.yes)
    report = run_demo(
        args.out, n_frames=args.frames, seed=args.seed, progress_factory=_tqdm_progress
    )
    print(report)
    return 0


def _cmd_bench(args: argparse.Namespace) -> int:
    from napari_symbac.bench import BenchConfig, run_rows
    from napari_symbac.bench.report import markdown, write_outputs
    from napari_symbac.bench.run import log_to_stderr
    from napari_symbac.bench.subprocesses import check_symbac_python

    if args.repeats is not None and args.repeats < 1:
        raise ValueError(f"--repeats must be at least 1, got {args.repeats}")
    python = None if args.symbac_python is None else check_symbac_python(args.symbac_python)
    out = None if args.out is None else _output_folder(args.out)
    config = BenchConfig.make(args.quick, python, args.repeats)
    result = run_rows(config, log=log_to_stderr)
    if out is not None:
        from napari_symbac.bench.scaling import measure_scaling, plot_scaling

        log_to_stderr("scaling (frames, cells, image size, PSF radius)")
        result.scaling = measure_scaling(config, result.rounds)
        written = write_outputs(result, out)
        plot = plot_scaling(result.scaling, out / "scaling.png")
        if plot is None:
            log_to_stderr("no scaling.png: matplotlib is not installed (pip install matplotlib)")
        else:
            written.append(plot)
    print(markdown(result))
    if out is not None:
        print(f"\nwrote {', '.join(p.name for p in written)} to {out}")
    return 0


#: What diagnose asks of an automatic start wider than any rod
#: (:class:`~napari_symbac.fit.start.WideStartError`).
DIAGNOSE_WIDE_START_FIX = (
    "pass the cells' instance masks as --masks M, or --region Y0:Y1,X0:X1 for a window of "
    "separate cells"
)


#: What diagnose asks when its automatic start found no bright cell
#: (:class:`~napari_symbac.fit.start.FaintStartError`).
DIAGNOSE_FAINT_START_FIX = (
    "pass the cells' instance masks as --masks M, or paint rough cell and background "
    "strokes and pass them as --labels L"
)


def _no_cells_advice(
    err: Exception,
    k: int,
    n_frames: int,
    region: tuple[int, int, int, int],
    frame_shape: tuple[int, ...],
) -> str:
    """The base fit's "no cells" of diagnose, with where and what to do. Found as a
    user: `diagnose` of ColiCoords ds3 (4 frames of 512 x 512 px, cells off centre) said
    only "the start found no cells in the image": its frame 1 held none in the centre
    256 x 256 px window that is diagnosed by default, which the message did not say."""
    from napari_symbac.diagnose.region import SMALL_WINDOW_PX
    from napari_symbac.fit.start import FaintStartError

    y0, y1, x0, x1 = region
    window = region != (0, frame_shape[0], 0, frame_shape[1])
    where = f"frame {k}" if n_frames > 1 else "the image"
    if window:
        where += f", rows {y0}:{y1}, columns {x0}:{x1}"
    every = " in every frame" if n_frames > 1 else ""
    faint = isinstance(err, FaintStartError)  # its fix is worded here
    if window:
        fix = f"pass --region Y0:Y1,X0:X1 for a window with cells{every}, or --region full"
        if min(y1 - y0, x1 - x0) < SMALL_WINDOW_PX:  # found as a user: a 40 x 40 px
            # window around one cell was "no cells", a 64 x 64 one worked
            fix = (
                f"the {y1 - y0} x {x1 - x0} px window may be too small for the start to "
                f"tell the cells from the background (give one of at least {SMALL_WINDOW_PX}"
                f" x {SMALL_WINDOW_PX} px around them); or {fix}"
            )
    else:
        fix = DIAGNOSE_FAINT_START_FIX if faint else "give an image with cells in it"
    if n_frames > 1:
        fix += ", or --frames with the frames that hold cells"
    return f"{where}: {err.cause if faint else err}: {fix}"


def _cmd_defaults(args: argparse.Namespace) -> int:
    import yaml

    from napari_symbac import settings as settings_module

    if args.kind == "export":
        from napari_symbac.export import export_of

        # the default export of the default pipeline: its trench's images drawn from the
        # frames after it has filled (found as a user: `defaults export` wrote
        # first_frame: 0, and the export of that file drew frame 1, one cell in an
        # empty trench, for the first of its images)
        default = export_of(settings_module.PipelineSettings())
    else:
        classes = {
            "pipeline": settings_module.PipelineSettings,
            "simulation": settings_module.SimulationSettings,
            "microscope": settings_module.Microscope,
            "render": settings_module.RenderSettings,
            "camera": settings_module.Camera,
        }
        default = classes[args.kind]()
    if args.out:
        if Path(args.out).is_dir():  # found as a user: "exists and is not the default
            # settings (your edits?) ... add --force", and --force then "Is a directory"
            raise ValueError(
                f"--out {args.out} is a folder: give a file name (e.g. {args.kind}.yaml)"
            )
        if not args.force and not _holds(args.out, settings_module.to_dict(default)):
            raise ValueError(
                f"{args.out} exists and is not the default {args.kind} settings (your "
                "edits?): it is left as it is; give another file name, or add --force to "
                "replace it"
            )
        settings_module.save_settings(default, args.out)
        print(f"wrote default {args.kind} settings to {args.out}")
    else:
        print(yaml.safe_dump(settings_module.to_dict(default), sort_keys=False), end="")
    return 0


def _holds(path: str, data: dict) -> bool:
    """Whether ``path`` is missing or already holds the settings ``data`` (so that writing
    them there loses nothing; found as a user: re-running the README's `defaults
    microscope --out microscope.yaml` replaced the pixel size entered in it)."""
    import json

    from napari_symbac.settings import read_settings_mapping

    if not Path(path).exists():
        return True
    try:
        held = read_settings_mapping(path)
    except (ValueError, OSError):
        return False
    # the defaults' tuples as the file's lists (found as a user: a second `defaults
    # export --out export.yaml` called the untouched file "your edits")
    return held == json.loads(json.dumps(data))


# --------------------------------------------------------------------------------------
# Parser
# --------------------------------------------------------------------------------------


_YES_HELP = (
    f"start a run of more than {LARGE_RUN_FRAMES:,} frames without refusing (hours of work)"
)

#: The ``--channel`` of the commands that read a recording.
CHANNEL_HELP = (
    "the channel to read of a TIFF of several (an ImageJ hyperstack or OME-TIFF with a "
    "channel axis), counted from 0"
)
MICROSCOPE_HELP = (
    "microscope YAML/JSON: modality, pixel_size_um, numerical_aperture, refractive_index, "
    "wavelength_um, condenser, and optionally a camera section (baseline_adu, "
    "sensitivity_adu_per_e, dark_noise_e; without it the camera is measured from the "
    "image); write one to edit with `napari-symbac defaults microscope --out M.yaml` "
    "(without it: the default optics, a note says which, and the pixel size from the "
    "image or --pixel-size-um)"
)


PIXEL_SIZE_HELP = (
    "the recording's pixel size in um in the sample (the camera pixel divided by the "
    "magnification): wins over the image file's metadata and the microscope file's "
    "pixel_size_um, and settles them when they disagree"
)


class _HelpFormatter(argparse.HelpFormatter):
    """argparse's help, with an ``examples:`` epilog kept line by line (argparse would
    run its commands together into one paragraph)."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        if text.startswith("examples:"):
            return "\n".join(indent + line for line in text.splitlines())
        return super()._fill_text(text, width, indent)


def _examples(*lines: str) -> str:
    """An ``examples:`` epilog of commands (and ``# comments``), one a line."""
    return "examples:\n" + "\n".join(f"  {line}" for line in lines)


#: Each command's examples, as a new user would type them.
_EXAMPLES = {
    "demo": _examples("napari-symbac demo --out symbac-demo"),
    "simulate": _examples(
        "napari-symbac defaults simulation --out sim.yaml   # edit, then:",
        "napari-symbac simulate --config sim.yaml --out sim/",
        "napari-symbac simulate --config fitted/settings.yaml --out sim/ --frames 100",
    ),
    "render": _examples("napari-symbac render sim/ --config fitted/settings.yaml --out images/"),
    "export": _examples(
        "napari-symbac export --config fitted/settings.yaml --out matched/ --n-items 500",
        "napari-symbac defaults export --out export.yaml   # edit formats, sizes, then:",
        "napari-symbac export --config export.yaml --out dataset/ --workers 2",
    ),
    "fit": _examples(
        "napari-symbac defaults microscope --out microscope.yaml   # set pixel_size_um, ...",
        "napari-symbac fit trench.tif --microscope microscope.yaml --out fitted/",
        "napari-symbac fit field.tif --microscope microscope.yaml --modality fluorescence "
        "--masks masks.tif --out fitted/",
        "napari-symbac fit movie.tif --microscope microscope.yaml --frames 0-9 --out fitted/",
        "# then a training dataset that matches the recording:",
        "napari-symbac export --config fitted/settings.yaml --out dataset/",
    ),
    "calibrate": _examples(
        "napari-symbac calibrate field.tif --microscope microscope.yaml --out matched/ "
        "--n-items 500 --formats tiff,omnipose",
        "napari-symbac calibrate colony.png --microscope microscope.yaml --masks "
        "colony_masks.tif --cell-width-um 1.0 --out matched/   # pixel size unknown",
        "napari-symbac calibrate movie.tif --frame 3 --masks movie_masks.tif --microscope "
        "microscope.yaml --out matched/",
    ),
    "diagnose": _examples(
        "napari-symbac diagnose trench.tif --microscope microscope.yaml --out diagnosis/",
        "napari-symbac diagnose field.tif --microscope microscope.yaml --region full "
        "--out diagnosis/",
        "# then a dataset drawn with the effects it accepted:",
        "napari-symbac export --config diagnosis/settings.yaml --out dataset/",
    ),
    "bench": _examples(
        "napari-symbac bench --quick",
        "# once: an environment with SyMBac 0.5.2 (in a source checkout: bash "
        "tools/make-symbac-env.sh)",
        "python -m venv symbac-venv && symbac-venv/bin/pip install SyMBac==0.5.2 "
        "opencv-python-headless",
        "napari-symbac bench --symbac-python symbac-venv/bin/python --out bench/",
    ),
    "defaults": _examples(
        "napari-symbac defaults microscope --out microscope.yaml",
        "napari-symbac defaults pipeline   # print every setting",
    ),
}


def _add_stain_options(parser: argparse.ArgumentParser, drawn_by: str, config: bool) -> None:
    """``--envelope-stain`` and ``--depth-layers`` of ``fit`` and ``calibrate``: where a
    fluorescence stain sits in the cells, fitted, and drawn by ``drawn_by`` (``config``:
    the command's ``--config`` may give the starts)."""
    unless = " unless --config gives one" if config else ""
    parser.add_argument(
        "--envelope-stain",
        action="store_true",
        help="fluorescence: fit, with the cells and optics, the fraction of the stain in the "
        "cell envelope (a membrane dye: cells brighter at the rim than on the centre line; "
        f"starts at 0.5{unless}); {drawn_by} draws it "
        "(render.envelope_stain_fraction)",
    )
    parser.add_argument(
        "--depth-layers",
        type=int,
        default=0,
        metavar="N",
        help="fluorescence: image the cells' stain in N slabs through the depth, each "
        "through the PSF defocused by its distance from the focal plane (eq. 16; 5 is "
        "enough), and fit the focal plane's distance from the cells' mid-plane (starts at "
        f"0.2 um{unless}); 0 (default): the 2-D projection through one PSF",
    )


def _add_command(sub, name: str, **kwargs) -> argparse.ArgumentParser:
    """The subcommand ``name``, its help ending with its examples."""
    return sub.add_parser(name, epilog=_EXAMPLES[name], formatter_class=_HelpFormatter, **kwargs)


class _Parser(argparse.ArgumentParser):
    """argparse's parser, whose usage errors are one line (argparse prints the whole usage
    block first: nine lines for calibrate, the error last)."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")

    def parse_args(self, args=None, namespace=None):
        """Options no command takes are refused by the command given, with its help and
        the nearest spelling (argparse refused them at the top level: "napari-symbac:
        error: unrecognized arguments: --frames 3 (see napari-symbac --help)")."""
        parsed, extras = self.parse_known_args(args, namespace)
        if extras:
            command = self._commands().get(getattr(parsed, "command", None), self)
            message = f"unrecognized arguments: {' '.join(extras)}"
            options = [o for action in command._actions for o in action.option_strings]
            guesses = [
                difflib.get_close_matches(extra.split("=")[0], options, n=1, cutoff=0.8)
                for extra in extras
                if extra.startswith("--")
            ]
            if any(guesses):
                message += "; did you mean " + ", ".join(g[0] for g in guesses if g) + "?"
            command.error(message)
        return parsed

    def _commands(self) -> dict[str, argparse.ArgumentParser]:
        for action in self._actions:
            if isinstance(action, argparse._SubParsersAction):
                return dict(action.choices)
        return {}


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="napari-symbac",
        description="Synthetic micrographs of bacteria with perfect ground truth (SyMBac method).",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    demo = _add_command(
        sub,
        "demo",
        help="simulate, render and export a small mother-machine dataset (no input needed)",
        description="Run the main job on the built-in defaults: simulate a mother-machine "
        "trench, render phase-contrast frames with masks, write a small training dataset "
        "and a preview montage, and print what was written and how long each step took.",
    )
    demo.add_argument("--out", default="symbac-demo", help="output folder (default: %(default)s)")
    demo.add_argument(
        "--frames", type=_at_least_one, default=40, help="frames to simulate (default: 40)"
    )
    demo.add_argument("--seed", type=_seed, default=0, help="random seed (default: 0)")
    demo.add_argument("--yes", action="store_true", help=_YES_HELP)
    demo.set_defaults(func=_cmd_demo)

    simulate = _add_command(
        sub,
        "simulate",
        help="run the growth simulation and save it",
        description="Simulate cell growth with pymunk physics (in a mother-machine trench, a "
        "chamber, on an agar pad or within drawn walls: the config's geometry) and save "
        "settings, per-frame cell states and lineage to a folder.",
    )
    simulate.add_argument(
        "--config",
        help="SimulationSettings YAML/JSON, or a pipeline file (its simulation section: the "
        "settings.yaml of fit or diagnose), or an export file (its pipeline's: the "
        "export_settings.yaml of calibrate); default: built-in",
    )
    simulate.add_argument("--out", help="output folder (default: save_dir of the config)")
    simulate.add_argument(
        "--frames", type=_at_least_one, help="frames to simulate (default: the config's n_frames)"
    )
    simulate.add_argument("--seed", type=_seed, help="random seed (default: the config's seed)")
    simulate.add_argument("--yes", action="store_true", help=_YES_HELP)
    simulate.set_defaults(func=_cmd_simulate)

    render = _add_command(
        sub,
        "render",
        help="render a saved simulation to images and masks",
        description="Draw and render every frame of a saved simulation; writes images.tif "
        "(uint16), labels.tif (uint32 instance masks, cell ids consistent over time) and "
        "semantic.tif (uint8, cells separated by zeros).",
    )
    render.add_argument("simulation", help="folder written by 'napari-symbac simulate'")
    render.add_argument("--config", help="PipelineSettings YAML/JSON for optics and camera")
    render.add_argument("--out", required=True, help="output folder")
    _add_backend_options(render)
    render.set_defaults(func=_cmd_render)

    export = _add_command(
        sub,
        "export",
        help="generate a training dataset (DeLTA, Cellpose, StarDist, COCO, CTC, ...)",
        description="Generate a randomised training dataset in parallel with dask; re-running "
        "the same command resumes an interrupted export.",
    )
    export.add_argument(
        "--config",
        required=True,
        help="ExportSettings YAML/JSON (`defaults export`, calibrate's "
        "export_settings.yaml), or a pipeline file such as the settings.yaml that fit and "
        "diagnose write (its default export)",
    )
    export.add_argument("--out", required=True, help="output folder")
    export.add_argument(
        "--n-items",
        type=_at_least_one,
        help="images (or time series) to export, instead of the config's n_items",
    )
    export.add_argument(
        "--n-frames",
        type=_at_least_one,
        help="frames each simulation runs, instead of the config's simulation.n_frames (a "
        "time series holds them all; a field fit's settings.yaml holds 1)",
    )
    export.add_argument(
        "--formats",
        help="comma-separated formats, instead of the config's: tiff, png, delta, omnipose, "
        "stardist, coco, ome-zarr; ctc and trackmate for --kind timeseries",
    )
    export.add_argument(
        "--kind",
        choices=("frames", "timeseries"),
        help="independent frames, or whole simulated time series with their tracks, "
        "instead of the config's kind (a pipeline file such as fit's settings.yaml: frames)",
    )
    export.add_argument(
        "--workers",
        type=_at_least_one,
        help="local worker processes, at most one per core (default: one per core)",
    )
    export.add_argument(
        "--scheduler",
        help="address of an existing dask scheduler (tcp://HOST:PORT); its workers must see "
        "--out at the same path",
    )
    export.add_argument("--yes", action="store_true", help=_YES_HELP)
    _add_backend_options(export)
    export.set_defaults(func=_cmd_export)

    fit = _add_command(
        sub,
        "fit",
        help="fit cells, trench and optics to a real image (analysis by synthesis)",
        description="Fit every cell, the trench (or an open field) and the optics so the "
        "rendered image overlays a real one. Writes settings.yaml (PipelineSettings, reusable "
        "by render/export), cells.json (each cell with standard errors when the fit gives "
        "them), residual.tif, before_after.png and report.txt (what did not converge or "
        "sits at a bound). Refuses inputs it cannot fit, saying what to pass instead.",
    )
    fit.add_argument(
        "image",
        help="real image (TIFF or PNG; a colour PNG of equal channels is read as grey): one "
        "frame or a (T, Y, X) series",
    )
    fit.add_argument("--microscope", help=MICROSCOPE_HELP)
    fit.add_argument("--pixel-size-um", type=float, help=PIXEL_SIZE_HELP)
    fit.add_argument("--out", required=True, help="output folder")
    start = fit.add_mutually_exclusive_group()
    start.add_argument("--labels", help="painted class labels TIFF (1 cell, 2 media, 3 device)")
    start.add_argument("--masks", help="instance masks TIFF (0 background, 1..N cells)")
    fit.add_argument(
        "--modality",
        choices=["phase", "fluorescence", "brightfield"],
        help="default: the TIFF's OME metadata, else the microscope file",
    )
    fit.add_argument(
        "--geometry",
        type=_geometry_word,
        choices=["trench", "field"],
        help="mother-machine trench or open field ('open' is the same as 'field'; default: "
        "field for fluorescence, for an "
        "image wider than 100 px or less than twice as tall as wide, or when the config's "
        "simulation geometry is agar_pad; else trench)",
    )
    fit.add_argument(
        "--frames",
        help="frames of a series to fit, e.g. 0, 0,2,5 or 0-3 (several: fitted jointly, "
        "optics shared, cells linked into tracks; consecutive frames track best); "
        "required for a series, not for a single image",
    )
    fit.add_argument("--channel", type=_whole_number(0), help=CHANNEL_HELP)
    fit.add_argument(
        "--config", help="PipelineSettings YAML/JSON: starting render, camera, trench closed end"
    )
    camera = fit.add_mutually_exclusive_group()
    camera.add_argument("--camera", help="Camera YAML/JSON (gain, baseline, read noise)")
    camera.add_argument(
        "--dark", help="dark frames TIFF: baseline and read noise from them, gain from the image"
    )
    fit.add_argument(
        "--max-iterations",
        type=int,
        help="Levenberg-Marquardt iterations per round of the fit (default: 25; fewer "
        "end the rounds sooner, but the moves that add, remove, split and merge cells "
        "take most of a field's time: 2 against 25 saved 13 %% on a ColiCoords field)",
    )
    fit.add_argument(
        "--cell-brightness",
        choices=["shared", "per-cell"],
        help="one cell intensity for all cells, or one per cell (default: per-cell in "
        "fluorescence, shared in phase contrast)",
    )
    fit.add_argument(
        "--keep-cells",
        action="store_true",
        help="fit the cells the start gives (your --masks' cells, as annotated) and no "
        "others: no cell added, removed, split or merged (default: the fit's moves do so "
        "where the residual and the BIC ask for it)",
    )
    fit.add_argument(
        "--width-sd-um",
        type=float,
        default=0.0,
        help="0 (default): one width shared by all cells; > 0: a width per cell, tied to "
        "the shared one by a Gaussian prior of this s.d. (um)",
    )
    fit.add_argument(
        "--illumination-order",
        type=int,
        default=0,
        help="0 (default): flat illumination; 1-6: the image times a smooth surface of this "
        "degree, fitted with the scene (vignetting; on a trench it also takes up the PDMS "
        "level beyond the kernel's reach, docs/fitting.md); single frames only",
    )
    _add_stain_options(fit, "settings.yaml", config=True)
    fit.set_defaults(func=_cmd_fit)

    cal = _add_command(
        sub,
        "calibrate",
        help="fit a real image and export a training dataset matched to it",
        description="Fit a real recording (the scene fit, or the masks' scene with the "
        "partially coherent phase model for dense colonies), turn the fit into matched "
        "settings (pixel size, cell sizes, intensities, brightness variation, camera, "
        "colony layout) and export a training dataset with them. Writes dataset/, "
        "report.txt (real against synthetic: class medians, noise, power spectrum), "
        "report.png (real | synthetic), export_settings.yaml and masks.tif.",
    )
    cal.add_argument(
        "image",
        help="real image (TIFF or PNG; a colour PNG of equal channels is read as grey): one "
        "2D frame, or a (T, Y, X) series with --frame",
    )
    cal.add_argument(
        "--frame", type=int, help="the frame of a (T, Y, X) series to calibrate on (and of "
        "its masks or labels when they are a series too); required for a series"
    )
    cal.add_argument("--channel", type=_whole_number(0), help=CHANNEL_HELP)
    cal.add_argument("--microscope", help=MICROSCOPE_HELP)
    cal.add_argument("--out", required=True, help="output folder (new or empty)")
    cal_start = cal.add_mutually_exclusive_group()
    cal_start.add_argument("--masks", help="instance masks TIFF (0 background, 1..N cells)")
    cal_start.add_argument(
        "--labels", help="painted class labels TIFF (1 cell, 2 media, 3 device)"
    )
    cal.add_argument(
        "--modality",
        choices=["phase", "fluorescence", "brightfield"],
        help="the recording's contrast (default: the image file's, else the microscope file's)",
    )
    cal.add_argument("--camera", help="Camera YAML/JSON (default: measured from the image)")
    cal_scale = cal.add_mutually_exclusive_group()
    cal_scale.add_argument("--pixel-size-um", type=float, help=PIXEL_SIZE_HELP)
    cal_scale.add_argument(
        "--cell-width-um",
        type=float,
        help="known cell width: the pixel size becomes it over the masks' median width "
        "(for recordings whose pixel size is not known)",
    )
    cal.add_argument("--n-items", type=_at_least_one, default=100, help="images (default 100)")
    cal.add_argument("--yes", action="store_true", help=_YES_HELP)
    cal.add_argument(
        "--formats",
        default="tiff",
        help="comma-separated frame formats: tiff, png, delta, omnipose, stardist, coco, "
        "ome-zarr (default tiff)",
    )
    cal.add_argument("--seed", type=_seed, default=0, help="dataset seed (default 0)")
    _add_stain_options(cal, "the dataset", config=False)
    cal.set_defaults(func=_cmd_calibrate)

    diag = _add_command(
        sub,
        "diagnose",
        help="find where the fitted model and a recording differ, name and fit the missing physics",
        description="Fit the scene, test the catalogue of missing effects, keep those that "
        "improve held-out pixels; write diagnosis.json, report.txt, figures and settings.",
    )
    diag.add_argument("image", help="recording (TIFF or PNG), one frame or a (T, Y, X) series")
    diag.add_argument(
        "--frames",
        help="frames of a series to diagnose, e.g. 0, 0,2,5 or 0-3, as fit takes them "
        "(default: every frame, diagnosed as one time series)",
    )
    diag.add_argument("--channel", type=_whole_number(0), help=CHANNEL_HELP)
    diag_start = diag.add_mutually_exclusive_group()
    diag_start.add_argument(
        "--labels", help="painted class labels TIFF (1 cell, 2 media, 3 device)"
    )
    diag_start.add_argument(
        "--masks",
        help="instance masks TIFF (0 background, 1..N cells; one frame, or one per frame of a "
        "series): the base fit starts from these cells, as `fit --masks` does (cells too "
        "faint or too crowded for the automatic start)",
    )
    diag.add_argument("--microscope", help=MICROSCOPE_HELP)
    diag.add_argument("--pixel-size-um", type=float, help=PIXEL_SIZE_HELP)
    diag.add_argument(
        "--modality",
        choices=["phase", "fluorescence", "brightfield"],
        help="default: the TIFF's OME metadata, else the microscope file (as fit)",
    )
    diag.add_argument(
        "--geometry",
        type=_geometry_word,
        choices=("trench", "field"),
        help="mother-machine trench or open field ('open' is the same as 'field'; default: "
        "field for fluorescence or an image wider than 100 px or less than twice as tall as "
        "wide, else trench)",
    )
    diag.add_argument(
        "--region",
        metavar="Y0:Y1,X0:X1|full|cells|centre",
        help="the window of each frame to diagnose, in pixels (default, cells: the whole "
        "frame up to 256 x 256 pixels, else the window of that many that holds the most "
        "whole cells (of --masks, when given) in every frame; centre: the centre one)",
    )
    diag.add_argument(
        "--max-effects",
        type=_at_least_one,
        default=DIAGNOSE_MAX_EFFECTS,
        metavar="N",
        help="accept at most N effects (default: %(default)s); report.txt names the "
        "candidates left untested when a diagnosis stops there",
    )
    diag.add_argument("--seed", type=_seed, default=0, help="bootstrap seed (default: 0)")
    diag.add_argument("--out", required=True, help="output folder")
    diag.set_defaults(func=_cmd_diagnose)

    bench = _add_command(
        sub,
        "bench",
        help="run every benchmark and print one table (optionally beside SyMBac 0.5.2)",
        description="Run every benchmark of napari-symbac (simulation, render, slider, fit, "
        "export, memory) and print one table: each cost, its ratio to one plain FFT "
        "convolution of the same frame, and SyMBac 0.5.2's cost at the same settings when "
        "--symbac-python names an interpreter that has it (make one with `python -m venv "
        "DIR && DIR/bin/pip install SyMBac==0.5.2`, or tools/make-symbac-env.sh in a source "
        "checkout). Rounds interleave the two tools; the table shows the "
        "median and range. A full run takes tens of minutes; --quick about a minute.",
    )
    bench.add_argument(
        "--symbac-python", help="python of a virtual environment with SyMBac==0.5.2 installed"
    )
    bench.add_argument(
        "--quick", action="store_true", help="small sizes and one round (about a minute)"
    )
    bench.add_argument("--repeats", type=int, help="rounds (default: 3; 1 with --quick)")
    bench.add_argument(
        "--out", help="also write bench.md, bench.json and scaling.png to this folder"
    )
    bench.set_defaults(func=_cmd_bench)

    defaults = _add_command(
        sub,
        "defaults",
        help="print or write the default settings as a starting config",
        description="Print (or write with --out) the default settings of one kind as YAML, "
        "to edit and pass to --config.",
    )
    defaults.add_argument(  # found as a user: nothing said which kind goes where
        "kind",
        choices=["pipeline", "simulation", "microscope", "render", "camera", "export"],
        help="pipeline: every section, for render/fit --config (and simulate, "
        "export); simulation: simulate --config; microscope: --microscope of fit, "
        "calibrate, diagnose; camera: fit/calibrate --camera; export: export --config; "
        "render: the render: section of a pipeline file, to copy into one",
    )
    defaults.add_argument("--out", help="write to this .yaml/.json file instead of printing")
    defaults.add_argument(
        "--force",
        action="store_true",
        help="replace --out when it exists and holds other settings (edited ones)",
    )
    defaults.set_defaults(func=_cmd_defaults)
    return parser


#: What to do when a command runs out of memory.
OUT_OF_MEMORY_ADVICE = (
    "this machine cannot hold what was asked for; ask for less at once: a crop of the "
    "image, fewer frames, a smaller field or fewer workers"
)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``napari-symbac`` command."""
    from napari_symbac.export.atomic import ExportError

    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        with _terminate_as_interrupt():
            return args.func(args)
    except BrokenPipeError as err:
        if not _stdout_closed():  # another pipe than the reader of the output
            print(f"napari-symbac {args.command}: error: {_one_line(err)}", file=sys.stderr)
            return 2
        return 141  # the reader stopped reading (`| head`), as a shell's tools end: quietly
    except (ValueError, TypeError, OSError, ExportError) as err:
        from napari_symbac.fit.start import FaintStartError, WideStartError

        text = _one_line(err)
        if isinstance(err, WideStartError):  # fit and calibrate take the masks so
            text += " (--masks M)"
        elif isinstance(err, FaintStartError):  # ... and the labels
            text += " (--masks M or --labels L)"
        print(f"napari-symbac {args.command}: error: {text}", file=sys.stderr)
        return 2
    except ImportError as err:  # an optional dependency, with how to install it (found as
        # a user: a DXF outline without ezdxf ended in a traceback)
        print(f"napari-symbac {args.command}: error: {_one_line(err)}", file=sys.stderr)
        return 2
    except MemoryError as err:
        print(
            f"napari-symbac {args.command}: error: out of memory ({_one_line(err)}): "
            f"{OUT_OF_MEMORY_ADVICE}",
            file=sys.stderr,
        )
        return 2
    except KeyboardInterrupt as stop:
        # on a terminal a progress bar holds the line: the message starts a new one (found
        # as a user: "...48.13image/s]napari-symbac export: interrupted")
        start = "\n" if sys.stderr.isatty() else ""
        print(
            f"{start}napari-symbac {args.command}: {interrupted_text(args.command)}",
            file=sys.stderr,
        )
        return 143 if isinstance(stop, Terminated) else 130


def _stdout_closed() -> bool:
    """Whether standard output is a pipe whose reader has gone; if so, it is pointed at
    the null device so that Python's flush at exit does not fail again. Found as a user:
    `napari-symbac demo | head -3` ended with "error: Broken pipe: the path given; check
    that the path is right", of a demo that had finished."""
    import select

    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):  # replaced by an object without a file
        return False
    if hasattr(select, "poll"):  # a pipe whose reader has gone polls as an error
        poll = select.poll()
        poll.register(fd, select.POLLOUT)
        if not any(events & select.POLLERR for _, events in poll.poll(0)):
            return False
    os.dup2(os.open(os.devnull, os.O_WRONLY), fd)
    return True


class Terminated(KeyboardInterrupt):
    """SIGTERM received: the command unwinds as after Ctrl-C (exit status 143)."""


def _raise_terminated(signum: int, frame: object) -> None:
    raise Terminated


@contextlib.contextmanager
def _terminate_as_interrupt() -> Iterator[None]:
    """SIGTERM (``timeout``, ``kill``, a cluster's job scheduler) unwinds the command as
    Ctrl-C does, so that its staging folders are removed and a finished export is kept
    (found as a user: ``timeout 120 napari-symbac calibrate ...`` left a 49 MB
    ``.OUT.partial-*`` folder beside --out). Only the main thread handles signals."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


#: Commands that do not resume a run that stopped: they start over when run again.
_STARTS_OVER = ("simulate", "render", "fit", "calibrate", "diagnose")


def interrupted_text(command: str) -> str:
    """What ``command`` leaves when stopped with Ctrl-C, and what to do then (found as a
    user: simulate and demo said an export's words)."""
    if command in _STARTS_OVER:
        return f"interrupted: run the same {command} again (it starts over; only an export resumes)"
    if command == "demo":
        return "interrupted: run the same demo again (its dataset resumes where it stopped)"
    return "interrupted; the items finished so far are kept (an export resumes when run again)"


def _one_line(err: BaseException) -> str:
    """The error's message on one line; a bare OSError gets its path and a fix (a full
    disk says so)."""
    import errno

    from napari_symbac.export.atomic import is_short_write

    text = str(err)
    if isinstance(err, OSError) and (err.errno == errno.ENOSPC or is_short_write(err)):
        # found as a user: a full disk was "check that the path is right"
        where = f" writing {err.filename}" if err.filename else ""
        return f"the disk is full{where}: free some space or give --out on another disk"
    if isinstance(err, OSError) and err.strerror and text.startswith("[Errno"):
        where = err.filename or "the path given"
        text = (
            f"{err.strerror}: {where}; check that the path is right, that its folder "
            "exists and that you may write there"
        )
    return " ".join(text.split()) or type(err).__name__


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
