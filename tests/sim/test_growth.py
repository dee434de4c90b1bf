"""Growth models, division and lysis reproduce their defining statistics (section 2)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from napari_symbac.settings import SimulationSettings, TrenchGeometry
from napari_symbac.sim import Simulation, simulate, spherocylinder_volume_um3


def _division_table(sim: Simulation) -> np.ndarray:
    """Rows of (birth length, division length, interdivision time) of every cell born
    and divided within the run whose daughters were both recorded.

    The division length is recovered from the daughters by volume conservation at
    equal width: ``L_div = L1 + L2 - w / 3``.
    """
    first: dict[int, tuple[float, float]] = {}
    for frame in sim.frames:
        for cid, length, width in zip(frame.ids, frame.length_um, frame.width_um):
            first.setdefault(int(cid), (float(length), float(width)))
    children: dict[int, list[int]] = {}
    for record in sim.lineage.values():
        children.setdefault(record.parent_id, []).append(record.cell_id)
    rows = []
    dt = sim.settings.frame_interval_min
    for record in sim.lineage.values():
        kids = children.get(record.cell_id, [])
        if (
            record.fate != "divided"
            or record.parent_id == 0
            or record.cell_id not in first
            or len(kids) != 2
            or not all(k in first for k in kids)
        ):
            continue
        (l1, w1), (l2, _) = first[kids[0]], first[kids[1]]
        rows.append(
            (
                first[record.cell_id][0],
                l1 + l2 - w1 / 3,
                (record.division_frame - record.birth_frame) * dt,
            )
        )
    return np.array(rows)


def _slope(x: np.ndarray, y: np.ndarray) -> float:
    return float(np.polyfit(x, y, 1)[0])


@pytest.fixture(scope="module")
def tables() -> dict[str, np.ndarray]:
    out = {}
    for model in ("sizer", "adder", "timer"):
        settings = SimulationSettings(
            n_frames=400,
            trench=TrenchGeometry(length_um=25.0),
            growth_model=model,
            septum_sd=0.1,
            max_length_var_um2=0.09,
            seed=1,
        )
        out[model] = _division_table(simulate(settings))
    return out


def test_enough_divisions(tables):
    for model, table in tables.items():
        assert len(table) >= 100, f"{model}: only {len(table)} complete cell cycles"


def test_sizer_division_length_independent_of_birth_length(tables):
    birth, division, _ = tables["sizer"].T
    assert abs(_slope(birth, division)) < 0.2
    # ... so the added length falls one-for-one with birth length (not an adder)
    assert _slope(birth, division - birth) < -0.8
    assert division.mean() == pytest.approx(3.5, abs=0.3)


def test_adder_added_length_independent_of_birth_length(tables):
    birth, division, _ = tables["adder"].T
    added = division - birth
    assert abs(_slope(birth, added)) < 0.2
    assert _slope(birth, division) == pytest.approx(1.0, abs=0.2)
    assert added.mean() == pytest.approx(1.75, abs=0.25)


def test_timer_constant_interdivision_time(tables):
    birth, division, time_min = tables["timer"].T
    assert abs(_slope(birth, time_min)) < 1.0  # minutes per um
    assert time_min.std() / time_min.mean() < 0.12
    assert time_min.mean() == pytest.approx(25.0, abs=3.5)
    # exponential growth over a fixed time multiplies length: L_div ~ 2 L_birth
    assert _slope(birth, division) > 1.5
    # a sizer's cycle time falls steeply with birth length; a timer's does not
    sizer_birth, _, sizer_time = tables["sizer"].T
    assert _slope(sizer_birth, sizer_time) < -5.0


def test_volume_conserved_at_division():
    settings = SimulationSettings(
        n_frames=120, trench=TrenchGeometry(length_um=20.0), growth_noise=0.0, seed=3
    )
    sim = simulate(settings)
    growth = math.exp(settings.growth_rate_per_min * settings.frame_interval_min)
    where: dict[int, tuple[int, int]] = {}
    for t, frame in enumerate(sim.frames):
        for i, cid in enumerate(frame.ids):
            where.setdefault(int(cid), (t, i))
    checked = 0
    for record in sim.lineage.values():
        if record.fate != "divided":
            continue
        kids = [k for k, r in sim.lineage.items() if r.parent_id == record.cell_id]
        if not all(k in where for k in kids):
            continue
        last = sim.frames[record.end_frame]
        i = int(np.flatnonzero(last.ids == record.cell_id)[0])
        length_at_division = last.length_um[i] * growth
        firsts = [sim.frames[where[k][0]] for k in kids]
        idx = [where[k][1] for k in kids]
        width = firsts[0].width_um[idx[0]]
        mother_volume = spherocylinder_volume_um3(length_at_division, width)
        daughters_volume = sum(
            spherocylinder_volume_um3(f.length_um[j], f.width_um[j]) for f, j in zip(firsts, idx)
        )
        assert daughters_volume == pytest.approx(mother_volume, rel=1e-9)
        assert len(kids) == 2
        checked += 1
    assert checked >= 20


def test_width_varies_between_and_within_lineages():
    settings = SimulationSettings(
        n_frames=150, trench=TrenchGeometry(length_um=20.0), width_var_um2=0.004, seed=5
    )
    sim = simulate(settings)
    last = sim.frames[-1]
    assert last.width_um.std() > 0.01  # between cells
    # within a lineage: a cell's width changes over its life (relaxing to its target)
    changes = []
    for record in sim.lineage.values():
        if record.parent_id and record.fate == "divided":
            trace = sim.trace(record.cell_id)
            if trace.frames.size >= 3:
                changes.append(abs(trace.width_um[-1] - trace.width_um[0]))
    assert np.mean(changes) > 0.005
    # widths stay physical
    assert all((f.width_um > 0.5).all() and (f.width_um < 1.4).all() for f in sim.frames)


def test_length_traces_are_sawtooth():
    sim = simulate(SimulationSettings(n_frames=80, seed=2))
    mother_line = []
    record = sim.lineage[1]
    # follow the cell at the closed end through its generations
    while True:
        trace = sim.trace(record.cell_id)
        assert np.all(np.diff(trace.length_um) > 0), "a cell must grow over its life"
        mother_line.append(trace)
        kids = sorted(sim.children(record.cell_id))
        if not kids:
            break
        record = sim.lineage[kids[0]]
    assert len(mother_line) >= 3
    for before, after in itertools.pairwise(mother_line):
        assert after.length_um[0] < 0.75 * before.length_um[-1]  # the drop at division


def test_lysis_removes_cells_at_the_expected_rate():
    p = 0.03
    settings = SimulationSettings(
        n_frames=400, trench=TrenchGeometry(length_um=25.0), lysis_p=p, seed=11
    )
    sim = simulate(settings)
    at_risk = sum(len(f) for f in sim.frames[:-1])
    lysed = sum(r.fate == "lysed" for r in sim.lineage.values())
    sd = math.sqrt(at_risk * p * (1 - p))
    assert abs(lysed - at_risk * p) < 4 * sd, (lysed, at_risk * p)
    # a lysed cell is absent from the frame after its last one
    for record in sim.lineage.values():
        if record.fate == "lysed" and record.end_frame + 1 < len(sim.frames):
            assert record.cell_id not in sim.frames[record.end_frame + 1].ids
    no_lysis = simulate(SimulationSettings(n_frames=100, seed=11))
    assert not any(r.fate == "lysed" for r in no_lysis.lineage.values())


def test_curvature_drawn_once_per_cell_when_transforming():
    sim = simulate(SimulationSettings(n_frames=40, do_transformation=True, seed=4))
    curvatures = [r.curvature for r in sim.lineage.values()]
    assert all(any(c) for c in curvatures)
    assert len(set(curvatures)) == len(curvatures)
    plain = simulate(SimulationSettings(n_frames=40, seed=4))
    assert all(r.curvature == (0.0, 0.0, 0.0) for r in plain.lineage.values())
