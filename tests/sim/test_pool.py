"""Parked bodies (napari_symbac.sim.pool): a big colony reuses the bodies of removed
cells instead of removing them from the space (which scans every contact). A reused
body carries no contact over, so only the solver's order changes: lineage, lengths
and widths stay the same, and the physics statistics with them."""

from __future__ import annotations

import pickle

import numpy as np
import pymunk
import pytest
from scipy.spatial import cKDTree

from napari_symbac.settings import AgarPadGeometry, SimulationSettings, TrenchGeometry
from napari_symbac.sim import Simulator, simulate
from napari_symbac.sim import pool as pool_module
from napari_symbac.sim.pool import BodyPool

SQUARE = [(-2.0, -2.0), (2.0, -2.0), (2.0, 2.0), (-2.0, 2.0)]
ROD = [(-1.0, -3.0), (1.0, -3.0), (1.0, 3.0), (-1.0, 3.0)]


def _arbiters(body: pymunk.Body) -> list:
    found: list = []
    body.each_arbiter(found.append)
    return found


def test_small_colonies_remove_bodies_from_the_space():
    space = pymunk.Space()
    bodies = BodyPool(space)
    body, shape = bodies.take(SQUARE, 1.0, 2.0, 3.0, (5.0, 6.0), 0.5)
    assert body in space.bodies
    assert shape in space.shapes
    assert (body.mass, body.moment, tuple(body.position), body.angle) == (2.0, 3.0, (5.0, 6.0), 0.5)
    assert shape.radius == 1.0
    bodies.give_back(body, shape)
    assert body not in space.bodies
    assert len(bodies) == 0


def test_big_colonies_park_bodies_and_reuse_them_without_their_contacts(monkeypatch):
    monkeypatch.setattr(pool_module, "PARK_MIN_CELLS", 1)
    space = pymunk.Space()
    bodies = BodyPool(space)
    a, a_shape = bodies.take(SQUARE, 1.0, 1.0, 1.0, (0.0, 0.0), 0.0)
    b, _ = bodies.take(SQUARE, 1.0, 1.0, 1.0, (5.5, 0.0), 0.0)  # 0.5 deep into a
    space.step(1.0)
    bodies.tick()
    assert _arbiters(a)
    bodies.give_back(a, a_shape)
    assert a in space.bodies  # parked, not removed
    assert a.position.get_distance(b.position) > 1e6
    assert tuple(a.velocity) == (0.0, 0.0)
    assert len(bodies) == 1
    # its contact with b is still cached: not handed out yet
    c, _ = bodies.take(SQUARE, 1.0, 1.0, 1.0, (50.0, 0.0), 0.0)
    assert c is not a
    for _ in range(space.collision_persistence + 1):
        space.step(1.0)
        bodies.tick()
    e, _ = bodies.take(SQUARE, 1.0, 1.0, 1.0, (-50.0, 0.0), 0.0)
    assert e is not a  # one step short
    space.step(1.0)
    bodies.tick()
    d, d_shape = bodies.take(ROD, 0.5, 7.0, 8.0, (5.0, 0.25), 0.2)
    assert d is a
    assert d_shape is a_shape
    assert [tuple(v) for v in d_shape.get_vertices()] == ROD
    assert d_shape.radius == 0.5
    assert (d.mass, d.moment, tuple(d.position), d.angle) == (7.0, 8.0, (5.0, 0.25), 0.2)
    assert _arbiters(d) == []  # no contact history: like a new body
    assert len(bodies) == 0


def _pad(seed: int = 2) -> SimulationSettings:
    return SimulationSettings(
        geometry="agar_pad", n_frames=62, agar_pad=AgarPadGeometry(40.0, 40.0), seed=seed
    )


def _depths(frame) -> np.ndarray:
    pos = np.c_[frame.x_um, frame.y_um]
    axes = _capsule_axes(frame.angle_rad, frame.length_um, frame.width_um)
    _, gap = _neighbour_gaps(pos, axes, frame.width_um, 0.0)
    return -gap[gap < 0]


@pytest.fixture(scope="module")
def removing():
    return simulate(_pad())


@pytest.fixture(scope="module")
def parking():
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(pool_module, "PARK_MIN_CELLS", 10)
        simulator = Simulator(_pad())
        for _ in simulator.iter_frames():
            pass
        again = simulate(_pad())
    return simulator, again


def test_parking_reuses_bodies_and_is_deterministic(parking):
    simulator, again = parking
    sim = simulator.result()
    assert again == sim  # same seed, same bits
    born = len(sim.lineage)
    alive = len(sim.frames[-1])
    # bodies in the space: the living cells, the parked ones, the static body's none
    in_space = len(simulator._space.bodies)
    assert in_space == alive + len(simulator._pool)
    assert in_space < born - 50  # most daughters got a parked body


def test_parking_changes_only_the_positions(parking, removing):
    sim = parking[0].result()
    assert sim.lineage == removing.lineage  # the same divisions, at the same frames
    moved = False
    for a, b in zip(sim.frames, removing.frames):
        assert a.ids.tobytes() == b.ids.tobytes()
        assert a.length_um.tobytes() == b.length_um.tobytes()
        assert a.width_um.tobytes() == b.width_um.tobytes()
        moved |= not np.array_equal(a.x_um, b.x_um)
    assert moved  # the solver's order of bodies differs, so trajectories do
    # the same physics: overlaps and compactness as with removal
    last, ref = sim.frames[-1], removing.frames[-1]
    assert len(last) > 120
    depth, ref_depth = _depths(last), _depths(ref)
    assert np.median(depth) < np.median(ref_depth) + 0.01
    assert depth.max() < ref_depth.max() + 0.05
    spread = np.hypot(last.x_um - last.x_um.mean(), last.y_um - last.y_um.mean()).std()
    ref_spread = np.hypot(ref.x_um - ref.x_um.mean(), ref.y_um - ref.y_um.mean()).std()
    assert spread == pytest.approx(ref_spread, rel=0.1)


def test_parked_cells_stay_out_of_a_chamber_and_its_walls_hold(monkeypatch):
    monkeypatch.setattr(pool_module, "PARK_MIN_CELLS", 5)
    settings = SimulationSettings(
        geometry="chamber",
        n_frames=100,
        n_founders=3,
        trench=TrenchGeometry(length_um=10.0, width_um=10.0),
        seed=1,
    )
    simulator = Simulator(settings)
    for _ in simulator.iter_frames():
        pass
    sim = simulator.result()
    assert any(r.fate == "exited" for r in sim.lineage.values())
    assert len(simulator._pool) + len(sim.frames[-1]) == len(simulator._space.bodies)
    for frame in sim.frames:
        p0, p1 = frame.poles_um()
        r = frame.width_um / 2
        assert (np.minimum(p0[:, 0], p1[:, 0]) - r).min() > -0.06
        assert (np.maximum(p0[:, 0], p1[:, 0]) + r).max() < 10.06
        assert (np.minimum(p0[:, 1], p1[:, 1]) - r).min() > -0.06
        assert frame.y_um.max() <= 10.0


def test_a_pickled_simulator_keeps_reusing_parked_bodies(monkeypatch):
    # napari-symbac bench times colonies restored from pickles
    monkeypatch.setattr(pool_module, "PARK_MIN_CELLS", 10)
    simulator = Simulator(_pad())
    for _ in range(55):
        simulator.step()
    restored = pickle.loads(pickle.dumps(simulator))
    parked = len(restored._pool)
    assert parked > 0
    bodies = len(restored._space.bodies)
    born = len(restored.result().lineage)
    for _ in range(5):
        frame = restored.step()
    new_cells = len(restored.result().lineage) - born
    assert new_cells > parked  # more daughters than parked bodies ...
    assert len(restored._space.bodies) - bodies < new_cells - parked + 1  # ... all reused
    assert len(restored._space.bodies) == len(frame) + len(restored._pool)


# overlap depth of capsules (the measure of docs/simulation.md's contact-depth table)
def _capsule_axes(angle_rad: np.ndarray, length_um: np.ndarray, width_um: np.ndarray) -> np.ndarray:
    """``(n, 2)`` vectors from each centre to one cap's centre (``angle_rad`` from +y,
    as in :class:`~napari_symbac.sim.cells.FrameCells`)."""
    half = np.maximum(length_um - width_um, 0.0) / 2
    return np.c_[np.sin(angle_rad), np.cos(angle_rad)] * half[:, None]


def _neighbour_gaps(
    pos_um: np.ndarray, axes_um: np.ndarray, width_um: np.ndarray, within_um: float
) -> tuple[np.ndarray, np.ndarray]:
    """Pairs ``(k, 2)`` of cells whose capsules may be closer than ``within_um`` and
    their gaps ``(k,)`` (negative: overlap)."""
    if len(pos_um) < 2:
        return np.empty((0, 2), dtype=np.intp), np.empty(0)
    reach = float(np.hypot(axes_um[:, 0], axes_um[:, 1]).max() + width_um.max() / 2)
    pairs = cKDTree(pos_um).query_pairs(2 * reach + within_um, p=np.inf, output_type="ndarray")
    i, j = pairs[:, 0], pairs[:, 1]
    gap = _axis_distance(pos_um[i], axes_um[i], pos_um[j], axes_um[j])
    return pairs, gap - (width_um[i] + width_um[j]) / 2


def _axis_distance(
    centre_a: np.ndarray, half_a: np.ndarray, centre_b: np.ndarray, half_b: np.ndarray
) -> np.ndarray:
    """Distance between the segments ``centre +- half`` of each row (the capsules'
    axes): the closest points of two segments, clamped to both (Ericson,
    *Real-Time Collision Detection*, 5.1.9)."""
    p, q = centre_a - half_a, centre_b - half_b
    d1, d2, r = 2 * half_a, 2 * half_b, p - q
    a = np.einsum("ij,ij->i", d1, d1)
    e = np.einsum("ij,ij->i", d2, d2)
    f = np.einsum("ij,ij->i", d2, r)
    c = np.einsum("ij,ij->i", d1, r)
    b = np.einsum("ij,ij->i", d1, d2)
    tiny = 1e-12
    a_ = np.where(a > tiny, a, 1.0)
    e_ = np.where(e > tiny, e, 1.0)
    denom = a * e - b * b
    skew = denom > tiny * a_ * e_  # not parallel: else any s, take 0
    s = np.where(skew, np.clip((b * f - c * e) / np.where(skew, denom, 1.0), 0, 1), 0.0)
    t = (b * s + f) / e_
    s = np.where(t < 0, np.clip(-c / a_, 0, 1), np.where(t > 1, np.clip((b - c) / a_, 0, 1), s))
    t = np.clip(t, 0, 1)
    point_b = e <= tiny  # b is a point (a round cell)
    s = np.where(point_b, np.clip(-c / a_, 0, 1), s)
    t = np.where(point_b, 0.0, t)
    point_a = a <= tiny
    t = np.where(point_a, np.where(point_b, 0.0, np.clip(f / e_, 0, 1)), t)
    s = np.where(point_a, 0.0, s)
    gap = p + d1 * s[:, None] - (q + d2 * t[:, None])
    return np.hypot(gap[:, 0], gap[:, 1])
