"""Rigid-body physics, geometries, determinism and the step-wise API."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from napari_symbac.settings import (
    AgarPadGeometry,
    OutlineGeometry,
    SimulationSettings,
    TrenchGeometry,
    from_dict,
    to_dict,
)
from napari_symbac.sim import FrameCells, LineageRecord, Simulation, Simulator, simulate

WALL_TOLERANCE_UM = 0.06


def _extent(frame: FrameCells) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    p0, p1 = frame.poles_um()
    r = frame.width_um / 2
    return (
        np.minimum(p0[:, 0], p1[:, 0]) - r,
        np.maximum(p0[:, 0], p1[:, 0]) + r,
        np.minimum(p0[:, 1], p1[:, 1]) - r,
        np.maximum(p0[:, 1], p1[:, 1]) + r,
    )


@pytest.fixture(scope="module")
def trench_sim() -> Simulation:
    return simulate(SimulationSettings(n_frames=150, trench=TrenchGeometry(length_um=20.0)))


def test_interface_shapes_and_types(trench_sim):
    sim = trench_sim
    assert len(sim.frames) == sim.settings.n_frames == 150
    seen: set[int] = set()
    for frame in sim.frames:
        assert frame.ids.dtype == np.int64
        assert len(frame) == frame.ids.size == frame.x_um.size == frame.width_um.size
        assert len(np.unique(frame.ids)) == len(frame)
        seen.update(frame.ids.tolist())
    assert min(seen) == 1
    assert seen <= set(sim.lineage)
    for record in sim.lineage.values():
        assert isinstance(record, LineageRecord)
        assert record.fate in ("divided", "lysed", "exited", "alive")
        assert record.parent_id == 0 or record.parent_id in sim.lineage
        assert record.birth_frame <= record.end_frame + 1
    assert sum(r.parent_id == 0 for r in sim.lineage.values()) == 1
    alive = {r.cell_id for r in sim.lineage.values() if r.fate == "alive"}
    assert alive == set(sim.frames[-1].ids.tolist())
    # frames are immutable
    with pytest.raises(ValueError, match="read-only"):
        sim.frames[0].x_um[0] = 1.0


def test_cells_stay_inside_the_trench(trench_sim):
    width = trench_sim.settings.trench.width_um
    length = trench_sim.settings.trench.length_um
    for frame in trench_sim.frames:
        left, right, top, _ = _extent(frame)
        assert left.min() > -WALL_TOLERANCE_UM
        assert right.max() < width + WALL_TOLERANCE_UM
        assert top.min() > -WALL_TOLERANCE_UM
        assert frame.y_um.max() <= length  # centres past the open end are removed
    assert any(r.fate == "exited" for r in trench_sim.lineage.values())


def test_cells_fill_the_trench_and_stack_tightly(trench_sim):
    frame = trench_sim.frames[-1]
    _, _, top, bottom = _extent(frame)
    order = np.argsort(frame.y_um)
    gaps = top[order][1:] - bottom[order][:-1]
    assert len(frame) >= 6
    assert np.median(gaps) == pytest.approx(0.0, abs=0.05)
    assert gaps.min() > -0.2  # no cell passes through another


def test_gravity_packs_cells_and_double_loads_a_wide_trench():
    def side_by_side(gravity: float) -> int:
        settings = SimulationSettings(
            n_frames=120, trench=TrenchGeometry(length_um=16.0, width_um=2.0), gravity=gravity
        )
        count = 0
        for frame in simulate(settings).frames:
            dx = np.abs(frame.x_um[:, None] - frame.x_um[None])
            dy = np.abs(frame.y_um[:, None] - frame.y_um[None])
            count += int(((dx > 0.7) & (dy < 0.8)).sum() // 2)
        return count

    assert side_by_side(0.0) == 0
    assert side_by_side(0.5) > 20


def test_negative_gravity_loosens_stacking():
    def median_gap(gravity: float) -> float:
        settings = SimulationSettings(
            n_frames=100, trench=TrenchGeometry(length_um=20.0), gravity=gravity
        )
        gaps = []
        for frame in simulate(settings).frames[50:]:
            _, _, top, bottom = _extent(frame)
            order = np.argsort(frame.y_um)
            gaps.extend((top[order][1:] - bottom[order][:-1]).tolist())
        return float(np.median(gaps))

    loose, packed = median_gap(-0.3), median_gap(0.0)
    assert packed < 0.01 < 0.03 < loose
    # strong negative gravity washes every cell out of the trench (motile strains)
    washed = simulate(SimulationSettings(n_frames=100, gravity=-1.0))
    assert len(washed.frames[-1]) == 0
    assert all(r.fate != "alive" for r in washed.lineage.values())


def test_same_seed_is_bit_identical_and_other_seeds_differ():
    settings = SimulationSettings(n_frames=60, lysis_p=0.01, do_transformation=True, seed=7)
    a, b = simulate(settings), simulate(settings)
    assert a == b
    for fa, fb in zip(a.frames, b.frames):
        assert fa.x_um.tobytes() == fb.x_um.tobytes()
        assert fa.angle_rad.tobytes() == fb.angle_rad.tobytes()
    c = simulate(settings, rng=np.random.default_rng(7))
    assert c == a
    d = simulate(dataclasses.replace(settings, seed=8))
    assert d != a


def test_step_wise_run_matches_and_can_be_cancelled():
    settings = SimulationSettings(n_frames=30, seed=3)
    full = simulate(settings)
    simulator = Simulator(settings)
    frames = []
    for frame in simulator.iter_frames():
        frames.append(frame)
        if len(frames) == 10:
            break
    partial = simulator.result()
    assert len(partial.frames) == partial.settings.n_frames == 10
    assert partial.frames == full.frames[:10]
    assert all(r.end_frame <= 9 for r in partial.lineage.values())
    rest = list(simulator.iter_frames())
    assert len(rest) == 20
    assert simulator.result() == full
    with pytest.raises(RuntimeError, match="already"):
        simulator.step()


def test_progress_reports_every_frame():
    calls = []
    simulate(
        SimulationSettings(n_frames=7), progress=lambda done, total: calls.append((done, total))
    )
    assert calls == [(i, 7) for i in range(1, 8)]


def test_chamber_grows_in_two_dimensions():
    settings = SimulationSettings(
        geometry="chamber",
        n_frames=120,
        n_founders=3,
        trench=TrenchGeometry(length_um=10.0, width_um=10.0),
    )
    sim = simulate(settings)
    frame = sim.frames[-1]
    assert len(frame) >= 25
    assert frame.x_um.std() > 2.0  # spread across the chamber
    # The walls hold in every frame, not only the last (cells along the closed end
    # were once pushed 0.5 um into a side wall by their neighbours' growth).
    for shown in sim.frames:
        left, right, top, _ = _extent(shown)
        assert left.min() > -WALL_TOLERANCE_UM
        assert right.max() < 10 + WALL_TOLERANCE_UM
        assert top.min() > -WALL_TOLERANCE_UM
    assert frame.y_um.max() <= 10.0
    assert any(r.fate == "exited" for r in sim.lineage.values())


def test_agar_pad_colony_grows_as_a_monolayer():
    settings = SimulationSettings(
        geometry="agar_pad", n_frames=48, agar_pad=AgarPadGeometry(30.0, 30.0)
    )
    sim = simulate(settings)
    counts = sim.cell_counts()
    assert counts[0] == 1
    assert counts[-1] >= 40
    frame = sim.frames[-1]
    assert np.all((frame.x_um >= 0) & (frame.x_um <= 30) & (frame.y_um >= 0) & (frame.y_um <= 30))
    assert np.hypot(frame.x_um - 15, frame.y_um - 15).max() < 15  # a compact colony
    # a 2D colony, not a single file of cells
    assert np.ptp(frame.x_um) > 6
    assert np.ptp(frame.y_um) > 6
    assert sim.walls_um == ()
    # a monolayer: no two cell centres coincide
    d = np.hypot(frame.x_um[:, None] - frame.x_um[None], frame.y_um[:, None] - frame.y_um[None])
    assert d[np.triu_indices(len(frame), 1)].min() > 0.3


def test_custom_outline_confines_cells():
    box = [(0.0, 14.0), (0.0, 0.0), (6.0, 0.0), (6.0, 14.0)]  # open at the bottom
    settings = SimulationSettings(
        geometry="outline",
        n_frames=100,
        outline=OutlineGeometry(
            polylines_um=(tuple(box),), founders_um=((3.0, 2.0),), exit_margin_um=1.0
        ),
    )
    sim = simulate(settings)
    assert len(sim.walls_um) == 1
    assert sim.walls_um[0].shape == (4, 2)
    # the drawn line is the wall's centre, and the wall is 0.05 um thick on each side
    tol = WALL_TOLERANCE_UM + 0.1
    for frame in sim.frames:
        left, right, top, _ = _extent(frame)
        assert left.min() > -tol
        assert right.max() < 6 + tol
        assert top.min() > -tol
        assert frame.y_um.max() <= 15.0
    assert sim.cell_counts()[-1] >= 15


def test_outline_from_dxf(tmp_path):
    ezdxf = pytest.importorskip("ezdxf")
    doc = ezdxf.new()
    # drawn in mm with y up: a 6 x 14 um cup open at the bottom of the image
    doc.modelspace().add_lwpolyline(
        [(0, 0), (0, 0.014), (0.006, 0.014), (0.006, 0)], dxfattribs={"layer": "WALLS"}
    )
    doc.modelspace().add_line((1, 1), (2, 2), dxfattribs={"layer": "NOTES"})
    path = tmp_path / "device.dxf"
    doc.saveas(path)
    settings = SimulationSettings(
        geometry="outline",
        n_frames=40,
        outline=OutlineGeometry(
            dxf_path=str(path), dxf_layer="WALLS", dxf_unit_um=1000.0, founders_um=((3.0, 2.0),)
        ),
    )
    sim = simulate(settings)
    (wall,) = sim.walls_um
    np.testing.assert_allclose(wall, [[0, 14], [0, 0], [6, 0], [6, 14]], atol=1e-9)
    for frame in sim.frames:
        left, right, top, _ = _extent(frame)
        assert left.min() > -0.12
        assert right.max() < 6.12
        assert top.min() > -0.12


def test_geometry_settings_round_trip():
    settings = SimulationSettings(
        geometry="outline",
        outline=OutlineGeometry(polylines_um=(((0, 0), (1, 2)),), founders_um=((0.5, 0.5),)),
    )
    data = to_dict(settings)
    assert from_dict(SimulationSettings, data) == settings
    # lists from YAML become tuples
    data["outline"]["polylines_um"] = [[[0, 0], [1, 2]]]
    assert from_dict(SimulationSettings, data) == settings
