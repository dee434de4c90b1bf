"""Records of a simulation: per-frame cell states, lineage and the whole run.

These are plain frozen dataclasses of numpy arrays and numbers, with no pymunk
objects in them, so a finished :class:`Simulation` costs only its arrays
(supplement section 2: "at every time-point, each cell's location and dimensions
are kept track of and recorded", section 3).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from napari_symbac.settings import SimulationSettings

__all__ = [
    "CellTrace",
    "Fate",
    "FrameCells",
    "LineageRecord",
    "Simulation",
    "spherocylinder_length_um",
    "spherocylinder_volume_um3",
]

Fate = Literal["divided", "lysed", "exited", "alive"]
FATES: tuple[Fate, ...] = ("divided", "lysed", "exited", "alive")

_FIELDS = ("ids", "x_um", "y_um", "angle_rad", "length_um", "width_um")


def spherocylinder_volume_um3(length_um: float | np.ndarray, width_um: float | np.ndarray):
    """Volume of a spherocylinder of pole-to-pole ``length_um`` and ``width_um``.

    ``V = pi r^2 L - (2/3) pi r^3`` with ``r = width / 2`` (a cylinder of length
    ``L - 2r`` plus two hemispherical caps).
    """
    r = np.asarray(width_um, dtype=float) / 2
    volume = math.pi * r**2 * np.asarray(length_um, dtype=float) - 2 / 3 * math.pi * r**3
    return float(volume) if np.ndim(volume) == 0 else volume


def spherocylinder_length_um(volume_um3: float, width_um: float) -> float:
    """Pole-to-pole length of a spherocylinder of given volume and width (inverse of
    :func:`spherocylinder_volume_um3`)."""
    r = width_um / 2
    return (volume_um3 + 2 / 3 * math.pi * r**3) / (math.pi * r**2)


@dataclass(frozen=True, eq=False)
class FrameCells:
    """The cells present in one frame, as equal-length 1-D arrays (one entry per cell).

    Coordinates
    -----------
    ``"trench"`` / ``"chamber"``: ``x_um`` runs across the trench from its left wall,
    ``y_um`` along it from the closed end, which is at the top of the image (row 0),
    so ``y_um`` grows down the image rows. ``"agar_pad"``: from the top-left corner of
    the field. ``"outline"``: the walls' own coordinates (y down the image rows).

    ``angle_rad`` is the angle of the long axis from the trench axis (the +y
    direction, down the image rows): the unit vector from the centre to one pole is
    ``(sin(angle), cos(angle))`` in ``(x, y)``. Zero is a cell lying along the trench;
    a positive angle tilts the lower pole to the right.

    Attributes
    ----------
    ids
        int64 cell ids, unique over the whole run, starting at 1 (0 is background).
    x_um, y_um
        Centre of each cell.
    angle_rad
        Orientation of the long axis, see above.
    length_um
        Pole-to-pole length, caps included.
    width_um
        Diameter of the cell.
    """

    ids: np.ndarray
    x_um: np.ndarray
    y_um: np.ndarray
    angle_rad: np.ndarray
    length_um: np.ndarray
    width_um: np.ndarray

    def __post_init__(self) -> None:
        # views, so that making them read-only never touches the caller's arrays
        ids = np.asarray(self.ids, dtype=np.int64).reshape(-1).view()
        object.__setattr__(self, "ids", ids)
        for name in _FIELDS[1:]:
            value = np.asarray(getattr(self, name), dtype=np.float64).reshape(-1).view()
            if value.shape != ids.shape:
                raise ValueError(
                    f"FrameCells.{name} has {value.size} entries but ids has {ids.size}: "
                    "every array needs one entry per cell"
                )
            object.__setattr__(self, name, value)
        for name in _FIELDS:
            getattr(self, name).flags.writeable = False

    def __len__(self) -> int:
        return int(self.ids.size)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, FrameCells):
            return NotImplemented
        return all(np.array_equal(getattr(self, n), getattr(other, n)) for n in _FIELDS)

    __hash__ = None  # type: ignore[assignment]

    @classmethod
    def empty(cls) -> FrameCells:
        """A frame without cells."""
        return cls(*(np.zeros(0) for _ in _FIELDS))

    @property
    def volume_um3(self) -> np.ndarray:
        """Volume of each cell (spherocylinder)."""
        return spherocylinder_volume_um3(self.length_um, self.width_um)

    def poles_um(self) -> tuple[np.ndarray, np.ndarray]:
        """Centres of the two end caps, ``((n, 2), (n, 2))`` arrays of ``(x, y)``."""
        half = (self.length_um - self.width_um) / 2
        d = np.stack([np.sin(self.angle_rad), np.cos(self.angle_rad)], axis=1) * half[:, None]
        centre = np.stack([self.x_um, self.y_um], axis=1)
        return centre - d, centre + d


@dataclass(frozen=True)
class LineageRecord:
    """Life of one cell: ground truth for tracking and lineage analysis.

    Attributes
    ----------
    cell_id
        The cell's id (as in :attr:`FrameCells.ids`).
    parent_id
        The mother's id; 0 for founder cells.
    birth_frame
        First frame in which the cell is present.
    end_frame
        Last frame in which the cell is present (a dividing cell's daughters appear
        in ``end_frame + 1``); ``n_frames - 1`` for cells still alive at the end. A
        daughter that left the trench (or field) in the frame of its birth is in no
        frame: ``end_frame = birth_frame - 1``, fate ``"exited"`` (its sister is then
        its mother's only daughter in the exported tracks).
    fate
        ``"divided"``, ``"lysed"``, ``"exited"`` (left the trench / field) or ``"alive"``.
    curvature
        ``(a_um, b, c)`` of eq. 1, drawn once at birth when ``do_transformation`` is
        set (zeros otherwise), so a cell keeps its shape over its life.
    """

    cell_id: int
    parent_id: int
    birth_frame: int
    end_frame: int
    fate: Fate
    curvature: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def division_frame(self) -> int | None:
        """Frame in which the cell's daughters first appear, or ``None``."""
        return self.end_frame + 1 if self.fate == "divided" else None


@dataclass(frozen=True, eq=False)
class CellTrace:
    """Per-frame state of one cell over its life (a sawtooth trace in a lineage)."""

    cell_id: int
    frames: np.ndarray
    x_um: np.ndarray
    y_um: np.ndarray
    angle_rad: np.ndarray
    length_um: np.ndarray
    width_um: np.ndarray


@dataclass(frozen=True, eq=False)
class Simulation:
    """A finished run: its settings, the cells of every frame and every cell's lineage.

    Attributes
    ----------
    settings
        The settings that produced the run.
    frames
        One :class:`FrameCells` per frame (``len(frames) == settings.n_frames``).
    lineage
        :class:`LineageRecord` of every cell that ever lived, keyed by id.
    walls_um
        Static walls of the geometry as ``(k, 2)`` arrays of ``(x, y)`` polyline
        vertices in the frame's coordinates (empty for an agar pad).
    """

    settings: SimulationSettings
    frames: list[FrameCells]
    lineage: dict[int, LineageRecord]
    walls_um: tuple[np.ndarray, ...] = field(default=())

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Simulation):
            return NotImplemented
        return (
            self.settings == other.settings
            and self.frames == other.frames
            and self.lineage == other.lineage
            and len(self.walls_um) == len(other.walls_um)
            and all(np.array_equal(a, b) for a, b in zip(self.walls_um, other.walls_um))
        )

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        """A line, not every frame's arrays (found as an API user: 135 KB for 200 frames
        at the end of a notebook cell)."""
        cells = sum(len(frame.ids) for frame in self.frames[-1:])
        return (
            f"Simulation({self.settings.geometry}, {len(self.frames)} frames, "
            f"{len(self.lineage)} cells over the run, {cells} in the last frame, "
            f"seed {self.settings.seed})"
        )

    def trace(self, cell_id: int) -> CellTrace:
        """Per-frame position, length and width of one cell over its life.

        Raises
        ------
        KeyError
            If no cell has that id.
        """
        record = self.lineage[cell_id]
        rows: list[tuple[int, int]] = []
        for t in range(record.birth_frame, min(record.end_frame, len(self.frames) - 1) + 1):
            where = np.flatnonzero(self.frames[t].ids == cell_id)
            if where.size:
                rows.append((t, int(where[0])))
        columns = {
            name: np.array([getattr(self.frames[t], name)[i] for t, i in rows])
            for name in _FIELDS[1:]
        }
        return CellTrace(cell_id, np.array([t for t, _ in rows], dtype=np.int64), **columns)

    def children(self, cell_id: int) -> list[int]:
        """Ids of the daughters of ``cell_id`` (empty unless it divided)."""
        return [c for c, r in self.lineage.items() if r.parent_id == cell_id]

    def cell_counts(self) -> np.ndarray:
        """Number of cells in each frame."""
        return np.array([len(f) for f in self.frames], dtype=np.int64)
