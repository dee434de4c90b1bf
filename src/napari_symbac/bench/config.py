"""Sizes and repeats of a benchmark run (full, or ``--quick`` for tests)."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["EXPORT_SIM_FRAMES", "BenchConfig"]

#: Frames of the simulation an export row renders its images from (both tools).
EXPORT_SIM_FRAMES = 60


@dataclass(frozen=True)
class BenchConfig:
    """What one ``napari-symbac bench`` run measures.

    Parameters
    ----------
    quick
        Small sizes, one repeat: about a minute (what the test runs).
    repeats
        Rounds; each round runs every benchmark and then SyMBac once (interleaved), and
        the table shows the median and range over rounds.
    symbac_python
        Interpreter of an environment with SyMBac 0.5.2 (``tools/make-symbac-env.sh``),
        or ``None`` for no SyMBac column.
    trench_frames
        Frames of the 15 um trench simulation (ours and SyMBac's).
    colony_cells
        Colony sizes at which the simulation's frame cost is read.
    render_frames
        Frames timed per render row.
    gpu_frames, gpu_field_frames
        Trench frames and 1024 x 1024 fields per ``torch:cuda`` batch.
    batch_frames
        Trench frames of the ``torch:cpu`` batch and of scipy's run beside it.
    export_images
        Images per export run.
    fit_iterations
        Iteration limit of the fits (``fit_scene``'s ``max_iterations``).
    fit_field_cells
        Cells of the 256 x 256 fluorescence field that is fitted.
    """

    quick: bool = False
    repeats: int = 3
    symbac_python: str | None = None
    trench_frames: int = 100
    colony_cells: tuple[int, int, int] = (400, 1000, 4000)
    render_frames: int = 20
    gpu_frames: int = 1000
    gpu_field_frames: int = 6
    batch_frames: int = 100
    export_images: int = 100
    fit_iterations: int = 25
    fit_field_cells: int = 16

    @classmethod
    def make(cls, quick: bool, symbac_python: str | None = None, repeats: int | None = None):
        """The full configuration, or the quick one (small sizes, one repeat)."""
        if not quick:
            return cls(symbac_python=symbac_python, repeats=repeats or 3)
        return cls(
            quick=True,
            repeats=repeats or 1,
            symbac_python=symbac_python,
            trench_frames=30,
            colony_cells=(40, 80, 160),
            render_frames=3,
            gpu_frames=20,
            gpu_field_frames=2,
            batch_frames=8,
            export_images=10,
            fit_iterations=3,
            fit_field_cells=4,
        )

    @property
    def symbac_settings(self) -> dict[str, int]:
        """Sizes of the SyMBac run (its simulation is ~100x slower than ours)."""
        return {
            "sim_frames": self.trench_frames,
            "render_frames": self.render_frames,
            "export_n": self.export_images,
            "export_sim_frames": EXPORT_SIM_FRAMES,
        }
