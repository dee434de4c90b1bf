"""The ``napari-symbac`` command: every step of the pipeline, headless.

Run ``napari-symbac --help`` or ``napari-symbac COMMAND --help``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from napari_symbac import __version__
from napari_symbac._timing import StepTimer

__all__ = ["main"]


def _tqdm_progress(
    desc: str, total: int | None = None
) -> tuple[Callable[[int, int], None], object]:
    from tqdm import tqdm

    bar = tqdm(total=total, desc=desc, unit="frame", leave=False, file=sys.stderr, disable=None)

    def update(done: int, total_now: int) -> None:
        bar.total = total_now
        bar.n = done
        bar.refresh()

    return update, bar


# --------------------------------------------------------------------------------------
# Commands
# --------------------------------------------------------------------------------------


def _load_pipeline(config: str | None):
    from napari_symbac.settings import PipelineSettings, load_settings

    return PipelineSettings() if config is None else load_settings(config, PipelineSettings)


def _cmd_simulate(args: argparse.Namespace) -> int:
    import dataclasses

    from napari_symbac.settings import SimulationSettings, load_settings
    from napari_symbac.sim import simulate

    settings = (
        SimulationSettings()
        if args.config is None
        else load_settings(args.config, SimulationSettings)
    )
    overrides = {k: v for k, v in (("n_frames", args.frames), ("seed", args.seed)) if v is not None}
    out = Path(args.out or settings.save_dir or "simulation")
    # simulate() saves to save_dir itself, atomically, once the run is complete.
    settings = dataclasses.replace(settings, **overrides, save_dir=str(out))
    timer = StepTimer()
    update, bar = _tqdm_progress("simulate", settings.n_frames)
    with timer.step("simulate and save"):
        simulation = simulate(settings, progress=update)
    bar.close()
    print(
        f"wrote simulation of {settings.n_frames} frames, {len(simulation.lineage)} cells to {out}"
    )
    print(timer.report())
    return 0


def _cmd_render(args: argparse.Namespace) -> int:
    import dataclasses

    import tifffile

    from napari_symbac.pipeline import render_simulation
    from napari_symbac.sim import load_simulation

    timer = StepTimer()
    with timer.step("load"):
        simulation = load_simulation(args.simulation)
        settings = dataclasses.replace(_load_pipeline(args.config), simulation=simulation.settings)
    update, bar = _tqdm_progress("render", len(simulation.frames))
    with timer.step("render"):
        series = render_simulation(simulation, settings, progress=update)
    bar.close()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with timer.step("write"):
        for name, array in (
            ("images", series.images),
            ("labels", series.labels),
            ("semantic", series.semantic),
        ):
            tmp = out / f".{name}.tif.partial"
            tifffile.imwrite(tmp, array, imagej=array.dtype != "uint32", compression="zlib")
            tmp.replace(out / f"{name}.tif")
    print(f"wrote images.tif, labels.tif, semantic.tif {series.images.shape} to {out}")
    print(timer.report())
    return 0


def _cmd_export(args: argparse.Namespace) -> int:
    from napari_symbac.export import export_dataset, load_export_settings

    settings = load_export_settings(args.config)
    timer = StepTimer()
    update, bar = _tqdm_progress("export", settings.n_items)
    with timer.step("export"):
        report = export_dataset(
            settings,
            args.out,
            workers=args.workers,
            scheduler=args.scheduler,
            progress=update,
        )
    bar.close()
    print(report)
    print(timer.report())
    return 0


def _cmd_fit(args: argparse.Namespace) -> int:
    import dataclasses
    import json

    import imageio.v3 as iio
    import numpy as np
    import tifffile

    from napari_symbac.fit import fit_scene
    from napari_symbac.fit.scene_fit import before_after_montage
    from napari_symbac.io import read_recording
    from napari_symbac.settings import Microscope, load_settings, save_settings

    timer = StepTimer()
    with timer.step("load"):
        image = read_recording(args.image).data
        if args.frame is not None:
            image = image[args.frame]
        labels = None if args.labels is None else tifffile.imread(args.labels)
        base = _load_pipeline(args.config)
        microscope = load_settings(args.microscope, Microscope)
    update, bar = _tqdm_progress("fit")
    with timer.step("fit"):
        result = fit_scene(
            image, microscope, base.render, base.camera, labels=labels, progress=update
        )
    bar.close()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with timer.step("write"):
        settings = dataclasses.replace(base, microscope=microscope, render=result.render)
        note = ""
        if result.trench is not None:
            try:
                trench = result.trench_geometry(image.shape[-2], microscope.pixel_size_um)
                width = float(np.median(result.cells.width_um))
                simulation = dataclasses.replace(
                    base.simulation, trench=trench, cell_width_um=width
                )
                settings = dataclasses.replace(settings, simulation=simulation)
            except ValueError as err:
                note = f" (simulation settings kept: {err})"
        save_settings(settings, out / "settings.yaml")
        table = {
            "cells": result.cells_table(),
            "trench": None if result.trench is None else dataclasses.asdict(result.trench),
            "terms": {k: list(v) for k, v in result.terms.items()},
            "coordinates": "um from the top-left corner of the image",
        }
        (out / "cells.json").write_text(json.dumps(table, indent=2, default=float))
        tifffile.imwrite(out / "residual.tif", result.residual)
        iio.imwrite(out / "before_after.png", before_after_montage(image, result))
    before, after = result.objective_before, result.objective_after
    print(
        f"fitted {len(result.cells)} cells; pixel chi2 {before:.3g} -> {after:.3g}; wrote "
        f"settings.yaml, cells.json, residual.tif, before_after.png to {out}{note}"
    )
    print(timer.report())
    return 0


def _cmd_diagnose(args: argparse.Namespace) -> int:
    import json

    import numpy as np
    import tifffile
    import yaml

    from napari_symbac.diagnose.config import load_microscope_file
    from napari_symbac.diagnose.figures import write_figures
    from napari_symbac.diagnose.model import build_design
    from napari_symbac.diagnose.run import diagnose
    from napari_symbac.diagnose.stages import updated_settings
    from napari_symbac.fit import fit_scene
    from napari_symbac.io import read_recording
    from napari_symbac.settings import PipelineSettings, RenderSettings, save_settings

    timer = StepTimer()
    with timer.step("load"):
        config = load_microscope_file(args.microscope)
        for note in config.notes:
            print(f"note: {note}", file=sys.stderr)
        image = np.asarray(read_recording(args.image).data)
        if image.ndim not in (2, 3):
            raise ValueError(
                f"{args.image} must be one frame (Y, X) or a series (T, Y, X), got {image.shape}"
            )
        stack = image[None] if image.ndim == 2 else image
        labels = None if args.labels is None else tifffile.imread(args.labels)
        if labels is not None and labels.shape != stack.shape[-2:]:
            raise ValueError(
                f"--labels has shape {labels.shape}, the image frames {stack.shape[-2:]}: "
                "paint one frame of the image's size"
            )
        geometry = args.geometry or ("trench" if stack.shape[-1] <= 100 else "open")
    start = RenderSettings()
    if config.microscope.modality == "fluorescence":
        start = RenderSettings(cell_intensity=2000.0, media_intensity=200.0, device_intensity=200.0)
    update, bar = _tqdm_progress("fit")
    scenes = []
    with timer.step("base fit"):
        render = start
        for k, frame in enumerate(stack):
            fit = fit_scene(
                frame, config.microscope, render, config.camera, labels=labels, geometry=geometry
            )
            scenes.append(fit.scene)
            render = fit.render
            update(k + 1, len(stack))
    bar.close()
    update, bar = _tqdm_progress("diagnose")
    with timer.step("diagnose"):
        design = build_design(scenes, config.microscope, render, config.camera)
        result = diagnose(stack, design, rng=np.random.default_rng(args.seed), progress=update)
    bar.close()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with timer.step("write"):
        doc = result.as_dict()
        doc["notes"] = list(config.notes)
        (out / "diagnosis.json").write_text(json.dumps(doc, indent=2, default=float))
        (out / "report.txt").write_text(result.report() + "\n")
        figures = write_figures(result, stack, out)
        base = PipelineSettings(microscope=config.microscope, render=render, camera=config.camera)
        accepted = [(e.name, e.params) for e in result.accepted]
        settings, extra = updated_settings(base, accepted)
        save_settings(settings, out / "settings.yaml")
        stages_text = yaml.safe_dump({"extra_stages": extra}, sort_keys=False)
        (out / "extra_stages.yaml").write_text(stages_text)
    names = ", ".join(e.name for e in result.accepted) or "nothing significant"
    print(
        f"accepted: {names}; held-out deviance {result.base_fit['held_out']:.4f} -> "
        f"{result.final_fit['held_out']:.4f}; wrote diagnosis.json, report.txt, "
        f"{', '.join(figures)}, settings.yaml, extra_stages.yaml to {out}"
    )
    print(timer.report())
    return 0


def _cmd_demo(args: argparse.Namespace) -> int:
    from napari_symbac.demo import run_demo

    report = run_demo(
        args.out, n_frames=args.frames, seed=args.seed, progress_factory=_tqdm_progress
    )
    print(report)
    return 0


def _cmd_defaults(args: argparse.Namespace) -> int:
    import yaml

    from napari_symbac import settings as settings_module

    if args.kind == "export":
        from napari_symbac.export import ExportSettings

        default = ExportSettings()
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
        settings_module.save_settings(default, args.out)
        print(f"wrote default {args.kind} settings to {args.out}")
    else:
        print(yaml.safe_dump(settings_module.to_dict(default), sort_keys=False), end="")
    return 0


# --------------------------------------------------------------------------------------
# Parser
# --------------------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="napari-symbac",
        description="Synthetic micrographs of bacteria with perfect ground truth (SyMBac method).",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    demo = sub.add_parser(
        "demo",
        help="simulate, render and export a small mother-machine dataset (no input needed)",
        description="Run the main job on the built-in defaults: simulate a mother-machine "
        "trench, render phase-contrast frames with masks, write a small training dataset "
        "and a preview montage, and print what was written and how long each step took.",
    )
    demo.add_argument("--out", default="symbac-demo", help="output folder (default: %(default)s)")
    demo.add_argument("--frames", type=int, default=40, help="frames to simulate (default: 40)")
    demo.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    demo.set_defaults(func=_cmd_demo)

    simulate = sub.add_parser(
        "simulate",
        help="run the growth simulation and save it",
        description="Simulate cell growth in a mother-machine trench with pymunk physics and "
        "save settings, per-frame cell states and lineage to a folder.",
    )
    simulate.add_argument("--config", help="SimulationSettings YAML/JSON (default: built-in)")
    simulate.add_argument("--out", help="output folder (default: save_dir of the config)")
    simulate.add_argument("--frames", type=int, help="override n_frames")
    simulate.add_argument("--seed", type=int, help="override the seed")
    simulate.set_defaults(func=_cmd_simulate)

    render = sub.add_parser(
        "render",
        help="render a saved simulation to images and masks",
        description="Draw and render every frame of a saved simulation; writes images.tif "
        "(uint16), labels.tif (uint32 instance masks, cell ids consistent over time) and "
        "semantic.tif (uint8, cells separated by zeros).",
    )
    render.add_argument("simulation", help="folder written by 'napari-symbac simulate'")
    render.add_argument("--config", help="PipelineSettings YAML/JSON for optics and camera")
    render.add_argument("--out", required=True, help="output folder")
    render.set_defaults(func=_cmd_render)

    export = sub.add_parser(
        "export",
        help="generate a training dataset (DeLTA, Cellpose, StarDist, COCO, CTC, ...)",
        description="Generate a randomised training dataset in parallel with dask; re-running "
        "the same command resumes an interrupted export.",
    )
    export.add_argument("--config", required=True, help="ExportSettings YAML/JSON")
    export.add_argument("--out", required=True, help="output folder")
    export.add_argument(
        "--workers", type=int, help="local worker processes (default: one per core)"
    )
    export.add_argument("--scheduler", help="address of an existing dask scheduler")
    export.set_defaults(func=_cmd_export)

    fit = sub.add_parser(
        "fit",
        help="fit cells, trench and optics to a real image (analysis by synthesis)",
        description="Segment a real phase-contrast trench (Otsu), then fit every cell, the "
        "trench and the optical parameters so the rendered image overlays it; writes the "
        "fitted PipelineSettings (settings.yaml, reusable by render/export), the fitted "
        "cells (cells.json), the residual (residual.tif) and before_after.png.",
    )
    fit.add_argument("image", help="real image (TIFF), one frame")
    fit.add_argument("--labels", help="painted class labels TIFF (1 cell, 2 media, 3 device)")
    fit.add_argument("--microscope", required=True, help="Microscope YAML/JSON")
    fit.add_argument("--config", help="PipelineSettings YAML/JSON with starting render/camera")
    fit.add_argument("--frame", type=int, help="frame of a time series to fit")
    fit.add_argument("--out", required=True, help="output folder")
    fit.set_defaults(func=_cmd_fit)

    diag = sub.add_parser(
        "diagnose",
        help="find where the fitted model and a recording differ, name and fit the missing physics",
        description="Fit the scene, test the catalogue of missing effects, keep those that "
        "improve held-out pixels; write diagnosis.json, report.txt, figures and settings.",
    )
    diag.add_argument("image", help="recording (TIFF), one frame or a (T, Y, X) series")
    diag.add_argument("--labels", help="painted class labels TIFF (1 cell, 2 media, 3 device)")
    diag.add_argument("--microscope", required=True, help="microscope JSON/YAML (issue 11 keys)")
    diag.add_argument(
        "--geometry", choices=("trench", "open"), help="default: trench if <= 100 px wide"
    )
    diag.add_argument("--seed", type=int, default=0, help="bootstrap seed (default: 0)")
    diag.add_argument("--out", required=True, help="output folder")
    diag.set_defaults(func=_cmd_diagnose)

    defaults = sub.add_parser(
        "defaults",
        help="print or write the default settings as a starting config",
        description="Print (or write with --out) the default settings of one kind as YAML, "
        "to edit and pass to --config.",
    )
    defaults.add_argument(
        "kind", choices=["pipeline", "simulation", "microscope", "render", "camera", "export"]
    )
    defaults.add_argument("--out", help="write to this .yaml/.json file instead of printing")
    defaults.set_defaults(func=_cmd_defaults)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``napari-symbac`` command."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except (ValueError, OSError) as err:
        print(f"napari-symbac {args.command}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"napari-symbac {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
