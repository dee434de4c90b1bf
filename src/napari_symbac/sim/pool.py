"""Bodies of removed cells kept for new ones, so that removing a cell from a big colony
does not scan every contact.

``cpSpaceRemoveShape`` (and ``cpSpaceRemoveBody``) walk all of the space's cached
contacts to drop the removed shape's, so each division, exit or lysis cost time in
proportion to the colony: 3-9 % of a 4400-cell colony's time (docs/simulation.md).
Once the space holds :data:`PARK_MIN_CELLS` cells, a removed cell's body and shape
are instead *parked*: moved far out of the field, alone, and left at rest. Chipmunk
forgets their contacts by itself after ``collision_persistence`` steps; from then on
the pair is handed out again for a new cell (a daughter, say), reshaped and placed,
with no contact history, as a new body would be.
"""

from __future__ import annotations

from collections import deque

import pymunk
from pymunk._chipmunk_cffi import lib as _chipmunk

__all__ = ["PARK_MIN_CELLS", "BodyPool"]

#: Cells in the space from which removed bodies are parked and reused; smaller runs
#: add and remove bodies as before (and stay bit-identical to earlier versions).
PARK_MIN_CELLS = 1000
#: Where parked bodies wait (world units: 10 cm away), each at its own spot along a
#: line, 10 um apart (farther than any cell is long).
PARK_AT = -1.0e7
PARK_SPACING = 1.0e3
PARK_SPOTS = 100_000


class BodyPool:
    """Hands out pymunk bodies for new cells and takes back those of removed ones.

    Parameters
    ----------
    space
        The space all cells' bodies live in.
    """

    def __init__(self, space: pymunk.Space) -> None:
        self._space = space
        self._alive = 0
        self._parked: deque[tuple[pymunk.Body, pymunk.Poly, int]] = deque()
        self._spot = 0
        self._steps = 0  # physics steps seen (pickled with the pool, unlike Chipmunk's)

    def __len__(self) -> int:
        """Parked bodies."""
        return len(self._parked)

    def tick(self) -> None:
        """Count one physics step of the space (call after each ``space.step``)."""
        self._steps += 1

    def take(
        self,
        vertices: list[tuple[float, float]],
        radius: float,
        mass: float,
        moment: float,
        position: tuple[float, float],
        angle: float,
    ) -> tuple[pymunk.Body, pymunk.Poly]:
        """A body (with its rounded-polygon shape) in the space, of the given shape,
        mass and moment of inertia, at ``position`` and ``angle`` (world units),
        at rest: a parked one whose contacts Chipmunk has forgotten (parked more than
        ``collision_persistence + 1`` :meth:`tick` s ago), else a new one."""
        self._alive += 1
        forgotten = self._steps - self._space.collision_persistence - 1
        if self._parked and self._parked[0][2] < forgotten:
            body, shape, _ = self._parked.popleft()
            _chipmunk.cpPolyShapeSetVertsRaw(shape._shape, len(vertices), vertices)
            shape.unsafe_set_radius(radius)
            body.mass, body.moment = mass, moment
            body.position = position
            body.angle = angle
            return body, shape
        body = pymunk.Body(1.0, 1.0)
        body.mass, body.moment = mass, moment
        body.position = position
        body.angle = angle
        shape = pymunk.Poly(body, vertices, radius=radius)
        shape.elasticity = 0.0
        shape.friction = 0.0
        self._space.add(body, shape)
        return body, shape

    def give_back(self, body: pymunk.Body, shape: pymunk.Poly) -> None:
        """Take a removed cell's body out of play: park it (big colonies) or remove it
        from the space."""
        if self._alive < PARK_MIN_CELLS:
            self._space.remove(body, shape)
        else:
            self._spot = (self._spot + 1) % PARK_SPOTS
            body.position = (PARK_AT, PARK_AT - PARK_SPACING * self._spot)
            body.velocity = (0.0, 0.0)
            body.angular_velocity = 0.0
            self._parked.append((body, shape, self._steps))
        self._alive -= 1
