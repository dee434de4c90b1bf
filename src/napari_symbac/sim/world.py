"""The physics world of a run: every cell's pymunk body in one space, or, for a big
colony, in spatial tiles of one space each.

Chipmunk's contact solver sweeps all of a space's contacts ``SOLVER_ITERATIONS``
times per step. Above ~1000 cells those contacts no longer fit the core's cache and
every sweep waits on memory: the cost per cell and step grew 2-3x from 500 to 5000
cells. Past :data:`TILE_MIN_CELLS` cells the world is therefore cut into square tiles
of :data:`TILE_UM`, each its own space (a few hundred cells, whose contacts stay in
cache). A cell's body lives in the space of the tile holding its centre; a cell within
reach of another tile is also present there as a *ghost*: a kinematic copy that
follows its owner (moved to the owner's pose plus its set velocity in each physics
iteration) and pushes that tile's cells, but is not pushed back. Each tile thus
resolves its own cells' contacts with their neighbours across the seam, and the
neighbours do the same on their side.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pymunk

from napari_symbac.sim.bodies import BodyTable, set_vertices
from napari_symbac.sim.contacts import capsule_axes, neighbour_gaps
from napari_symbac.sim.geometry import Layout

__all__ = ["TILE_MIN_CELLS", "TILE_UM", "World"]

#: Physics world units per micrometre. Chipmunk's tolerances are absolute, so a
#: fine scale keeps them far below a micrometre.
SCALE = 100.0
#: Overlap tolerated between touching shapes (um); smaller costs more iterations.
COLLISION_SLOP_UM = 0.002
#: Fraction of an overlap left after one physics iteration (Chipmunk's collision bias
#: at ``dt = 1``): each iteration corrects 70 % of what remains.
COLLISION_BIAS = 0.3
#: Constraint-solver iterations within one physics iteration.
SOLVER_ITERATIONS = 20
#: A world switches to tiles when it holds this many cells (and stays tiled).
TILE_MIN_CELLS = 1000
#: Side of a tile (um): about 250 cells of a dense colony.
TILE_UM = 25.0
#: Extra reach (um) for which a cell gets a ghost in a neighbouring tile: covers a
#: frame's motion relative to the neighbours.
GHOST_MARGIN_UM = 0.5

_CELL = 0b001
_GHOST = 0b010
_WALL = 0b100
#: Ghosts touch only the cells of their tile (not walls, not other ghosts).
_GHOST_FILTER = pymunk.ShapeFilter(categories=_GHOST, mask=_CELL)
_WALL_FILTER = pymunk.ShapeFilter(categories=_WALL)
#: Where unused ghosts wait (world units): far from any field.
_PARK_UNITS = 1e7

Key = tuple[int, int]


def _make_space(layout: Layout, wall_filter: pymunk.ShapeFilter | None) -> pymunk.Space:
    space = pymunk.Space()
    space.iterations = SOLVER_ITERATIONS
    space.collision_slop = COLLISION_SLOP_UM * SCALE
    space.collision_bias = COLLISION_BIAS
    space.damping = 0.0
    for x0, y0, x1, y1, radius in layout.segments_um:
        wall = pymunk.Segment(
            space.static_body, (x0 * SCALE, y0 * SCALE), (x1 * SCALE, y1 * SCALE), radius * SCALE
        )
        wall.elasticity = 0.0
        wall.friction = 0.0
        if wall_filter is not None:
            wall.filter = wall_filter
        space.add(wall)
    return space


class _Tile:
    """One tile's space, the cells it owns and the ghosts it holds (internal)."""

    def __init__(self, space: pymunk.Space) -> None:
        self.space = space
        # rebuilt by World.prepare for one frame
        self.owned = np.empty(0, dtype=np.intp)  # indices into the frame's cells
        self.sources = np.empty(0, dtype=np.intp)  # owner index of each ghost
        self.table: BodyTable | None = None
        self.ghost_pos = np.empty((0, 2))
        self.ghost_angle = np.empty(0)
        self.parked: list[tuple[pymunk.Body, pymunk.Poly]] = []  # ghosts for reuse


class World:
    """The bodies of a run's living cells, stepped together.

    Below :data:`TILE_MIN_CELLS` cells this is one pymunk space, as it always was
    (runs stay bit-identical); from then on, square tiles with ghosts (module
    docstring). Cells are addressed by their id; once per frame :meth:`prepare`
    fixes the order in which :meth:`poses` and :meth:`set_motion` see them.

    Parameters
    ----------
    layout
        The geometry: its walls go into every space.
    """

    def __init__(self, layout: Layout) -> None:
        self._layout = layout
        self.space = _make_space(layout, None)
        self._tiles: dict[Key, _Tile] | None = None
        self._owner: dict[int, Key] = {}  # cell id -> tile (tiled only)
        self._ghosts: dict[int, dict[Key, tuple[pymunk.Body, pymunk.Poly]]] = {}
        #: this frame: cell id -> its ghosts' Chipmunk shapes (for reshaping)
        self.ghost_shapes: dict[int, list] = {}
        self._table: BodyTable | None = None  # one space: this frame's table
        self._n = 0

    @property
    def tiled(self) -> bool:
        """Whether the cells are split into tiles."""
        return self._tiles is not None

    @property
    def n_tiles(self) -> int:
        """Number of spaces with cells in them (1 before tiling)."""
        if self._tiles is None:
            return 1
        return sum(1 for key in self._tiles if key in set(self._owner.values()))

    # ---------------------------------------------------------------- membership
    def add(self, cell_id: int, body: pymunk.Body, shape: pymunk.Poly) -> None:
        """Put a new cell's body (with its shape) into the world."""
        if self._tiles is None:
            self.space.add(body, shape)
            return
        key = _key_of(body.position)
        self._tile(key).space.add(body, shape)
        self._owner[cell_id] = key

    def remove(self, cell_id: int, body: pymunk.Body, shape: pymunk.Poly) -> None:
        """Take a cell's body and shape (and its ghosts) out of the world."""
        if self._tiles is None:
            self.space.remove(body, shape)
            return
        self._tiles[self._owner.pop(cell_id)].space.remove(body, shape)
        for key, ghost in self._ghosts.pop(cell_id, {}).items():
            self._park(key, ghost)

    def _tile(self, key: Key) -> _Tile:
        tile = self._tiles.get(key)
        if tile is None:
            tile = self._tiles[key] = _Tile(_make_space(self._layout, _WALL_FILTER))
        return tile

    # ---------------------------------------------------------------- one frame
    def prepare(
        self,
        ids: Sequence[int],
        bodies: Sequence[pymunk.Body],
        shapes: Sequence[pymunk.Poly],
        length_um: np.ndarray,
        width_um: np.ndarray,
    ) -> None:
        """Fix the order of the cells for this frame's physics iterations.

        Tiles the world when it reaches :data:`TILE_MIN_CELLS` cells; once tiled,
        moves each body whose centre has changed tile to its new tile's space and
        creates or removes ghosts so that every cell within reach of another tile's
        cells (its length at the end of the frame, ``length_um``) has one there.
        """
        self._n = len(bodies)
        if self._tiles is None and self._n >= TILE_MIN_CELLS:
            self._split(ids, bodies, shapes)
        if self._tiles is None:
            self._table = BodyTable(self.space, bodies)
            return
        pos, body_angle = self.poses_of(ids, bodies)
        pos = pos / SCALE
        keys = np.floor(pos / TILE_UM).astype(np.int64)
        owners: list[Key] = []
        for cell_id, body, shape, key in zip(ids, bodies, shapes, map(tuple, keys.tolist())):
            old = self._owner[cell_id]
            if old != key:  # crossed into another tile
                self._tiles[old].space.remove(body, shape)
                ghost = self._ghosts.get(cell_id, {}).pop(key, None)
                if ghost is not None:
                    self._park(key, ghost)
                self._tile(key).space.add(body, shape)
                self._owner[cell_id] = key
            owners.append(key)
        self._update_ghosts(
            ids, bodies, shapes, pos, -body_angle, keys, owners, length_um, width_um
        )
        self.ghost_shapes = {
            cell_id: [shape._shape for _, shape in where.values()]
            for cell_id, where in self._ghosts.items()
        }
        owned: dict[Key, list[int]] = {}
        for i, key in enumerate(owners):
            owned.setdefault(key, []).append(i)
        index = {cell_id: i for i, cell_id in enumerate(ids)}
        ghosts_in: dict[Key, list[tuple[int, pymunk.Body]]] = {}
        for cell_id, where in self._ghosts.items():
            for key, (ghost, _) in where.items():
                ghosts_in.setdefault(key, []).append((index[cell_id], ghost))
        for key in sorted(self._tiles):
            tile = self._tiles[key]
            members = owned.get(key, [])
            tile.owned = np.array(members, dtype=np.intp)
            ghosts = ghosts_in.get(key, [])
            tile.sources = np.array([i for i, _ in ghosts], dtype=np.intp)
            tile.table = (
                BodyTable(tile.space, [bodies[i] for i in members] + [g for _, g in ghosts])
                if members
                else None
            )

    def _split(
        self, ids: Sequence[int], bodies: Sequence[pymunk.Body], shapes: Sequence[pymunk.Poly]
    ) -> None:
        """Move every body from the one space into tiles (once)."""
        for body, shape in zip(bodies, shapes):
            self.space.remove(body, shape)
        self.space = None
        self._tiles = {}
        for cell_id, body, shape in zip(ids, bodies, shapes):
            self.add(cell_id, body, shape)

    def _update_ghosts(
        self,
        ids: Sequence[int],
        bodies: Sequence[pymunk.Body],
        shapes: Sequence[pymunk.Poly],
        pos: np.ndarray,
        angle: np.ndarray,
        keys: np.ndarray,
        owners: list[Key],
        length_um: np.ndarray,
        width_um: np.ndarray,
    ) -> None:
        """Give each cell a ghost in every other tile that owns a cell closer to it
        than :data:`GHOST_MARGIN_UM` (capsule to capsule), and only there."""
        axes = capsule_axes(angle, length_um, width_um)
        pairs, gap = neighbour_gaps(pos, axes, width_um, GHOST_MARGIN_UM)
        i, j = pairs[:, 0], pairs[:, 1]
        near = pairs[(gap < GHOST_MARGIN_UM) & (keys[i] != keys[j]).any(axis=1)]
        wanted: dict[int, set[Key]] = {}
        for a, b in near.tolist():
            wanted.setdefault(a, set()).add(owners[b])
            wanted.setdefault(b, set()).add(owners[a])
        index = {cell_id: i for i, cell_id in enumerate(ids)}
        for cell_id in list(self._ghosts):
            i = index.get(cell_id)
            keep = wanted.get(i, set()) if i is not None else set()
            where = self._ghosts[cell_id]
            for key in [k for k in where if k not in keep]:
                self._park(key, where.pop(key))
            if not where:
                del self._ghosts[cell_id]
        for i in sorted(wanted):
            where = self._ghosts.setdefault(ids[i], {})
            for key in sorted(wanted[i]):
                if key not in where:
                    where[key] = self._new_ghost(bodies[i], shapes[i], key)

    def _new_ghost(self, body: pymunk.Body, shape: pymunk.Poly, key: Key):
        """A ghost of ``body`` in tile ``key``: a parked one of that tile, else a new one.

        Parking instead of removing saves ``cpSpaceRemoveShape``, which scans all of
        the space's cached contacts, and pymunk's object creation.
        """
        tile = self._tiles[key]
        vertices = [tuple(v) for v in shape.get_vertices()]
        if tile.parked:
            ghost, ghost_shape = tile.parked.pop()
            set_vertices(ghost_shape._shape, vertices)
            ghost_shape.unsafe_set_radius(shape.radius)
        else:
            ghost = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
            ghost_shape = pymunk.Poly(ghost, vertices, radius=shape.radius)
            ghost_shape.elasticity = 0.0
            ghost_shape.friction = 0.0
            ghost_shape.filter = _GHOST_FILTER
            tile.space.add(ghost, ghost_shape)
        ghost.position = body.position
        ghost.angle = body.angle
        return ghost, ghost_shape

    def _park(self, key: Key, ghost: tuple[pymunk.Body, pymunk.Poly]) -> None:
        """Move an unneeded ghost far out of the colony, alone, for reuse."""
        parked = self._tiles[key].parked
        ghost[0].position = (-_PARK_UNITS, -_PARK_UNITS - 10.0 * SCALE * len(parked))
        parked.append(ghost)

    # ---------------------------------------------------------------- shapes
    def set_radius(self, cell_id: int, shape: pymunk.Poly, radius: float) -> None:
        """Set the rounding radius of a cell's shape and of its ghosts."""
        shape.unsafe_set_radius(radius)
        for _, ghost_shape in self._ghosts.get(cell_id, {}).values():
            ghost_shape.unsafe_set_radius(radius)

    # ---------------------------------------------------------------- iterations
    def poses(self) -> tuple[np.ndarray, np.ndarray]:
        """Positions ``(n, 2)`` (world units) and body angles ``(n,)`` of the cells,
        in the order given to :meth:`prepare`."""
        if self._tiles is None:
            return self._table.poses()
        pos = np.empty((self._n, 2))
        angle = np.empty(self._n)
        for tile in self._active():
            p, a = tile.table.poses()
            k = len(tile.owned)
            pos[tile.owned], angle[tile.owned] = p[:k], a[:k]
            tile.ghost_pos, tile.ghost_angle = p[k:], a[k:]
        self._pos, self._angle = pos, angle
        return pos, angle

    def set_motion(self, velocity: np.ndarray, spin: np.ndarray | float) -> None:
        """Set the cells' velocities (``(n, 2)``, world units per step) and angular
        velocities; each ghost gets the velocity that takes it, in the next step, to
        its owner's pose (read by the last :meth:`poses`) moved by the owner's."""
        if self._tiles is None:
            self._table.set_motion(velocity, spin)
            return
        spin = np.broadcast_to(np.asarray(spin, dtype=float), (self._n,))
        for tile in self._active():
            src = tile.sources
            v = np.concatenate(
                [velocity[tile.owned], self._pos[src] + velocity[src] - tile.ghost_pos]
            )
            w = np.concatenate(
                [spin[tile.owned], self._angle[src] + spin[src] - tile.ghost_angle]
            )
            tile.table.set_motion(v, w)

    def stop(self) -> None:
        """Zero every velocity (between frames nothing moves)."""
        if self._tiles is None:
            self._table.set_motion(np.zeros((self._n, 2)), 0.0)
            self._table = None
            return
        for tile in self._active():
            n = len(tile.owned) + len(tile.sources)
            tile.table.set_motion(np.zeros((n, 2)), 0.0)
        self._drop_tables()

    def step(self) -> None:
        """One physics iteration (a pymunk step of ``dt = 1``) of every space."""
        if self._tiles is None:
            self.space.step(1.0)
            return
        for tile in self._active():
            tile.space.step(1.0)

    def _active(self) -> list[_Tile]:
        return [self._tiles[key] for key in sorted(self._tiles) if self._tiles[key].table]

    def _drop_tables(self) -> None:
        # pymunk.batch buffers cannot be pickled: tables live for one frame only
        for tile in self._tiles.values():
            tile.table = None
        self._pos = self._angle = None

    # ---------------------------------------------------------------- outside frames
    def poses_of(
        self, ids: Sequence[int], bodies: Sequence[pymunk.Body]
    ) -> tuple[np.ndarray, np.ndarray]:
        """Positions and body angles of ``bodies`` (cells ``ids``) right now."""
        if self._tiles is None:
            return BodyTable(self.space, bodies).poses()
        pos = np.empty((len(bodies), 2))
        angle = np.empty(len(bodies))
        groups: dict[Key, list[int]] = {}
        for i, cell_id in enumerate(ids):
            groups.setdefault(self._owner[cell_id], []).append(i)
        for key, rows in groups.items():
            p, a = BodyTable(self._tiles[key].space, [bodies[i] for i in rows]).poses()
            pos[rows], angle[rows] = p, a
        return pos, angle

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_table"] = None
        state["ghost_shapes"] = {}
        state.pop("_pos", None)
        state.pop("_angle", None)
        return state


def _key_of(position: pymunk.Vec2d) -> Key:
    return (
        math.floor(position.x / SCALE / TILE_UM),
        math.floor(position.y / SCALE / TILE_UM),
    )

