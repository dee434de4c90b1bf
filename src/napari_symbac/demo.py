"""``napari-symbac demo``: the main job on built-in defaults, headless.

Simulates a mother-machine trench, renders phase-contrast frames with masks, writes a
small training dataset and a preview montage, and reports what it wrote and how long
each step took. Needs nothing outside the package.
"""

from __future__ import annotations

import dataclasses
import shutil
from collections.abc import Callable
from pathlib import Path

from napari_symbac._timing import StepTimer
from napari_symbac.settings import PipelineSettings, save_settings, to_dict

__all__ = ["DEMO_FORMATS", "run_demo"]

#: Dataset formats the demo writes.
DEMO_FORMATS = ("tiff", "omnipose", "delta", "ctc")

ProgressFactory = Callable[[str, int], tuple[Callable[[int, int], None], object]]


def run_demo(
    out: str | Path = "symbac-demo",
    *,
    n_frames: int = 40,
    seed: int = 0,
    settings: PipelineSettings | None = None,
    progress_factory: ProgressFactory | None = None,
) -> str:
    """Simulate, render and export a small dataset into ``out``; return a report.

    Parameters
    ----------
    out
        Output folder; created if needed. Running the demo again with the same
        settings finds the dataset complete and rewrites only the preview. If the
        run fails (disk full, interrupted) and it created the folder, the folder is
        removed again.
    n_frames
        Number of frames to simulate and render.
    seed
        Seed of the run: the same seed writes bit-identical files.
    settings
        Settings to use instead of the built-in defaults.
    progress_factory
        ``factory(description, total) -> (update, handle)``; ``update(done, total)``
        is called during long steps and ``handle.close()`` at the end of each.
    """
    if n_frames < 1:
        raise ValueError(f"n_frames must be at least 1, got {n_frames}")
    base = settings or PipelineSettings()
    settings = dataclasses.replace(
        base, simulation=dataclasses.replace(base.simulation, n_frames=n_frames, seed=seed)
    )
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"the demo's output {out} is a file: give the path of a folder")
    _check_earlier_demo(out, settings)
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    from napari_symbac.export.atomic import EXPORT_RESUMES, ExportError

    try:
        return _run(out, settings, n_frames, seed, progress_factory)
    except BaseException as err:
        if not created:
            raise
        shutil.rmtree(out, ignore_errors=True)  # a failed first run (full disk, Ctrl-C)
        if isinstance(err, ExportError):  # leaves nothing behind, and says so (found as
            # a user: a full disk's message still said the export would resume)
            cause = str(err).replace(f": {EXPORT_RESUMES}", "")
            raise ExportError(
                f"{cause}: the demo's folder {out} was removed; run the demo again once "
                "that is fixed",
                err.path,
                err.errno,
            ) from err
        raise


def _check_earlier_demo(out: Path, settings: PipelineSettings) -> None:
    """Refuse a folder that holds a demo made with other settings.

    Found as a user: `demo --out symbac-demo --seed 3` after the README's seed-0 demo
    replaced the settings, simulation and preview with seed 3's and kept the seed-0
    dataset ("0 written, 40 already there"), exit 0.

    Raises
    ------
    ValueError
        Naming the settings that differ and what to do.
    """
    import json

    from napari_symbac.export.manifest import settings_differences
    from napari_symbac.settings import read_settings_mapping

    earlier = out / "settings.yaml"
    if not earlier.is_file():
        return
    try:
        held = read_settings_mapping(earlier)
    except (OSError, ValueError):
        held = None
    wanted = json.loads(json.dumps(to_dict(settings)))  # YAML's lists for the tuples
    if held != wanted:
        changed = settings_differences(held, wanted) if isinstance(held, dict) else "unreadable"
        raise ValueError(
            f"{out} holds a demo made with other settings ({changed}): give another --out, "
            "or delete that folder first"
        )


def _run(
    out: Path,
    settings: PipelineSettings,
    n_frames: int,
    seed: int,
    progress_factory: ProgressFactory | None,
) -> str:
    import imageio.v3 as iio

    from napari_symbac.export import series_items, write_items
    from napari_symbac.pipeline import montage, render_simulation
    from napari_symbac.sim import save_simulation, simulate

    timer = StepTimer()

    def timed(name: str, func, total: int | None = None):
        update, handle = (None, None)
        if progress_factory is not None and total is not None:
            update, handle = progress_factory(name, total)
        with timer.step(name):
            result = func(update) if total is not None else func()
        if handle is not None:
            handle.close()
        return result

    simulation = timed(
        "simulate", lambda update: simulate(settings.simulation, progress=update), n_frames
    )
    timed("save simulation", lambda: save_simulation(simulation, out / "simulation"))
    series = timed(
        "render", lambda update: render_simulation(simulation, settings, progress=update), n_frames
    )
    items = series_items(
        series.images,
        series.labels,
        series.semantic,
        lineage=simulation.lineage,
        pixel_size_um=settings.microscope.pixel_size_um,
        frame_interval_min=settings.simulation.frame_interval_min,
    )
    header = {"settings": to_dict(settings)}  # a resumed dataset is checked against them
    written = timed(
        "write dataset",
        lambda: write_items(items, out / "dataset", DEMO_FORMATS, header=header),
    )
    preview = out / "preview.png"
    timed(
        "preview", lambda: iio.imwrite(preview, montage(series.images, series.labels, columns=20))
    )
    save_settings(settings, out / "settings.yaml")

    n_cells = len(simulation.lineage)
    lines = [
        f"napari-symbac demo: {n_frames} frames of a {settings.simulation.trench.length_um:g} um "
        f"trench, {n_cells} cells over the run, seed {seed}",
        f"  {out / 'settings.yaml'}  settings used (reload with --config)",
        f"  {out / 'simulation'}  simulation (cell states per frame + lineage)",
        f"  {out / 'dataset'}  {len(items)} image/mask pairs as {', '.join(DEMO_FORMATS)} "
        f"({written.n_written} written, {written.n_skipped} already there)",
        f"  {preview}  preview montage with mask outlines",
        "timings:",
        timer.report(),
    ]
    return "\n".join(lines)
