"""Benchmarks that run in a child process: exports (own peak memory), the slider (Qt),
and SyMBac 0.5.2 (its own interpreter)."""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import subprocess
import sys

from napari_symbac.bench.config import BenchConfig
from napari_symbac.bench.registry import register
from napari_symbac.bench.symbac_script import SCRIPT

__all__ = [
    "BenchSkipped",
    "check_symbac_python",
    "export_1",
    "export_2",
    "export_run",
    "run_json",
    "slider",
    "symbac_run",
]


class BenchSkipped(RuntimeError):
    """A benchmark that cannot run here; the message is shown in its row."""


def run_json(command: list[str], *, timeout_s: float, env: dict[str, str] | None = None) -> dict:
    """Run ``command`` and parse the JSON object on its last line of output.

    Raises
    ------
    RuntimeError
        If the command fails or prints no JSON, with the last line of its errors.
    """
    try:
        done = subprocess.run(
            command, capture_output=True, text=True, timeout=timeout_s, env=env, check=False
        )
    except subprocess.TimeoutExpired as err:
        raise RuntimeError(f"did not finish within {timeout_s:g} s") from err
    lines = done.stdout.strip().splitlines()
    if done.returncode != 0 or not lines:
        last = (done.stderr.strip().splitlines() or ["no output"])[-1]
        raise RuntimeError(f"exit {done.returncode}: {last[:200]}")
    return json.loads(lines[-1])


def export_run(config: BenchConfig, workers: int) -> dict[str, float]:
    """An export in a fresh process; with ``workers > 1`` always on a local cluster.

    (An export left to itself stays in one process when it judges the cluster's start
    too costly: ``NAPARI_SYMBAC_CLUSTER_START_S=0`` makes it start the workers, so the
    row measures them.) Returns the numbers of
    :func:`napari_symbac.bench.export_child.run`, ``peak_worker_mib`` among them when
    the workers ran.
    """
    command = [sys.executable, "-m", "napari_symbac.bench.export_child"]
    command += ["--n", str(config.export_images), "--workers", str(workers)]
    env = {**os.environ, "NAPARI_SYMBAC_CLUSTER_START_S": "0"}
    return run_json(command, timeout_s=1800, env=env)


@register("export_1")
def export_1(config: BenchConfig) -> dict[str, float]:
    """Export of ``config.export_images`` trench images (omnipose TIFF pairs), 1 worker."""
    return export_run(config, 1)


@register("export_2")
def export_2(config: BenchConfig) -> dict[str, float]:
    """The same with a local dask cluster of 2 worker processes."""
    if (os.cpu_count() or 1) < 2:
        raise BenchSkipped("skipped: 1 core (2 workers would be capped to 1)")
    return export_run(config, 2)


@register("slider")
def slider(config: BenchConfig) -> dict[str, float]:
    """Slider -> layer latency of the Tune widget (needs the ``gui`` extra)."""
    if importlib.util.find_spec("napari") is None or importlib.util.find_spec("qtpy") is None:
        raise BenchSkipped("skipped: no napari (pip install napari-symbac[gui])")
    command = [sys.executable, "-m", "napari_symbac.bench.gui_child", "5" if config.quick else "30"]
    env = {**os.environ, "QT_QPA_PLATFORM": "offscreen"}
    if not env.get("DISPLAY") and sys.platform.startswith("linux"):
        xvfb = shutil.which("xvfb-run")
        if xvfb is None:
            raise BenchSkipped("skipped: no display (napari's canvas needs X; install xvfb)")
        command = [xvfb, "-a", *command]
    return run_json(command, timeout_s=600, env=env)


def symbac_run(config: BenchConfig, render_shape: tuple[int, int], camera_shape: tuple[int, int]):
    """SyMBac 0.5.2's numbers at the settings of the rows (see ``symbac_script``)."""
    if config.symbac_python is None:
        raise BenchSkipped("no --symbac-python")
    settings = {
        **config.symbac_settings,
        "render_shape": list(render_shape),
        "camera_shape": list(camera_shape),
    }
    command = [config.symbac_python, "-c", SCRIPT, json.dumps(settings)]
    return run_json(command, timeout_s=3600)


def check_symbac_python(python: str) -> str:
    """``python`` if it runs and imports SyMBac 0.5.2, else a ValueError saying how to fix it."""
    fix = (
        "make one with: python -m venv DIR && DIR/bin/pip install SyMBac==0.5.2 (or bash "
        "tools/make-symbac-env.sh DIR in a source checkout), then pass DIR/bin/python"
    )
    if not (os.path.isfile(python) and os.access(python, os.X_OK)):
        raise ValueError(f"--symbac-python {python}: not an executable file; {fix}")
    probe = subprocess.run(
        [python, "-c", "from importlib.metadata import version; print(version('SyMBac'))"],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    found = probe.stdout.strip()
    if probe.returncode != 0:
        raise ValueError(f"--symbac-python {python}: SyMBac is not installed there; {fix}")
    if found != "0.5.2":
        raise ValueError(
            f"--symbac-python {python}: has SyMBac {found}, the comparison is with 0.5.2; {fix}"
        )
    return python
