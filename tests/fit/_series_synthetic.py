"""Series rendered from the simulator's own runs: known identities, divisions and exits."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from _fit_synthetic import PIXEL_UM, TRENCH, TRUTH

from napari_symbac.optics import ForwardModel
from napari_symbac.scene import draw_scene
from napari_symbac.settings import Camera, Microscope, SimulationSettings, TrenchGeometry
from napari_symbac.sim import FrameCells, Simulation, simulate


@dataclass(frozen=True)
class SeriesTruth:
    simulation: Simulation
    first_frame: int
    cells: list[FrameCells]  # the simulator's cells of each rendered frame (trench coordinates)
    stack: np.ndarray  # (T, 128, 46) uint16
    microscope: Microscope


def trench_simulation(seed: int = 3, n_frames: int = 40) -> Simulation:
    """A mother-machine run in the 128 x 46 px test trench: 5 min frames, ~25 min doubling."""
    return simulate(
        SimulationSettings(
            n_frames=n_frames,
            trench=TRENCH,
            frame_interval_min=5.0,
            cell_width_um=0.95,
            seed=seed,
        )
    )


def render_trench_series(
    simulation: Simulation, first: int, count: int, seed: int = 7
) -> SeriesTruth:
    """Frames ``first .. first + count - 1`` of a trench run, rendered with the fit tests'
    phase-contrast truth (:data:`~_fit_synthetic.TRUTH`) and camera noise."""
    microscope = Microscope(pixel_size_um=PIXEL_UM)
    model = ForwardModel(microscope, TRUTH, Camera())
    rng = np.random.default_rng(seed)
    cells = simulation.frames[first : first + count]
    images = [model.render(draw_scene(c, TRENCH, microscope, TRUTH), rng) for c in cells]
    return SeriesTruth(simulation, first, list(cells), np.stack(images), microscope)


def observe(
    frames: list[FrameCells],
    rng: np.random.Generator,
    offset_um: tuple[float, float] = (0.0, 0.0),
    noise_um: float = 0.03,
) -> tuple[list[FrameCells], list[np.ndarray]]:
    """The simulator's cells as a fit would report them: shuffled, renumbered 1..n,
    shifted by ``offset_um`` (image coordinates) and with the fit's scatter (``noise_um``
    on the centre, 1.6x on the length, 0.6x on the width, 1 rad/um on the angle).

    Returns the observed frames and, per frame, the simulator id of each observed cell.
    """
    observed, truth_ids = [], []
    for cells in frames:
        n = len(cells)
        order = rng.permutation(n)
        observed.append(
            FrameCells(
                ids=np.arange(1, n + 1),
                x_um=cells.x_um[order] + offset_um[0] + rng.normal(0, noise_um, n),
                y_um=cells.y_um[order] + offset_um[1] + rng.normal(0, noise_um, n),
                angle_rad=cells.angle_rad[order] + rng.normal(0, noise_um, n),
                length_um=cells.length_um[order] + rng.normal(0, 1.6 * noise_um, n),
                width_um=cells.width_um[order] + rng.normal(0, 0.6 * noise_um, n),
            )
        )
        truth_ids.append(cells.ids[order])
    return observed, truth_ids


def in_view(
    frames: list[FrameCells], origin_um: np.ndarray, size_um: tuple[float, float]
) -> list[FrameCells]:
    """The cells whose centre lies in a moving field of view (top-left ``origin_um[t]``,
    ``(height, width)``), in its coordinates: a drifting stage over a pad."""
    out = []
    for t, cells in enumerate(frames):
        x, y = cells.x_um - origin_um[t][0], cells.y_um - origin_um[t][1]
        keep = (x >= 0) & (x <= size_um[1]) & (y >= 0) & (y <= size_um[0])
        out.append(
            FrameCells(
                ids=cells.ids[keep],
                x_um=x[keep],
                y_um=y[keep],
                angle_rad=cells.angle_rad[keep],
                length_um=cells.length_um[keep],
                width_um=cells.width_um[keep],
            )
        )
    return out


def relations(track_ids, parents: dict[int, int], firsts: dict[int, int]) -> list[dict]:
    """Per pair of frames, for each cell of ``t + 1``: ``("link", i)`` (same track as cell
    ``i`` of frame ``t``), ``("division", i)`` (a daughter of cell ``i``) or ``("new", -1)``."""
    out = []
    for t in range(len(track_ids) - 1):
        before = [int(k) for k in track_ids[t]]
        rel = {}
        for j, track in enumerate(int(k) for k in track_ids[t + 1]):
            if track in before:
                rel[j] = ("link", before.index(track))
            elif parents.get(track, 0) in before and firsts.get(track) == t + 1:
                rel[j] = ("division", before.index(parents[track]))
            else:
                rel[j] = ("new", -1)
        out.append(rel)
    return out


def truth_relations(simulation: Simulation, truth_ids: list[np.ndarray], first: int = 0):
    """:func:`relations` of the simulator's own ids (frames counted from ``first``)."""
    parents = {c: r.parent_id for c, r in simulation.lineage.items()}
    firsts = {c: r.birth_frame - first for c, r in simulation.lineage.items()}
    return relations(truth_ids, parents, firsts)


def lineage_relations(lineage) -> list[dict]:
    """:func:`relations` of a :class:`~napari_symbac.fit.Lineage`."""
    parents = {int(t): int(p) for t, _b, _e, p in lineage.tracks}
    firsts = {int(t): int(b) for t, b, _e, _p in lineage.tracks}
    return relations(lineage.track_ids, parents, firsts)


@dataclass(frozen=True)
class PadTruth:
    simulation: Simulation
    first_frame: int
    origins_um: np.ndarray  # (T, 2): the field's top-left corner in each frame (x, y)
    stack: np.ndarray  # (T, 96, 96) uint16
    microscope: Microscope


def render_pad_series(
    seed: int = 1, first: int = 2, count: int = 4, colonies: int = 2, noise_seed: int = 7
) -> PadTruth:
    """A fluorescence agar pad: two founders (``colonies=2``: about 4.5 um apart, apart;
    1: touching) grown by the simulator (5 min frames, 0.9 um wide), seen through a
    96 x 96 px field of 80 nm that drifts 0.2-0.4 um per frame in a random direction,
    rendered with the fit tests' fluorescence truth and camera noise (frames ``first``
    .. ``first + count - 1``; seed 1 frames 2-5: both founders divide after frame 3)."""
    from _fit_synthetic import FLUO_TRUTH

    from napari_symbac.scene import Field
    from napari_symbac.settings import AgarPadGeometry

    pad = AgarPadGeometry(
        field_width_um=13.0, field_height_um=13.0, n_colonies=colonies,
        colony_separation_um=4.5, edge_margin_um=4.0,
    )  # fmt: skip
    simulation = simulate(
        SimulationSettings(
            n_frames=first + count, geometry="agar_pad", agar_pad=pad, n_founders=2,
            frame_interval_min=5.0, cell_width_um=0.9, seed=seed,
        )
    )  # fmt: skip
    px, shape = 0.08, (96, 96)
    microscope = Microscope(pixel_size_um=px, modality="fluorescence")
    model = ForwardModel(microscope, FLUO_TRUTH, Camera())
    rng = np.random.default_rng(noise_seed)
    start = simulation.frames[first]
    origin = np.array([start.x_um.mean(), start.y_um.mean()]) - np.array(shape[::-1]) * px / 2
    origins, images = [], []
    for t in range(count):
        if t:
            angle = rng.uniform(0, 2 * np.pi)
            origin = origin + rng.uniform(0.2, 0.4) * np.array([np.cos(angle), np.sin(angle)])
        origins.append(origin.copy())
        field = Field(shape[1] * px, shape[0] * px, origin_um=(float(origin[0]), float(origin[1])))
        cells = simulation.frames[first + t]
        scene = draw_scene(cells, TrenchGeometry(), microscope, FLUO_TRUTH, field=field)
        images.append(model.render(scene, rng))
    return PadTruth(simulation, first, np.array(origins), np.stack(images), microscope)
