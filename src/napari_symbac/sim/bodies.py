"""Read and write the state of all cells' bodies in one call each.

Going through ``pymunk.Body`` properties costs about 0.5 us of Python per body and
value, which at thousands of cells and 15 physics iterations a frame was a large part
of a colony's cost. :mod:`pymunk.batch` copies the positions and angles of every body
of a space into one buffer (and velocities back) in C; :class:`BodyTable` maps the
space's order of bodies to the simulator's order of cells.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pymunk
import pymunk.batch as batch
from pymunk._chipmunk_cffi import lib as _chipmunk

__all__ = ["BodyTable", "reshape_body"]

_POSE = batch.BodyFields.POSITION | batch.BodyFields.ANGLE
_MOTION = batch.BodyFields.VELOCITY | batch.BodyFields.ANGULAR_VELOCITY


class BodyTable:
    """The bodies of a space as rows of arrays, in the order of ``bodies``.

    Valid while no body is added to or removed from the space (pymunk's order of
    bodies changes then); build a new table after.

    Parameters
    ----------
    space
        The space holding the bodies.
    bodies
        The bodies to address, in the order the arrays should have; any other body of
        the space (e.g. its static body) keeps its velocity.
    """

    def __init__(self, space: pymunk.Space, bodies: Sequence[pymunk.Body]) -> None:
        self._space = space
        found = batch.Buffer()
        batch.get_space_bodies(space, batch.BodyFields.BODY_ID | _MOTION, found)
        ids = np.frombuffer(found.int_buf(), dtype=np.uintp).tolist()
        row_of = {body_id: row for row, body_id in enumerate(ids)}
        self._rows = np.array([row_of[body.id] for body in bodies], dtype=np.intp)
        # velocity and angular velocity of every body of the space, in its order
        self._motion = np.frombuffer(found.float_buf(), dtype=float).reshape(len(ids), 3).copy()
        self._motion_buffer = batch.Buffer()
        self._motion_buffer.set_float_buf(self._motion.reshape(-1))
        self._pose_buffer = batch.Buffer()

    def poses(self) -> tuple[np.ndarray, np.ndarray]:
        """``(position, angle)``: ``(n, 2)`` positions in world units and ``(n,)`` body
        angles (pymunk's, radians), in the order of ``bodies``."""
        self._pose_buffer.clear()
        batch.get_space_bodies(self._space, _POSE, self._pose_buffer)
        pose = np.frombuffer(self._pose_buffer.float_buf(), dtype=float).reshape(-1, 3)
        pose = pose[self._rows]
        return pose[:, :2], pose[:, 2]

    def set_motion(self, velocity: np.ndarray, angular_velocity: np.ndarray | float) -> None:
        """Set every body's velocity (``(n, 2)``, world units per time) and angular
        velocity (``(n,)`` or one value)."""
        self._motion[self._rows, :2] = velocity
        self._motion[self._rows, 2] = angular_velocity
        batch.set_space_bodies(self._space, _MOTION, self._motion_buffer)


def reshape_body(
    body: pymunk.Body,
    shape: pymunk.Poly,
    vertices: Sequence[tuple[float, float]],
    mass: float,
    moment: float,
) -> None:
    """Give ``shape`` new ``vertices`` (body coordinates, used as given) and its
    dynamic ``body`` a new ``mass`` and ``moment`` of inertia (both > 0).

    The same Chipmunk calls as ``Poly.unsafe_set_vertices`` and the ``Body.mass`` and
    ``Body.moment`` setters, without their Python layers: every growing cell is
    reshaped in every physics iteration, and those layers cost more than the calls.
    """
    _chipmunk.cpPolyShapeSetVertsRaw(shape._shape, len(vertices), vertices)
    _chipmunk.cpBodySetMass(body._body, mass)
    _chipmunk.cpBodySetMoment(body._body, moment)
