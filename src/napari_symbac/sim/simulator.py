"""Agent-based growth with rigid-body physics (supplement section 2, Algorithm 1).

Each cell is an agent (length, width, position, angle, growth-rate constant, division
target, target width) and a pymunk body carrying a capsule shape (a rounded box: a thin
:class:`pymunk.Poly` core with a radius, :func:`_core`). Every frame:

1. Each cell lyses with probability ``lysis_p``; otherwise it elongates as
   ``L <- L exp(k dt I)``, ``I ~ U(1 - a, 1 + a)``, while its width relaxes towards a
   target width drawn at birth (width varies within and between lineages).
2. A cell that meets its growth model's criterion (sizer: a drawn length; adder: a
   drawn added length; timer: a drawn age) divides at a noisy septum into two
   daughters whose volumes sum exactly to the mother's; daughters inherit its angle
   with a small jitter.
3. ``phys_iters`` physics iterations: jitter, gravity drift, collision resolution.
4. Cells whose centre has left the trench's open end (or the field) are removed.

Motion is overdamped: a body's velocity is reset every iteration to its gravity drift
plus jitter, so only the contact impulses and overlap correction move it further.
All randomness comes from one :class:`numpy.random.Generator`, and pymunk is
deterministic, so a seed gives a bit-identical trajectory.
"""

from __future__ import annotations

import math
import os
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path

import numpy as np
import pymunk

from napari_symbac.settings import SimulationSettings
from napari_symbac.sim.bodies import BodyTable, reshape_body
from napari_symbac.sim.cells import FrameCells, LineageRecord, Simulation
from napari_symbac.sim.geometry import Layout, make_layout
from napari_symbac.sim.pool import BodyPool

__all__ = ["Simulator", "simulate"]

Progress = Callable[[int, int], None]

#: Physics world units per micrometre. Chipmunk's tolerances are absolute, so a
#: fine scale keeps them far below a micrometre.
SCALE = 100.0
#: Overlap tolerated between touching shapes (um); smaller costs more iterations.
COLLISION_SLOP_UM = 0.002
#: Fraction of an overlap left after one physics iteration (Chipmunk's collision bias
#: at ``dt = 1``): each iteration corrects 70 % of what remains.
COLLISION_BIAS = 0.3
#: Half-width of the rectangle at the core of each cell's rounded box (world units).
CORE_HALF_WIDTH = 2.0
#: Factor on the cells' moment of inertia: contacts turn cells this much more slowly.
ROTATIONAL_DRAG = 10.0
#: Cells closer than this along the trench push each other (one growth group).
GROUP_GAP_UM = 0.05
#: Fraction of the gravity drift applied to groups already resting on the closed end
#: (or to a colony): a gentle compression that tightens stacking without asking the
#: solver to hold up a whole stack in one iteration.
GRAVITY_COMPRESSION = 0.1
#: Constraint-solver iterations within one physics iteration.
SOLVER_ITERATIONS = 20
#: A founder's length at the start, as a fraction of its division length (sizer) or of
#: ``cell_max_length_um`` (else): drawn uniformly in this range, so that founders are
#: not all newborn.
FOUNDER_LENGTH_FRACTION = (0.5, 0.9)


class _Cell:
    """Mutable agent state of one living cell (internal)."""

    __slots__ = (
        "age_min",
        "birth_length_um",
        "body",
        "cell_id",
        "length_um",
        "shape",
        "shown_length_um",
        "target",
        "target_width_um",
        "width_um",
    )

    def __init__(
        self, cell_id: int, length_um: float, width_um: float, target_width_um: float, target: float
    ) -> None:
        self.cell_id = cell_id
        self.length_um = length_um
        self.birth_length_um = length_um
        self.width_um = width_um
        self.target_width_um = target_width_um
        self.target = target
        self.age_min = 0.0
        self.shown_length_um = length_um  # length of the physics shape right now
        self.body: pymunk.Body | None = None
        self.shape: pymunk.Poly | None = None


class Simulator:
    """Run a simulation frame by frame (for live display and cancellation).

    Parameters
    ----------
    settings
        What to simulate.
    rng
        The generator every random draw comes from; ``None`` uses
        ``numpy.random.default_rng(settings.seed)``.

    Examples
    --------
    >>> from napari_symbac.settings import SimulationSettings
    >>> sim = Simulator(SimulationSettings(n_frames=5))
    >>> [len(frame) for frame in sim.iter_frames()][0]
    1
    >>> len(sim.result().frames)
    5
    """

    def __init__(
        self, settings: SimulationSettings, rng: np.random.Generator | None = None
    ) -> None:
        if not isinstance(settings, SimulationSettings):
            raise TypeError(f"Simulator needs SimulationSettings, got {type(settings).__name__}")
        self.settings = settings
        self.rng = np.random.default_rng(settings.seed) if rng is None else rng
        self.layout: Layout = make_layout(settings, self.rng)
        self._space = self._make_space()
        self._pool = BodyPool(self._space)
        self._cells: list[_Cell] = []
        self._frames: list[FrameCells] = []
        self._next_id = 1
        # lineage columns: id -> [parent, birth_frame, end_frame, fate, curvature]
        self._records: dict[int, list] = {}
        self._dt_min = settings.frame_interval_min
        self._width_relax = 1.0 - math.exp(-settings.growth_rate_per_min * self._dt_min)
        for x, y, angle in self.layout.founders:
            self._add_founder(x, y, angle)

    # ------------------------------------------------------------------ physics world
    def _make_space(self) -> pymunk.Space:
        space = pymunk.Space()
        space.iterations = SOLVER_ITERATIONS
        space.collision_slop = COLLISION_SLOP_UM * SCALE
        space.collision_bias = COLLISION_BIAS
        space.damping = 0.0
        for x0, y0, x1, y1, radius in self.layout.segments_um:
            wall = pymunk.Segment(
                space.static_body,
                (x0 * SCALE, y0 * SCALE),
                (x1 * SCALE, y1 * SCALE),
                radius * SCALE,
            )
            wall.elasticity = 0.0
            wall.friction = 0.0
            space.add(wall)
        return space

    def _attach_body(
        self,
        cell: _Cell,
        x_um: float,
        y_um: float,
        angle_rad: float,
        shown_length_um: float | None = None,
    ) -> None:
        if shown_length_um is not None:
            cell.shown_length_um = shown_length_um
        cell.body, cell.shape = self._pool.take(
            _core(cell.shown_length_um, cell.width_um),
            cell.width_um / 2 * SCALE - CORE_HALF_WIDTH,
            *_mass_and_moment(cell.width_um, cell.shown_length_um),
            (x_um * SCALE, y_um * SCALE),
            -angle_rad,
        )

    def _remove(self, cell: _Cell, fate: str, last_frame: int) -> None:
        self._pool.give_back(cell.body, cell.shape)
        cell.body = cell.shape = None
        record = self._records[cell.cell_id]
        record[2], record[3] = last_frame, fate

    # ------------------------------------------------------------------ agents
    def _draw_width(self) -> float:
        s = self.settings
        width = self.rng.normal(s.cell_width_um, math.sqrt(s.width_var_um2))
        return float(np.clip(width, 0.3 * s.cell_width_um, self.layout.max_width_um))

    def _draw_target(self) -> float:
        """Division criterion drawn at birth, in the growth model's own unit."""
        s = self.settings
        if s.growth_model == "sizer":
            value = self.rng.normal(s.cell_max_length_um, math.sqrt(s.max_length_var_um2))
            return float(max(value, 1.2 * s.cell_width_um))
        if s.growth_model == "adder":
            value = self.rng.normal(s.added_length_um, math.sqrt(s.max_length_var_um2))
            return float(max(value, 0.05 * s.added_length_um))
        value = self.rng.normal(s.interdivision_time_min, math.sqrt(s.interdivision_time_var_min2))
        return float(max(value, s.frame_interval_min))

    def _draw_curvature(self) -> tuple[float, float, float]:
        if not self.settings.do_transformation:
            return (0.0, 0.0, 0.0)
        a = self.rng.uniform(-0.1, 0.1) * self.settings.cell_width_um
        b = self.rng.uniform(0.75, 1.5)
        c = self.rng.uniform(-math.pi / 8, math.pi / 8)
        return (float(a), float(b), float(c))

    def _new_record(self, parent_id: int, birth_frame: int) -> int:
        cell_id = self._next_id
        self._next_id += 1
        self._records[cell_id] = [parent_id, birth_frame, -1, "alive", self._draw_curvature()]
        return cell_id

    def _add_founder(self, x_um: float, y_um: float, angle_rad: float) -> None:
        s = self.settings
        width = self._draw_width()
        target = self._draw_target()
        if s.growth_model == "sizer":
            length = target * self.rng.uniform(*FOUNDER_LENGTH_FRACTION)
        else:
            length = s.cell_max_length_um * self.rng.uniform(*FOUNDER_LENGTH_FRACTION)
        length = max(length, 1.05 * width)
        cell = _Cell(self._new_record(0, 0), length, width, width, target)
        if s.growth_model == "timer":
            cell.age_min = target * self.rng.uniform(0.0, 0.8)
        self._attach_body(cell, x_um, y_um, angle_rad)
        self._cells.append(cell)

    def _wants_division(self, cell: _Cell) -> bool:
        model = self.settings.growth_model
        if model == "sizer":
            return cell.length_um >= cell.target
        if model == "adder":
            return cell.length_um - cell.birth_length_um >= cell.target
        return cell.age_min >= cell.target

    def _divide(self, mother: _Cell, frame: int) -> list[_Cell]:
        """Split ``mother`` at a noisy septum, conserving volume (Algorithm 1).

        The daughters keep the mother's width at birth, so with
        ``V = pi r^2 L - (2/3) pi r^3`` their lengths sum to ``L + (2/3) r``.
        """
        s = self.settings
        w, big_l = mother.width_um, mother.length_um
        total = big_l + w / 3
        lo = 1.02 * w / total
        if lo >= 0.5:  # too short to split into two rods: keep growing
            return [mother]
        f = 0.5 + self.rng.normal(0.0, s.septum_sd) if s.septum_sd > 0 else 0.5
        f = float(np.clip(f, lo, 1.0 - lo))
        lengths = (f * total, (1.0 - f) * total)
        # The daughters' physics shapes start by exactly filling the mother's shape as
        # it was before this frame's growth, and grow to full length over the physics
        # iterations like every other cell, so division creates no sudden overlap.
        shown = mother.shown_length_um
        starts = tuple(max(length * shown / total, 1.01 * w) for length in lengths)
        body = mother.body
        cx, cy = body.position.x / SCALE, body.position.y / SCALE
        angle = -body.angle
        ux, uy = math.sin(angle), math.cos(angle)
        self._remove(mother, "divided", frame - 1)
        # The first daughter takes the pole at -u, the second the pole at +u.
        offsets = (-shown / 2 + starts[0] / 2, shown / 2 - starts[1] / 2)
        daughters = []
        for length, start, offset in zip(lengths, starts, offsets):
            cell_id = self._new_record(mother.cell_id, frame)
            daughter = _Cell(cell_id, length, w, self._draw_width(), self._draw_target())
            jitter = self.rng.uniform(-s.angle_jitter_rad, s.angle_jitter_rad)
            self._attach_body(daughter, cx + offset * ux, cy + offset * uy, angle + jitter, start)
            daughters.append(daughter)
        return daughters

    # ------------------------------------------------------------------ stepping
    def _grow_and_divide(self, frame: int) -> None:
        s = self.settings
        survivors: list[_Cell] = []
        a = s.growth_noise
        for cell in self._cells:
            lysis, noise = self.rng.random(2)
            if s.lysis_p > 0 and lysis < s.lysis_p:
                self._remove(cell, "lysed", frame - 1)
                continue
            rate = s.growth_rate_per_min * (1.0 - a + 2.0 * a * noise)
            cell.length_um *= math.exp(rate * self._dt_min)
            cell.width_um += (cell.target_width_um - cell.width_um) * self._width_relax
            cell.length_um = max(cell.length_um, 1.02 * cell.width_um)
            cell.age_min += self._dt_min
            if self._wants_division(cell):
                survivors.extend(self._divide(cell, frame))
            else:
                survivors.append(cell)
        self._cells = survivors

    def _physics(self) -> None:
        """``phys_iters`` iterations of: grow shapes a little, set each body's velocity
        (growth flow + gravity drift + jitter), resolve collisions with pymunk."""
        s = self.settings
        cells = self._cells
        n = len(cells)
        if n == 0:
            return
        iters = s.phys_iters
        drift = s.gravity * s.frame_interval_min / iters  # um per iteration
        jitter = s.jitter_um
        widths = np.array([c.width_um for c in cells])
        half = np.maximum(np.array([c.length_um for c in cells]) - widths, widths) / 2
        bodies = [c.body for c in cells]
        table = BodyTable(self._space, bodies)
        # Growth is spread over the iterations so that overlaps stay small (a capsule
        # whose core crosses another's would be pushed out sideways).
        start = np.array([c.shown_length_um for c in cells])
        ratio = np.array([c.length_um for c in cells]) / start
        rate = ratio ** (1.0 / iters) - 1.0  # relative elongation per iteration
        growing = np.flatnonzero(ratio != 1.0)
        grown = [cells[i] for i in growing.tolist()]
        for cell in grown:  # the width is fixed within a frame
            cell.shape.unsafe_set_radius(cell.width_um / 2 * SCALE - CORE_HALF_WIDTH)
        for it in range(iters):
            shown = start * ratio ** ((it + 1) / iters)
            if it + 1 == iters:
                lengths = [cell.length_um for cell in grown]
            else:
                lengths = shown[growing].tolist()
            for cell, length in zip(grown, lengths):
                cell.shown_length_um = length
                w = cell.width_um
                reshape_body(cell.body, cell.shape, _core(length, w), *_mass_and_moment(w, length))
            pos, body_angle = table.poses()
            pos = pos / SCALE
            angle = -body_angle
            velocity = self._flow(pos, angle, shown, widths, rate, drift)
            if self.layout.box_walls_um is not None:
                _clamp_at_walls(velocity, pos, angle, shown, widths, self.layout.box_walls_um)
            elif self.layout.segments_um and self.layout.flow != "none":
                _clamp_at_contacts(velocity, bodies)
            spin = 0.0
            if jitter > 0:
                kicks = self.rng.normal(0.0, jitter, size=(n, 3))
                velocity += kicks[:, :2]
                spin = -kicks[:, 2] / half
            velocity *= SCALE
            table.set_motion(velocity, spin)
            self._space.step(1.0)
            self._pool.tick()
            if self.layout.box_walls_um is not None:
                _hold_inside_walls(bodies, shown, widths, self.layout.box_walls_um)
        table.set_motion(np.zeros((n, 2)), 0.0)

    def _groups(
        self, pos: np.ndarray, angle: np.ndarray, length: np.ndarray, width: np.ndarray
    ) -> list[tuple[np.ndarray, bool, float, float]]:
        """Groups of cells touching along the trench: ``(members, grounded, top,
        bottom)``; a grounded group touches the closed end."""
        reach = np.abs(np.cos(angle)) * (length - width) / 2 + width / 2
        top, bottom = pos[:, 1] - reach, pos[:, 1] + reach
        order = np.argsort(top, kind="stable")
        groups = []
        start, group_bottom = 0, -np.inf
        for k, i in enumerate(order.tolist()):
            if k > 0 and top[i] > group_bottom + GROUP_GAP_UM:
                groups.append(order[start:k])
                start, group_bottom = k, -np.inf
            group_bottom = max(group_bottom, bottom[i])
        groups.append(order[start:])
        out = []
        for members in groups:
            g_top, g_bottom = float(top[members].min()), float(bottom[members].max())
            out.append((members, g_top <= GROUP_GAP_UM, g_top, g_bottom))
        return out

    def _flow(
        self,
        pos: np.ndarray,
        angle: np.ndarray,
        length: np.ndarray,
        width: np.ndarray,
        rate: np.ndarray,
        drift: float,
    ) -> np.ndarray:
        """Velocity (um per iteration) of each cell from growth and gravity.

        Overdamped cells in contact move with the growth of the cells between them and
        the point their group expands from. Pymunk's sequential-impulse solver would
        propagate such a push along a stack of ``N`` cells only over ~``N^2``
        iterations, letting overlaps pile up; predicting it leaves the solver only
        the residual contacts (collisions, buckling, walls) to resolve.

        * Trench and chamber: cells are grouped by overlap of their extents along the
          trench; a group touching the closed end expands from it, a free group
          from its middle: ``v_y = r (y - anchor)``. Positive gravity moves free
          groups towards the closed end at the drift speed and compresses grounded
          ones gently (:data:`GRAVITY_COMPRESSION` of it); negative gravity pulls
          cells out with a speed growing along the trench, opening gaps.
        * Chamber and outline: the colony expands from its centroid,
          ``v = (r / 2)(p - centroid)`` (area grows at the elongation rate ``r``);
          the part of it that would push a cell into a wall it touches is removed.
        * Agar pad: no prediction (an isotropic dilation would also widen the gaps
          of a loose colony); pymunk's contacts push the cells apart.

        Gravity on the agar pad pulls each cell towards (negative: away from) the
        nearest colony centre or scattered founder's place (one colony: the field
        centre), in the other 2D geometries along -y (negative: +y).
        """
        velocity = np.zeros_like(pos)
        if self.layout.flow in ("radial", "none"):
            if self.layout.flow == "radial" and np.any(rate):
                weight = length / length.sum()
                centroid = weight @ pos
                velocity += 0.5 * float(rate @ weight) * (pos - centroid)
            if drift != 0 and self.layout.gravity_centre_um is None:
                # walled 2D geometries: gravity acts along the y axis
                velocity[:, 1] -= drift * (GRAVITY_COMPRESSION if drift > 0 else 1.0)
            elif drift != 0:
                # each cell is pulled to the nearest centre (its own colony's)
                centres = np.asarray(
                    self.layout.gravity_centres_um or (self.layout.gravity_centre_um,)
                )
                offsets = centres[None, :, :] - pos[:, None, :]
                nearest = np.argmin(np.hypot(offsets[..., 0], offsets[..., 1]), axis=1)
                d = offsets[np.arange(len(pos)), nearest]
                dist = np.hypot(d[:, 0], d[:, 1])
                unit = d / np.where(dist > 0, dist, 1.0)[:, None]
                if drift > 0:
                    velocity += GRAVITY_COMPRESSION * drift * unit
                else:
                    scale = max(self.layout.exit_box_um[2] - self.layout.exit_box_um[0], 1.0)
                    velocity += drift * unit * (dist / scale)[:, None]
            return velocity
        grow = bool(np.any(rate))
        extent = max(self.layout.exit_box_um[3], 1.0)
        for members, grounded, g_top, g_bottom in self._groups(pos, angle, length, width):
            y = pos[members, 1]
            if grow:
                anchor = 0.0 if grounded else (g_top + g_bottom) / 2
                r = float(rate[members] @ length[members] / length[members].sum())
                velocity[members, 1] += r * (y - anchor)
            if drift > 0:
                velocity[members, 1] -= drift * (GRAVITY_COMPRESSION if grounded else 1.0)
            elif drift < 0:
                velocity[members, 1] -= drift * np.clip(y / extent, 0.0, 1.0)
        return velocity

    def _remove_exited(self, frame: int) -> FrameCells:
        """Remove the cells whose centre has left the exit box; the others' state."""
        cells = self._cells
        if not cells:
            return _frame_cells([], np.empty((0, 2)), np.empty(0))
        pos, body_angle = BodyTable(self._space, [c.body for c in cells]).poses()
        x0, y0, x1, y1 = (v * SCALE for v in self.layout.exit_box_um)
        x, y = pos[:, 0], pos[:, 1]
        inside = (x0 <= x) & (x <= x1) & (y0 <= y) & (y <= y1)
        for i in np.flatnonzero(~inside).tolist():
            self._remove(cells[i], "exited", frame - 1)
        self._cells = [cell for cell, keep in zip(cells, inside.tolist()) if keep]
        return _frame_cells(self._cells, pos[inside], body_angle[inside])

    @property
    def done(self) -> bool:
        """Whether all ``settings.n_frames`` frames have been simulated."""
        return len(self._frames) >= self.settings.n_frames

    def step(self) -> FrameCells:
        """Simulate the next frame and return its cells.

        Frame 0 is the founders after the physics has settled them; every later
        frame applies lysis, growth and division first.
        """
        if self.done:
            raise RuntimeError(
                f"the simulation already has all n_frames={self.settings.n_frames} frames"
            )
        frame = len(self._frames)
        if frame > 0:
            self._grow_and_divide(frame)
        self._physics()
        cells = self._remove_exited(frame)
        self._frames.append(cells)
        return cells

    def iter_frames(self, progress: Progress | None = None) -> Iterator[FrameCells]:
        """Yield each remaining frame as soon as it is simulated.

        Stop iterating to cancel; :meth:`result` then holds the frames made so far.
        """
        total = self.settings.n_frames
        while not self.done:
            cells = self.step()
            if progress is not None:
                progress(len(self._frames), total)
            yield cells

    def result(self) -> Simulation:
        """The run so far as a :class:`Simulation`.

        If fewer than ``n_frames`` frames were simulated (a cancelled run), the
        returned settings' ``n_frames`` is the number actually made.
        """
        done = len(self._frames)
        settings = self.settings
        if done != settings.n_frames:
            if done == 0:
                raise RuntimeError("no frame has been simulated yet: call step() or iter_frames()")
            settings = replace(settings, n_frames=done)
        lineage = {}
        for cell_id, (parent, birth, end, fate, curvature) in self._records.items():
            if birth >= done:
                continue
            if fate == "alive":
                end = done - 1
            lineage[cell_id] = LineageRecord(cell_id, parent, birth, end, fate, curvature)
        walls = tuple(np.array(w, dtype=float) for w in self.layout.walls_um)
        return Simulation(settings, list(self._frames), lineage, walls)


def _clamp_at_walls(
    velocity: np.ndarray,
    pos: np.ndarray,
    angle: np.ndarray,
    length: np.ndarray,
    width: np.ndarray,
    walls: tuple[float, float],
) -> None:
    """Stop the predicted flow from pushing cells that touch a trench or chamber wall
    into it (the contacts would have to undo it)."""
    along = (length - width) / 2
    reach_x = np.abs(np.sin(angle)) * along + width / 2
    reach_y = np.abs(np.cos(angle)) * along + width / 2
    left, right = walls
    at_left = (pos[:, 0] - reach_x <= left + GROUP_GAP_UM) & (velocity[:, 0] < 0)
    at_right = (pos[:, 0] + reach_x >= right - GROUP_GAP_UM) & (velocity[:, 0] > 0)
    at_top = (pos[:, 1] - reach_y <= GROUP_GAP_UM) & (velocity[:, 1] < 0)
    velocity[at_left | at_right, 0] = 0.0
    velocity[at_top, 1] = 0.0


def _hold_inside_walls(
    bodies: list[pymunk.Body],
    length: np.ndarray,
    width: np.ndarray,
    walls: tuple[float, float],
) -> None:
    """Move any cell that the solver left across a side wall or the closed end back
    inside: the PDMS walls are rigid.

    :func:`_clamp_at_walls` stops the predicted flow only of cells touching a wall; a
    horizontal cell along the closed end can still be pushed into a side wall by the
    growth of its neighbours faster than the contacts (bias, 15 iterations) push it
    back (0.5 um deep in a 10 um chamber before this projection). Moving the body's
    position, not its velocity, keeps the constraint exact in every iteration.
    """
    left, right = walls
    along = (length - width) / 2
    for body, half_length, w in zip(bodies, along.tolist(), width.tolist()):
        x, y = body.position
        x, y = x / SCALE, y / SCALE
        angle = -body.angle
        reach_x = abs(math.sin(angle)) * half_length + w / 2
        reach_y = abs(math.cos(angle)) * half_length + w / 2
        new_x = min(max(x, left + reach_x), right - reach_x) if right - left > 2 * reach_x else x
        new_y = max(y, reach_y)
        if new_x != x or new_y != y:
            body.position = (new_x * SCALE, new_y * SCALE)


def _clamp_at_contacts(velocity: np.ndarray, bodies: list[pymunk.Body]) -> None:
    """Remove the part of each predicted velocity that points into a static wall the
    cell touched in the last physics iteration (any wall shape)."""
    for i, body in enumerate(bodies):
        normals: list[tuple[float, float]] = []

        def _collect(arbiter: pymunk.Arbiter, normals=normals) -> None:
            other = arbiter.shapes[1].body
            if other.body_type == pymunk.Body.STATIC:
                n = arbiter.normal
                normals.append((n.x, n.y))

        body.each_arbiter(_collect)
        for nx, ny in normals:
            into = velocity[i, 0] * nx + velocity[i, 1] * ny
            if into > 0:
                velocity[i, 0] -= into * nx
                velocity[i, 1] -= into * ny


def _core(length_um: float, width_um: float) -> list[tuple[float, float]]:
    """Vertices of the thin core rectangle of a capsule-like rounded box.

    A pymunk ``Poly`` with radius ``r - c`` around a ``2c``-wide rectangle has the
    cell's width ``2r`` and, with half-length ``(L - w)/2 + c``, its length ``L``; its
    caps differ from hemispheres by at most ``c`` (:data:`CORE_HALF_WIDTH`).
    Rounded boxes collide robustly end to end, where Chipmunk's segment-segment
    test loses contacts between nearly collinear capsules.
    """
    c = CORE_HALF_WIDTH
    h = (length_um - width_um) / 2 * SCALE + c
    return [(-c, -h), (c, -h), (c, h), (-c, h)]


def _mass_and_moment(width_um: float, length_um: float) -> tuple[float, float]:
    """Mass = volume; moment of inertia of a rod of that length, times
    :data:`ROTATIONAL_DRAG` (overdamped cells turn much less than they slide)."""
    r = width_um / 2
    mass = math.pi * r * r * length_um - 2.0 / 3.0 * math.pi * r**3
    moment = ROTATIONAL_DRAG * mass * ((length_um * SCALE) ** 2 + (width_um * SCALE) ** 2) / 12
    return mass, moment


def _frame_cells(cells: list[_Cell], pos: np.ndarray, body_angle: np.ndarray) -> FrameCells:
    """The recorded state of ``cells``, whose bodies are at ``pos`` (world units) with
    pymunk angles ``body_angle``."""
    ids = np.array([c.cell_id for c in cells], dtype=np.int64)
    length = np.array([c.length_um for c in cells], dtype=float)
    width = np.array([c.width_um for c in cells], dtype=float)
    x, y = pos[:, 0] / SCALE, pos[:, 1] / SCALE
    return FrameCells(ids, x, y, _wrap(-body_angle), length, width)


def _wrap(angle: np.ndarray) -> np.ndarray:
    """Wrap axis angles to ``(-pi/2, pi/2]`` (a rod looks the same turned by pi)."""
    wrapped = (angle + math.pi / 2) % math.pi - math.pi / 2
    wrapped[wrapped == -math.pi / 2] = math.pi / 2
    return wrapped


def check_save_dir(save_dir: str | os.PathLike) -> Path:
    """Fail early, with the field's name, if ``save_dir`` cannot be written.

    Raises
    ------
    OSError
        If the directory (or its nearest existing parent) is not writable, or it holds
        other files and no saved simulation (which :func:`~napari_symbac.sim.io.
        save_simulation` would refuse only after the whole run).
    """
    from napari_symbac.sim.io import check_simulation_folder

    path = Path(save_dir).expanduser()
    probe_dir = path
    while not probe_dir.exists():
        if probe_dir.parent == probe_dir:
            break
        probe_dir = probe_dir.parent
    if probe_dir.exists() and not probe_dir.is_dir():
        raise OSError(
            f"SimulationSettings.save_dir={str(save_dir)!r}: {probe_dir} is a file, not a "
            "directory; choose another save_dir"
        )
    try:
        with tempfile.TemporaryFile(dir=probe_dir):
            pass
    except OSError as err:
        raise OSError(
            f"SimulationSettings.save_dir={str(save_dir)!r} is not writable ({err.strerror}): "
            "choose a directory you can write to"
        ) from err
    return check_simulation_folder(path)


def simulate(
    settings: SimulationSettings,
    rng: np.random.Generator | None = None,
    progress: Progress | None = None,
) -> Simulation:
    """Simulate growth in the settings' geometry (supplement section 2, Algorithm 1).

    Parameters
    ----------
    settings
        What to simulate. When ``settings.save_dir`` is set, it is checked for
        writability before the run and the result is saved there afterwards
        (:func:`~napari_symbac.sim.save_simulation`).
    rng
        The generator every random draw comes from; ``None`` uses
        ``numpy.random.default_rng(settings.seed)``.
    progress
        Called as ``progress(done, total)`` after each frame.

    Returns
    -------
    Simulation
        Settings, ``settings.n_frames`` frames of cells, and the lineage.
    """
    if not isinstance(settings, SimulationSettings):
        raise TypeError(
            f"simulate() needs SimulationSettings, got {type(settings).__name__}: pass "
            "SimulationSettings(...) or load_settings(path, SimulationSettings)"
        )
    if rng is not None and not isinstance(rng, np.random.Generator):
        seed = repr(rng) if isinstance(rng, int) else "seed"  # not a RandomState's repr
        given = f"{type(rng).__name__} {rng!r}" if isinstance(rng, int) else type(rng).__name__
        raise TypeError(
            f"simulate(rng=...) needs a numpy.random.Generator, got {given}: "
            f"pass numpy.random.default_rng({seed}), "
            "or set the seed in the settings (SimulationSettings(seed=...)) and leave rng out"
        )
    if settings.save_dir is not None:
        check_save_dir(settings.save_dir)
    simulator = Simulator(settings, rng)
    for _ in simulator.iter_frames(progress):
        pass
    result = simulator.result()
    if settings.save_dir is not None:
        from napari_symbac.sim.io import save_simulation

        save_simulation(result, settings.save_dir)
    return result
