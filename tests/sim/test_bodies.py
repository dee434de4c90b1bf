"""Batched access to the cells' bodies (napari_symbac.sim.bodies) and the colony runs
that rely on it."""

from __future__ import annotations

import numpy as np
import pymunk
import pytest

from napari_symbac.settings import AgarPadGeometry, SimulationSettings
from napari_symbac.sim import Simulation, Simulator, simulate
from napari_symbac.sim.bodies import BodyTable, reshape_body


def _space_with_bodies(n: int) -> tuple[pymunk.Space, list[pymunk.Body]]:
    space = pymunk.Space()
    wall = pymunk.Segment(space.static_body, (-50, -50), (50, -50), 1.0)
    space.add(wall)  # the static body takes part in pymunk.batch's iteration
    bodies = []
    for i in range(n):
        body = pymunk.Body(1.0 + i, 2.0 + i)
        body.position = (3.0 * i, -7.0 * i + 0.5)
        body.angle = 0.1 * i - 0.3
        space.add(body, pymunk.Circle(body, 1.0))
        bodies.append(body)
    return space, bodies


def test_body_table_follows_the_given_order_after_removals():
    space, bodies = _space_with_bodies(7)
    for gone in (bodies[1], bodies[4]):  # pymunk moves its last body into each gap
        space.remove(gone, *gone.shapes)
    kept = [bodies[k] for k in (6, 0, 3, 5, 2)]
    table = BodyTable(space, kept)
    pos, angle = table.poses()
    np.testing.assert_array_equal(pos, [tuple(b.position) for b in kept])
    np.testing.assert_array_equal(angle, [b.angle for b in kept])

    velocity = np.arange(10.0).reshape(5, 2) - 4.5
    spin = np.array([0.5, -1.0, 2.0, 0.0, 3.5])
    table.set_motion(velocity, spin)
    np.testing.assert_array_equal([tuple(b.velocity) for b in kept], velocity)
    np.testing.assert_array_equal([b.angular_velocity for b in kept], spin)
    assert tuple(space.static_body.velocity) == (0.0, 0.0)
    table.set_motion(np.zeros((5, 2)), 0.0)
    assert all(tuple(b.velocity) == (0.0, 0.0) and b.angular_velocity == 0.0 for b in kept)


def test_reshape_body_sets_vertices_mass_and_moment():
    space, (body,) = _space_with_bodies(1)
    shape = pymunk.Poly(body, [(-1, -1), (1, -1), (1, 1), (-1, 1)], radius=0.5)
    space.add(shape)
    vertices = [(-2.0, -30.0), (2.0, -30.0), (2.0, 30.0), (-2.0, 30.0)]
    reshape_body(body, shape, vertices, 4.25, 1234.5)
    assert [tuple(v) for v in shape.get_vertices()] == vertices
    assert body.mass == 4.25
    assert body.moment == 1234.5


def _colony(seed: int = 5) -> SimulationSettings:
    # a field small enough that cells leave it (fate "exited") within the run
    return SimulationSettings(
        geometry="agar_pad", n_frames=40, agar_pad=AgarPadGeometry(10.0, 10.0), seed=seed
    )


@pytest.fixture(scope="module")
def colony() -> Simulation:
    return simulate(_colony())


def test_colony_run_is_bit_identical_and_removes_cells_leaving_the_field(colony):
    again = simulate(_colony())
    assert again == colony
    for fa, fb in zip(again.frames, colony.frames):
        for name in ("x_um", "y_um", "angle_rad", "length_um"):
            assert getattr(fa, name).tobytes() == getattr(fb, name).tobytes()
    # a cell is removed in the frame its centre leaves the field (a daughter whose
    # centre is outside at birth ends the frame before it was born)
    exited = [r for r in colony.lineage.values() if r.fate == "exited"]
    assert any(r.end_frame >= r.birth_frame for r in exited)
    for frame in colony.frames:
        assert np.all((frame.x_um >= 0) & (frame.x_um <= 10))
        assert np.all((frame.y_um >= 0) & (frame.y_um <= 10))
        assert np.all((frame.angle_rad > -np.pi / 2) & (frame.angle_rad <= np.pi / 2))
    for record in exited:
        if record.end_frame >= record.birth_frame:
            assert record.cell_id in colony.frames[record.end_frame].ids
        if record.end_frame + 1 < len(colony.frames):
            assert record.cell_id not in colony.frames[record.end_frame + 1].ids
    assert simulate(_colony(seed=6)) != colony


def test_colony_step_wise_matches_one_call(colony):
    simulator = Simulator(_colony())
    frames = list(simulator.iter_frames())
    assert len(frames) == len(colony.frames)
    for fa, fb in zip(frames, colony.frames):
        assert fa.ids.tobytes() == fb.ids.tobytes()
        assert fa.x_um.tobytes() == fb.x_um.tobytes()
        assert fa.angle_rad.tobytes() == fb.angle_rad.tobytes()
