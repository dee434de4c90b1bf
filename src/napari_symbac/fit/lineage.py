"""Cell identity across the frames of a fitted series: links, divisions, lineage.

The fitted cells of consecutive frames are linked by one linear assignment per
pair of frames (:func:`scipy.optimize.linear_sum_assignment`) on a cost that
compares each cell of frame ``t + 1`` with the cell of frame ``t`` *as predicted
one frame later*:

* growth: a rod elongates along its axis, ``L -> g L`` with one growth factor
  ``g`` per frame for the series (measured from the links when not given);
* motion: in a mother-machine trench every cell is pushed towards the open end by
  the growth of the cells between it and the closed end (plus half its own), with
  the trench's own fitted placement per frame taking up any drift of the stage; in
  an open field a cell grows about its centre and the whole field drifts by one
  shift per frame (the median displacement of the linked cells).

The cost of a link is a sum of squared standardised differences (centre, length,
width, axis angle) with the scatter in micrometres and radians of
:class:`LinkSettings`; a link farther than ``gate_um`` from its prediction is not
allowed. A cell may also end (pushed out of the trench's open end or out of the
field: free; elsewhere at ``unlinked_cost``) or appear (at ``unlinked_cost``).

A division is a mother in frame ``t`` and two daughters in ``t + 1`` lying end to
end along her predicted axis, whose lengths add up to her grown length plus a
third of her width (two half-caps of volume: volume is conserved when a
spherocylinder splits into two of the same width). After the assignment, each
mother whose division explains her and her daughters at a lower cost than the
assignment did becomes the parent of two new tracks.

A cell missed in one frame (or fitted merged with a neighbour there) keeps its
track: the tracks that end in frame ``t - 1`` and the cells that start one in
``t + 1`` are linked over the gap (or as a division over it) when the prediction
two frames ahead matches (:attr:`LinkSettings.close_gaps`).

The result, :class:`Lineage`, is the Cell Tracking Challenge's: a track id per
cell and frame, and one ``L B E P`` row per track (track id, first frame, last
frame, parent track id or 0), the format of ``man_track.txt`` that the export
writes (:class:`~napari_symbac.export.tracking.CtcWriter`); a track with a gap is
written as the CTC does, one CTC track per stretch, each the parent of the next
(:meth:`Lineage.ctc_labels`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from napari_symbac.fit.placement import TrenchPlacement
from napari_symbac.sim import FrameCells

__all__ = ["Lineage", "LinkSettings", "link_cells"]

#: Stand-in for a forbidden link in the assignment's cost matrix.
_FORBIDDEN = 1e12


@dataclass(frozen=True)
class LinkSettings:
    """How cells are linked from frame to frame (:func:`link_cells`).

    Parameters
    ----------
    position_sd_um
        Scatter of a cell's centre about its prediction (fit error and the motion the
        prediction leaves out: jitter, pushing in a colony).
    length_sd_um
        Scatter of a cell's length about its grown length.
    width_sd_um
        Scatter of a cell's width between frames.
    angle_sd_rad
        Scatter of a cell's axis angle between frames (weighted down for cells close to
        round, whose axis is not defined).
    gate_um
        Largest distance of a linked cell's centre from its prediction (and of a
        daughter's from where the division puts her); farther links are not allowed.
    length_gate_um
        Largest difference between a linked cell's length and its grown length (and
        between the daughters' summed length and their mother's).
    unlinked_cost
        Cost of a track ending or starting inside the field of view, in the cost's
        units (squared standard deviations; a link of four terms each 2 s.d. off costs
        16). A track whose cell is predicted beyond the trench's open end or outside
        the field (or within ``exit_margin_um`` of that edge) ends at no cost.
    exit_margin_um
        How close to the edge of the field of view (the trench's open end) a predicted
        centre counts as leaving it: the push of the cells above is only predicted to
        within a few tenths of a micrometre, and the cell leaves when its centre does.
    max_drift_um
        Largest shift of an open field between two frames (stage drift). The first
        estimate of each frame's shift is the one that brings the most centres of the
        next frame within ``2 position_sd_um`` of a centre of this one (a vote over all
        pairs of cells closer than this), later ones the median shift of the links.
    growth_per_frame
        Length ratio ``L(t + 1) / L(t)`` of a growing cell; ``None``: measured as the
        median ratio of the linked cells (starting from 1).
    close_gaps
        Link over one missing frame: a track that ends in frame ``t - 1`` goes on
        with a cell that starts a track in ``t + 1`` (or divides into two of them)
        when the cell's prediction two frames ahead matches (scatter widened by
        ``sqrt 2``, same gates) at a cost below ``unlinked_cost``
        (the missing frame's price): a cell missed, or fitted merged with a neighbour,
        in one frame keeps its track.
    """

    position_sd_um: float = 0.25
    length_sd_um: float = 0.25
    width_sd_um: float = 0.1
    angle_sd_rad: float = 0.25
    gate_um: float = 1.5
    length_gate_um: float = 1.0
    unlinked_cost: float = 12.0
    exit_margin_um: float = 0.5
    max_drift_um: float = 3.0
    growth_per_frame: float | None = None
    close_gaps: bool = True

    def __post_init__(self) -> None:
        for name in (
            "position_sd_um",
            "length_sd_um",
            "width_sd_um",
            "angle_sd_rad",
            "gate_um",
            "length_gate_um",
            "unlinked_cost",
            "exit_margin_um",
            "max_drift_um",
        ):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"LinkSettings.{name} must be a positive number, got {value!r}")
        g = self.growth_per_frame
        if g is not None and not (isinstance(g, (int, float)) and math.isfinite(g) and g > 0):
            raise ValueError(
                f"LinkSettings.growth_per_frame must be a positive ratio or None, got {g!r}"
            )


@dataclass(frozen=True, eq=False)
class Lineage:
    """Identities and lineage of the cells of a series (:func:`link_cells`).

    Attributes
    ----------
    track_ids
        One int64 array per frame: the track id of each cell, in the order of that
        frame's :class:`~napari_symbac.sim.FrameCells`.
    tracks
        ``(K, 4)`` int64, one row per track: track id, first frame, last frame, parent
        track id (0: none), as the lines of the Cell Tracking Challenge's
        ``man_track.txt`` / ``res_track.txt``. A division ends the mother's track in
        frame ``t`` and starts each daughter's in ``t + 1``.
    growth_per_frame
        The length ratio used for the prediction (given or measured).
    drift_um
        ``(T - 1, 2)``: the ``(x, y)`` shift of the field between consecutive frames
        used for the prediction (zeros in a trench, whose placement is fitted per frame,
        and between frames that share no cell).
    link_costs
        One array per pair of frames: the cost of each accepted link of a cell of
        frame ``t + 1`` to its predecessor (NaN for a new track; the cost of the link
        over the gap for a cell whose track skipped frame ``t``).
    gaps
        ``(track, frame)`` of each frame that a track skips (:attr:`LinkSettings.close_gaps`):
        the track is in the frames before and after but not in this one.
    """

    track_ids: tuple[np.ndarray, ...]
    tracks: np.ndarray
    growth_per_frame: float
    drift_um: np.ndarray = field(repr=False)
    link_costs: tuple[np.ndarray, ...] = field(default=(), repr=False)
    gaps: tuple[tuple[int, int], ...] = ()

    def parent(self, track_id: int) -> int:
        """Parent track of ``track_id`` (0: none)."""
        row = np.flatnonzero(self.tracks[:, 0] == track_id)
        if row.size == 0:
            raise ValueError(f"no track {track_id}; the tracks are Lineage.tracks[:, 0]")
        return int(self.tracks[row[0], 3])

    def divisions(self) -> dict[int, tuple[int, ...]]:
        """``{mother track: daughter tracks}`` of every division."""
        out: dict[int, list[int]] = {}
        for track, _b, _e, parent in self.tracks.tolist():
            if parent:
                out.setdefault(parent, []).append(track)
        return {k: tuple(v) for k, v in out.items()}

    def table(self, frames: Sequence[int] | None = None) -> list[dict]:
        """The tracks as records (JSON): ``track``, ``first_frame``, ``last_frame``,
        ``parent``, ``missing_frames`` (the frames a track skips, see :attr:`gaps`).

        ``frames``: the recording's frame number of each frame of the series (default:
        0, 1, ...), used for every frame of the records.
        """
        number = (lambda k: int(k)) if frames is None else (lambda k: int(frames[k]))
        missing: dict[int, list[int]] = {}
        for track, t in self.gaps:
            missing.setdefault(track, []).append(number(t))
        return [
            {"track": t, "first_frame": number(b), "last_frame": number(e), "parent": p,
             "missing_frames": missing.get(t, [])}
            for t, b, e, p in self.tracks.tolist()
        ]  # fmt: skip

    def ctc_labels(self) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
        """The tracks as the Cell Tracking Challenge writes them.

        A CTC track is present in every frame from its first to its last, so a track
        that skips a frame (:attr:`gaps`) is written as one CTC track per stretch: the
        first keeps the track's id, each later one gets a new label (above every track
        id) whose parent is the stretch before it (the CTC's way of writing a gap), and
        daughters name the last stretch as their parent. Without gaps the labels are
        the track ids.

        Returns
        -------
        rows, labels
            ``(K, 4)`` int64 ``L B E P`` rows, and per frame the CTC label of each cell
            (same order as :attr:`track_ids`).
        """
        skipped: dict[int, list[int]] = {}
        for track, t in self.gaps:
            skipped.setdefault(track, []).append(t)
        next_label = int(self.tracks[:, 0].max(initial=0)) + 1
        stretches: dict[int, list[tuple[int, int, int]]] = {}  # track: (label, first, last)
        for track, first, last, _parent in self.tracks.tolist():
            bounds, begin = [], first
            for t in sorted(skipped.get(track, [])):
                bounds.append((begin, t - 1))
                begin = t + 1
            bounds.append((begin, last))
            labels = [track, *range(next_label, next_label + len(bounds) - 1)]
            next_label += len(bounds) - 1
            stretches[track] = [(k, b, e) for k, (b, e) in zip(labels, bounds)]
        rows = []
        for track, _first, _last, parent in self.tracks.tolist():
            before = stretches[parent][-1][0] if parent else 0
            for label, b, e in stretches[track]:
                rows.append((label, b, e, before))
                before = label
        per_frame = []
        for t, ids in enumerate(self.track_ids):
            per_frame.append(
                np.array(
                    [next(k for k, b, e in stretches[int(i)] if b <= t <= e) for i in ids],
                    np.int64,
                )
            )
        table = np.array(sorted(rows), np.int64).reshape(-1, 4)
        return table, tuple(per_frame)

    def ctc_text(self) -> str:
        """The tracks as ``res_track.txt``: one ``L B E P`` line per CTC track
        (:meth:`ctc_labels`)."""
        return "".join(f"{t} {b} {e} {p}\n" for t, b, e, p in self.ctc_labels()[0].tolist())

    def track_mask(self, t: int, labels: np.ndarray, cell_ids: np.ndarray) -> np.ndarray:
        """Frame ``t``'s instance mask relabelled from cell ids to CTC labels (uint16).

        ``labels`` holds ``cell_ids`` (e.g. ``SceneFit.scene.camera_labels()`` and
        ``SceneFit.cells.ids``); the result is a Cell Tracking Challenge ``mask{t}.tif``
        whose labels are those of :meth:`ctc_text` (the track ids, except for the
        stretches after a gap, :meth:`ctc_labels`).
        """
        cell_ids = np.asarray(cell_ids, np.int64)
        if cell_ids.shape != self.track_ids[t].shape:
            raise ValueError(
                f"frame {t} has {self.track_ids[t].size} tracked cells but {cell_ids.size} ids"
            )
        rows, ctc = self.ctc_labels()
        if rows.size and rows[:, 0].max() > np.iinfo(np.uint16).max:
            raise ValueError("more than 65535 tracks do not fit a uint16 mask")
        lookup = np.zeros(int(max(labels.max(initial=0), cell_ids.max(initial=0))) + 1, np.uint16)
        lookup[cell_ids] = ctc[t]
        return lookup[np.asarray(labels, np.int64)]

    def track_masks(
        self, labels: Sequence[np.ndarray], cell_ids: Sequence[np.ndarray]
    ) -> np.ndarray:
        """Every frame's instance mask relabelled from cell ids to track ids.

        Unlike :meth:`track_mask` (the CTC's labels), a track keeps its own id across
        a gap, so that a viewer colours a cell alike in every frame it is seen.

        Parameters
        ----------
        labels
            One mask per frame holding that frame's cell ids (e.g.
            ``SceneFit.scene.camera_labels()``), all of one shape.
        cell_ids
            Per frame the ids of the tracked cells (``SceneFit.cells.ids``), in the
            order of :attr:`track_ids`.

        Returns
        -------
        numpy.ndarray
            ``(T, Y, X)`` uint32, 0 outside the cells; a label in ``labels`` that is not
            among the frame's tracked cells is 0 too.
        """
        if len(labels) != len(self.track_ids) or len(cell_ids) != len(self.track_ids):
            raise ValueError(
                f"the lineage has {len(self.track_ids)} frames but {len(labels)} masks and "
                f"{len(cell_ids)} id lists were given"
            )
        out = []
        for t, (mask, ids) in enumerate(zip(labels, cell_ids)):
            ids = np.asarray(ids, np.int64)
            if ids.shape != self.track_ids[t].shape:
                raise ValueError(
                    f"frame {t} has {self.track_ids[t].size} tracked cells but {ids.size} ids"
                )
            mask = np.asarray(mask, np.int64)
            lookup = np.zeros(int(max(mask.max(initial=0), ids.max(initial=0))) + 1, np.uint32)
            lookup[ids] = self.track_ids[t]
            out.append(lookup[mask])
        return np.stack(out)

    def napari_tracks(self, masks: np.ndarray) -> tuple[np.ndarray, dict[int, list[int]]]:
        """The tracks as napari's Tracks layer takes them
        (:func:`~napari_symbac.track_points.napari_tracks`) from the ``(T, Y, X)``
        track-id ``masks`` of :meth:`track_masks`."""
        from napari_symbac.track_points import napari_tracks

        masks = np.asarray(masks)
        if masks.ndim != 3 or len(masks) != len(self.track_ids):
            raise ValueError(
                f"masks must be (T, Y, X) with T = {len(self.track_ids)} frames, "
                f"not of shape {masks.shape}"
            )
        parents = {d: m for m, daughters in self.divisions().items() for d in daughters}
        return napari_tracks(masks, parents)


def _axis(angle_rad: np.ndarray) -> np.ndarray:
    """Unit vectors ``(x, y)`` of the long axes (0 rad = along +y, the trench axis)."""
    return np.stack([np.sin(angle_rad), np.cos(angle_rad)], axis=-1)


def _angle_difference(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Difference of two axis angles, modulo pi (an axis has no direction)."""
    return (np.asarray(a) - np.asarray(b) + np.pi / 2) % np.pi - np.pi / 2


def _elongation(length_um: np.ndarray, width_um: np.ndarray) -> np.ndarray:
    """Weight of the angle term: 0 for a round cell (no axis), 1 from 2 widths long."""
    return np.clip((length_um - width_um) / np.maximum(width_um, 1e-9), 0.0, 1.0)


@dataclass(frozen=True)
class _Predicted:
    """Cells of frame ``t`` as expected in frame ``t + 1`` (image coordinates, um)."""

    centre: np.ndarray  # (n, 2) x, y
    length_um: np.ndarray
    width_um: np.ndarray
    angle_rad: np.ndarray
    leaving: np.ndarray  # bool: predicted out of the field of view (free to end)
    size_um: tuple[float, float]  # (height, width) of the field of view
    in_trench: bool
    margin_um: float  # a centre this close to the edge counts as leaving


def _predict(
    cells: FrameCells,
    growth: float,
    trench: tuple[TrenchPlacement, TrenchPlacement] | None,
    drift_um: np.ndarray,
    size_um: tuple[float, float],
    margin_um: float,
) -> _Predicted:
    """Where the cells of one frame should be one frame later.

    In a trench (``trench`` = placements in frames ``t`` and ``t + 1``), positions are
    taken relative to the trench, each cell moves along the trench by the growth of
    the cells nearer the closed end plus half its own (projected on the trench axis),
    and is placed back with the next frame's placement. In a field, each cell grows
    about its centre and the field moves by ``drift_um``.
    """
    centre = np.stack([cells.x_um, cells.y_um], axis=1).astype(float)
    grown = cells.length_um * growth
    if trench is not None:
        before, after = trench
        gain = (grown - cells.length_um) * np.abs(np.cos(cells.angle_rad))
        order = np.argsort(cells.y_um - before.top_um, kind="stable")
        pushed = np.empty(len(cells))
        pushed[order] = np.cumsum(gain[order]) - gain[order] / 2
        centre[:, 0] += after.left_um - before.left_um
        centre[:, 1] += after.top_um - before.top_um + pushed
    else:
        centre = centre + drift_um
    pred = _Predicted(
        centre, grown, cells.width_um.copy(), cells.angle_rad.copy(), np.zeros(0, bool),
        size_um, trench is not None, margin_um,
    )
    return dataclasses.replace(pred, leaving=_outside(pred, centre))


def _visible(
    centre: np.ndarray,
    angle_rad: np.ndarray,
    length_um: np.ndarray,
    width_um: np.ndarray,
    size_um: tuple[float, float],
) -> tuple[np.ndarray, np.ndarray]:
    """Centre and length of the part of each cell's axis inside the field of view.

    A cell that crosses the image's edge (pushed out of the trench's open end) is
    seen, and fitted, only in part: links compare the parts in view. The field is
    widened by half the cell's width (a cell lying along the edge, its axis just
    outside, is still in view).
    """
    u = _axis(angle_rad)
    low = -length_um / 2
    high = length_um / 2
    pad = width_um / 2
    for d, limit in ((0, size_um[1]), (1, size_um[0])):
        if not math.isfinite(limit):
            continue
        with np.errstate(divide="ignore", invalid="ignore"):
            a = (-pad - centre[:, d]) / u[:, d]
            b = (limit + pad - centre[:, d]) / u[:, d]
        flat = np.abs(u[:, d]) < 1e-9
        inside = (centre[:, d] >= -pad) & (centre[:, d] <= limit + pad)
        a = np.where(flat, np.where(inside, -np.inf, np.inf), a)
        b = np.where(flat, np.where(inside, np.inf, -np.inf), b)
        low = np.maximum(low, np.minimum(a, b))
        high = np.minimum(high, np.maximum(a, b))
    seen = np.maximum(high - low, 0.0)
    middle = np.where(seen > 0, (low + high) / 2, 0.0)
    return centre + u * middle[:, None], seen


def _link_costs(
    pred: _Predicted, nxt: FrameCells, s: LinkSettings, partial: np.ndarray
) -> np.ndarray:
    """``(n_t, n_t+1)`` costs of the one-to-one links (``inf``: outside the gates).

    Centres and lengths are those of the parts of the cells in the field of view.
    ``partial`` (``(n_t, n_t+1)`` bool) marks the pairs of which one cell is cut by the
    image's edge: its width and axis are those of the part in view (a cell lying along
    the edge shows a sliver of itself), so only centre and length are compared.
    """
    centre_p, length_p = _visible(
        pred.centre, pred.angle_rad, pred.length_um, pred.width_um, pred.size_um
    )
    centre_n, length_n = _visible(
        np.stack([nxt.x_um, nxt.y_um], axis=1),
        nxt.angle_rad,
        nxt.length_um,
        nxt.width_um,
        pred.size_um,
    )
    distance = np.linalg.norm(centre_p[:, None, :] - centre_n[None, :, :], axis=-1)
    d_length = length_n[None, :] - length_p[:, None]
    d_width = nxt.width_um[None, :] - pred.width_um[:, None]
    d_angle = _angle_difference(nxt.angle_rad[None, :], pred.angle_rad[:, None])
    weight = np.minimum(
        _elongation(length_p, pred.width_um)[:, None],
        _elongation(length_n, nxt.width_um)[None, :],
    )
    shape_terms = (d_width / s.width_sd_um) ** 2 + weight * (d_angle / s.angle_sd_rad) ** 2
    shape_terms = np.where(partial, 0.0, shape_terms)
    cost = (distance / s.position_sd_um) ** 2 + (d_length / s.length_sd_um) ** 2 + shape_terms
    cost[(distance > s.gate_um) | (np.abs(d_length) > s.length_gate_um)] = np.inf
    return cost


def _assign(cost: np.ndarray, end_cost: np.ndarray, start_cost: float) -> np.ndarray:
    """Best one-to-one links with ends and starts allowed: ``match[i]`` = j or -1.

    The square assignment of Jaqaman et al. (2008): ``[[links, ends], [starts,
    links^T]]``, where leaving cell ``i`` of frame ``t`` unlinked costs ``end_cost[i]``
    and leaving a cell of ``t + 1`` unlinked costs ``start_cost``.
    """
    n, m = cost.shape
    match = np.full(n, -1)
    if n == 0 or m == 0:
        return match
    big = np.where(np.isfinite(cost), cost, _FORBIDDEN)
    ends = np.full((n, n), _FORBIDDEN)
    ends[np.diag_indices(n)] = end_cost
    starts = np.full((m, m), _FORBIDDEN)
    starts[np.diag_indices(m)] = start_cost
    lower_right = np.where(np.isfinite(cost.T), 0.0, _FORBIDDEN)
    matrix = np.block([[big, ends], [starts, lower_right]])
    rows, cols = linear_sum_assignment(matrix)
    for i, j in zip(rows, cols):
        if i < n and j < m and np.isfinite(cost[i, j]):
            match[i] = j
    return match


def _outside(pred: _Predicted, points: np.ndarray) -> np.ndarray:
    """Points ``(k, 2)`` beyond the field of view (below the image in a trench), or
    within the exit margin of its edge."""
    height_um, width_um = pred.size_um
    m = pred.margin_um
    below = points[:, 1] > height_um - m
    if pred.in_trench:
        return below
    return below | (points[:, 0] < m) | (points[:, 0] > width_um - m) | (points[:, 1] < m)


def _division_cost(
    pred: _Predicted, k: int, nxt: FrameCells, daughters: tuple[int, ...], s: LinkSettings
) -> float:
    """Cost of mother ``k`` (predicted) splitting into ``daughters`` of frame ``t + 1``.

    The daughters lie end to end along the mother's axis, centred on her predicted
    centre, their lengths summing to her grown length plus a third of her width
    (volume conserved, same width); each is compared with where that puts her (along
    and across the axis), with the mother's width and axis angle. With one daughter,
    her sister is the rest of that length, and must lie beyond the field of view
    (pushed out of the trench or the field within the frame interval).
    """
    u = _axis(pred.angle_rad[k])
    c = pred.centre[k]
    expected = pred.length_um[k] + pred.width_um[k] / 3
    lengths = nxt.length_um[list(daughters)]
    centres = np.stack([nxt.x_um[list(daughters)], nxt.y_um[list(daughters)]], axis=1) - c
    along = centres @ u
    across = centres @ np.array([-u[1], u[0]])
    if len(daughters) == 2:
        total = float(lengths.sum())
        if abs(total - expected) > s.length_gate_um:
            return math.inf
        first, second = (0, 1) if along[0] <= along[1] else (1, 0)
        # the first daughter from -total/2 to -total/2 + L_first, the second after her
        target = np.empty(2)
        target[first] = -total / 2 + lengths[first] / 2
        target[second] = total / 2 - lengths[second] / 2
        length_term = ((total - expected) / s.length_sd_um) ** 2
    else:
        sister = expected - float(lengths[0])
        if not 0.25 * expected <= sister <= 0.75 * expected:
            return math.inf  # the septum is near mid-cell
        side = 1.0 if along[0] >= 0 else -1.0  # the daughter's end of the mother
        target = np.array([side * (expected / 2 - lengths[0] / 2)])
        sister_at = c - side * (expected / 2 - sister / 2) * u
        if not _outside(pred, sister_at[None])[0]:
            return math.inf
        # the septum is near mid-cell
        length_term = ((lengths[0] - expected / 2) / s.length_sd_um) ** 2
    miss = np.hypot(along - target, across)
    if np.any(miss > s.gate_um):
        return math.inf
    d_angle = _angle_difference(nxt.angle_rad[list(daughters)], pred.angle_rad[k])
    weight = _elongation(lengths, nxt.width_um[list(daughters)])
    return float(
        length_term
        + np.sum((miss / s.position_sd_um) ** 2)
        + np.sum(((nxt.width_um[list(daughters)] - pred.width_um[k]) / s.width_sd_um) ** 2)
        + np.sum(weight * (d_angle / s.angle_sd_rad) ** 2)
    )


def _division_candidates(
    pred: _Predicted, nxt: FrameCells, s: LinkSettings, cut: np.ndarray
) -> list[tuple[int, tuple[int, ...], float]]:
    """Every ``(mother, daughters, cost)`` within the gates.

    Daughters lie within reach of the mother's predicted centre; a pair's summed length
    is within ``length_gate_um`` of hers; a lone daughter is considered only for a
    mother reaching out of the field of view (where her sister may have gone), and not
    when ``cut`` says she is herself cut by the image's edge: her septum pole is then
    not in view, and a shorter part in view is the same cell seen less (a drift).
    """
    centres = np.stack([nxt.x_um, nxt.y_um], axis=1)
    expected = pred.length_um + pred.width_um / 3
    reach = expected / 2 + s.gate_um
    poles = _axis(pred.angle_rad) * (expected / 2)[:, None]
    out_of_view = _outside(pred, pred.centre + poles) | _outside(pred, pred.centre - poles)
    candidates = []
    for k in range(len(expected)):
        near = np.flatnonzero(np.linalg.norm(centres - pred.centre[k], axis=1) <= reach[k])
        lone = near[~cut[near]] if out_of_view[k] else near[:0]
        options: list[tuple[int, ...]] = [(int(a),) for a in lone]
        if near.size > 1:
            a, b = np.triu_indices(near.size, 1)
            total = nxt.length_um[near[a]] + nxt.length_um[near[b]]
            fits = np.abs(total - expected[k]) <= s.length_gate_um
            options += [(int(i), int(j)) for i, j in zip(near[a][fits], near[b][fits])]
        for daughters in options:
            split = _division_cost(pred, k, nxt, daughters, s)
            if math.isfinite(split):
                candidates.append((k, daughters, split))
    return candidates


def _divisions(
    pred: _Predicted,
    nxt: FrameCells,
    match: np.ndarray,
    cost: np.ndarray,
    end_cost: np.ndarray,
    s: LinkSettings,
    cut: np.ndarray,
) -> tuple[dict[int, tuple[int, ...]], np.ndarray]:
    """Divisions that explain the cells better than the assignment did, and the links left.

    A division of mother ``k`` into ``daughters`` replaces: her own link (or end), the
    daughters' starts, and the links of other cells to a daughter (those cells then
    end). Its gain is the change of the total cost; the best division is taken, the
    links updated, and the search repeated until no division lowers the cost.
    """
    m = cost.shape[1]
    match = match.copy()
    candidates = _division_candidates(pred, nxt, s, cut)
    chosen: dict[int, tuple[int, ...]] = {}
    used: set[int] = set()
    while True:
        linked_from = np.full(m, -1)
        for i, j in enumerate(match):
            if j >= 0:
                linked_from[j] = i
        best: tuple[float, int, tuple[int, ...]] | None = None
        for k, daughters, split in candidates:
            if k in chosen or used.intersection(daughters):
                continue
            own = match[k]
            before = cost[k, own] if own >= 0 else end_cost[k]
            after = split + (s.unlinked_cost if own >= 0 and own not in daughters else 0.0)
            for j in daughters:
                i = linked_from[j]
                if i < 0:
                    before += s.unlinked_cost
                elif i != k:
                    before += cost[i, j]
                    after += end_cost[i]
            gain = after - before
            if gain < 0 and (best is None or gain < best[0]):
                best = (gain, k, daughters)
        if best is None:
            return chosen, match
        _gain, k, daughters = best
        match[k] = -1
        match[np.isin(match, daughters)] = -1
        chosen[k] = daughters
        used.update(daughters)


@dataclass(frozen=True, eq=False)
class _Step:
    """Links of one pair of frames: ``match[i]`` = cell of ``t + 1`` or -1, divisions."""

    pred: _Predicted
    cost: np.ndarray
    match: np.ndarray
    split: dict[int, tuple[int, ...]]
    total: float
    score: float  # total with every end at ``unlinked_cost``: compares shifts fairly


def _link_pair(
    before: FrameCells,
    after: FrameCells,
    growth: float,
    placements: tuple[TrenchPlacement, TrenchPlacement] | None,
    drift_um: np.ndarray,
    size_um: tuple[float, float],
    s: LinkSettings,
    cut: tuple[np.ndarray, np.ndarray],
) -> _Step:
    """Assignment, then divisions, for one pair of frames; ``total`` is its whole cost.
    ``cut``: which cells of ``before`` and of ``after`` the image's edge cuts."""
    pred = _predict(before, growth, placements, drift_um, size_um, s.exit_margin_um)
    cut_before, cut_after = cut
    cost = _link_costs(pred, after, s, cut_before[:, None] | cut_after[None, :])
    end_cost = np.where(pred.leaving, 0.0, s.unlinked_cost)
    match = _assign(cost, end_cost, s.unlinked_cost)
    split, match = _divisions(pred, after, match, cost, end_cost, s, cut_after)
    explained = np.zeros(len(after), bool)
    total = 0.0
    free_ends = 0.0
    for i, j in enumerate(match):
        if j >= 0:
            total += cost[i, j]
            explained[j] = True
        elif i not in split:
            total += end_cost[i]
            free_ends += s.unlinked_cost - end_cost[i]
    for k, daughters in split.items():
        total += _division_cost(pred, k, after, daughters, s)
        explained[list(daughters)] = True
    total += s.unlinked_cost * int(np.count_nonzero(~explained))
    return _Step(pred, cost, match, split, float(total), float(total + free_ends))


def _no_links(
    before: FrameCells,
    after: FrameCells,
    growth: float,
    size_um: tuple[float, float],
    s: LinkSettings,
) -> _Step:
    """The step between two frames of different fields: every cell of ``before`` ends,
    every cell of ``after`` starts a track."""
    pred = _predict(before, growth, None, np.zeros(2), size_um, s.exit_margin_um)
    cost = np.full((len(before), len(after)), np.inf)
    total = s.unlinked_cost * (len(before) + len(after))
    return _Step(pred, cost, np.full(len(before), -1), {}, total, total)


def _placements(trench, t: int) -> tuple[TrenchPlacement, TrenchPlacement] | None:
    if trench is None or trench[t] is None or trench[t + 1] is None:
        return None
    return trench[t], trench[t + 1]


def link_cells(
    frames: Sequence[FrameCells],
    settings: LinkSettings | None = None,
    *,
    trench: Sequence[TrenchPlacement | None] | None = None,
    image_size_um: tuple[float, float] | None = None,
    cut_by_edge: Sequence[np.ndarray] | None = None,
    unrelated_frames: Sequence[int] = (),
    passes: int = 3,
) -> Lineage:
    """Give the cells of consecutive frames track ids and a lineage.

    Parameters
    ----------
    frames
        The cells of each frame in image coordinates (um; e.g.
        :attr:`SceneFit.cells <napari_symbac.fit.SceneFit.cells>` of each frame of a
        series), in time order. A frame may hold no cells: every track ends there.
    settings
        Scatter, gates and costs (:class:`LinkSettings`).
    trench
        The trench placement of each frame (:attr:`SceneFit.trench`) for a
        mother-machine series (closed end at the top, cells pushed down the trench);
        ``None`` for an open field.
    image_size_um
        ``(height, width)`` of the field of view: a cell predicted beyond it (below
        the image in a trench) may leave at no cost. Default: no edge.
    cut_by_edge
        Per frame, whether each cell is cut by the image's edge (its mask reaches the
        border: only its part in view was measured), when that is known
        (:func:`~napari_symbac.fit.start.cut_by_edge`). Such a cell is never taken as
        a division's lone daughter (her sister out of view): when the stage drifts,
        the part of a cell in view shrinks without any septum. Its links compare
        centre and length only (of the parts in view): its measured width and axis
        are its part's.
    passes
        Rounds of linking: after each, the growth factor (when not given) and the
        field's drift are measured again from the links.

    Returns
    -------
    Lineage
    """
    s = settings if settings is not None else LinkSettings()
    frames = list(frames)
    if not frames:
        raise ValueError("link_cells needs at least one frame of cells")
    if trench is not None and len(trench) != len(frames):
        raise ValueError(
            f"trench has {len(trench)} placements for {len(frames)} frames: give one per frame"
        )
    if passes < 1:
        raise ValueError(f"passes must be at least 1, got {passes}")
    cut = [np.zeros(len(f), bool) for f in frames]  # not known: none
    if cut_by_edge is not None:
        cut = [np.asarray(c, bool) for c in cut_by_edge]
        if len(cut) != len(frames) or any(c.shape != (len(f),) for c, f in zip(cut, frames)):
            raise ValueError("cut_by_edge needs one flag per cell of every frame")
    unrelated = {int(t) for t in unrelated_frames}
    if any(not 0 < t < len(frames) for t in unrelated):
        raise ValueError(
            f"unrelated_frames must name frames 1..{len(frames) - 1} (the first frame "
            f"follows none), got {sorted(unrelated)}"
        )
    size = image_size_um if image_size_um is not None else (math.inf, math.inf)
    is_trench = trench is not None and any(p is not None for p in trench)
    growth = s.growth_per_frame if s.growth_per_frame is not None else 1.0
    drift = np.zeros((max(len(frames) - 1, 0), 2))
    trench = trench if is_trench else None
    steps: list[_Step] = []
    for round_ in range(passes):
        steps = []
        for t in range(len(frames) - 1):
            pair = _placements(trench, t)
            pair_cut = (cut[t], cut[t + 1])
            if t + 1 in unrelated:
                steps.append(_no_links(frames[t], frames[t + 1], growth, size, s))
                continue
            if trench is None and round_ == 0:
                # the field's shift: the candidate whose links cost least (ends all
                # priced alike: a shift must not win by pushing cells out of view)
                tries = [
                    (_link_pair(frames[t], frames[t + 1], growth, None, d, size, s, pair_cut), d)
                    for d in _shift_candidates(frames[t], frames[t + 1], s)
                ]
                step, drift[t] = min(tries, key=lambda sd: sd[0].score)
            else:
                step = _link_pair(
                    frames[t], frames[t + 1], growth, pair, drift[t], size, s, pair_cut
                )
            steps.append(step)
        ratios = []
        for t, step in enumerate(steps):
            before, nxt = frames[t], frames[t + 1]
            i = np.flatnonzero(step.match >= 0)
            j = step.match[i]
            ratios += (nxt.length_um[j] / before.length_um[i]).tolist()
            if trench is None:
                seen = [np.stack([nxt.x_um[j], nxt.y_um[j]], 1)]
                expected = [step.pred.centre[i]]
                for k, daughters in step.split.items():
                    if len(daughters) == 2:  # the daughters' midpoint is the mother's centre
                        d = list(daughters)
                        seen.append(np.array([[nxt.x_um[d].mean(), nxt.y_um[d].mean()]]))
                        expected.append(step.pred.centre[[k]])
                shift = np.concatenate(seen) - np.concatenate(expected)
                # no link, no division: nothing says the field moved
                drift[t] = drift[t] + np.median(shift, axis=0) if shift.size else 0.0
        if s.growth_per_frame is None and ratios:
            growth = float(np.clip(np.median(ratios), 0.5, 2.0))
    gaps = _close_gaps(frames, steps, growth, drift, trench, size, s, cut) if s.close_gaps else []
    gaps = [g for g in gaps if not {g.t, g.t + 1} & unrelated]
    return _lineage(frames, steps, growth, drift, gaps)


@dataclass(frozen=True)
class _GapLink:
    """Cell ``cell`` of frame ``t - 1`` goes on as ``after`` (one cell: the same track;
    two: her daughters) in frame ``t + 1``, skipping frame ``t``."""

    t: int
    cell: int
    after: tuple[int, ...]
    cost: float


def _take(pred: _Predicted, index: list[int]) -> _Predicted:
    return dataclasses.replace(
        pred,
        centre=pred.centre[index],
        length_um=pred.length_um[index],
        width_um=pred.width_um[index],
        angle_rad=pred.angle_rad[index],
        leaving=pred.leaving[index],
    )


def _subset(cells: FrameCells, index: list[int]) -> FrameCells:
    return FrameCells(
        ids=cells.ids[index], x_um=cells.x_um[index], y_um=cells.y_um[index],
        angle_rad=cells.angle_rad[index], length_um=cells.length_um[index],
        width_um=cells.width_um[index],
    )  # fmt: skip


def _close_gaps(
    frames: list[FrameCells],
    steps: list[_Step],
    growth: float,
    drift: np.ndarray,
    trench,
    size_um: tuple[float, float],
    s: LinkSettings,
    cut: list[np.ndarray],
) -> list[_GapLink]:
    """Links and divisions over one missing frame (:attr:`LinkSettings.close_gaps`).

    For each frame ``t``: the tracks that end in ``t - 1`` (no link, no division;
    also those near the edge, which end for free) and the cells of ``t + 1`` that start a track
    are compared as one frame pair, the cells of ``t - 1`` predicted two frames ahead
    (growth ``g^2``, the two drifts, the placements of ``t - 1`` and ``t + 1``) with
    the scatter widened by ``sqrt 2``. A link or a division over the gap replaces an
    end and one or two starts (``unlinked_cost`` each) by its cost plus the price of
    the missing frame (``unlinked_cost``); the best of them are taken greedily while
    they lower the total.
    """
    root2 = math.sqrt(2.0)
    wide = dataclasses.replace(
        s,
        position_sd_um=s.position_sd_um * root2,
        length_sd_um=s.length_sd_um * root2,
        angle_sd_rad=s.angle_sd_rad * root2,
    )
    out: list[_GapLink] = []
    for t in range(1, len(frames) - 1):
        before, after = steps[t - 1], steps[t]
        ended = [
            i for i in range(len(frames[t - 1])) if before.match[i] < 0 and i not in before.split
        ]
        explained = set(after.match[after.match >= 0].tolist())
        explained.update(j for pair in after.split.values() for j in pair)
        started = [j for j in range(len(frames[t + 1])) if j not in explained]
        if not ended or not started:
            continue
        pair = None
        if trench is not None and trench[t - 1] is not None and trench[t + 1] is not None:
            pair = (trench[t - 1], trench[t + 1])
        shift = drift[t - 1] + drift[t]
        full = _predict(frames[t - 1], growth**2, pair, shift, size_um, s.exit_margin_um)
        pred = _take(full, ended)
        nxt = _subset(frames[t + 1], started)
        cut_before, cut_after = cut[t - 1][ended], cut[t + 1][started]
        cost = _link_costs(pred, nxt, wide, cut_before[:, None] | cut_after[None, :])
        options = [
            (float(cost[a, b]) - s.unlinked_cost, a, (int(b),), float(cost[a, b]))
            for a, b in zip(*np.nonzero(np.isfinite(cost)))
        ]
        options += [
            (c - 2 * s.unlinked_cost, k, daughters, c)
            for k, daughters, c in _division_candidates(pred, nxt, wide, cut_after)
            if len(daughters) == 2
        ]
        taken_a: set[int] = set()
        taken_b: set[int] = set()
        for gain, a, daughters, c in sorted(options):
            if gain >= 0:
                break
            if a in taken_a or taken_b.intersection(daughters):
                continue
            taken_a.add(a)
            taken_b.update(daughters)
            out.append(_GapLink(t, ended[a], tuple(started[d] for d in daughters), c))
    return out


def _shift_candidates(before: FrameCells, after: FrameCells, s: LinkSettings) -> list[np.ndarray]:
    """Shifts of an open field between two frames that groups of cells agree on.

    Every pair of cells (one per frame) closer than ``max_drift_um`` proposes its
    displacement (at most 2000 of them, evenly spaced, in a crowded field); the
    proposal with the most displacements within ``2 position_sd_um`` gives the median
    of those as a candidate, which are then set aside, five times;
    no shift is always a candidate. A frame in which every cell divides makes the
    mother-to-daughter offsets win the vote: the cost of the links decides.
    """
    a = np.stack([before.x_um, before.y_um], axis=1)
    b = np.stack([after.x_um, after.y_um], axis=1)
    shifts = (b[None, :, :] - a[:, None, :]).reshape(-1, 2)
    shifts = shifts[np.linalg.norm(shifts, axis=1) <= s.max_drift_um]
    candidates = [np.zeros(2)]
    for _ in range(5):
        if shifts.size == 0:
            break
        # at most 2000 proposals (evenly spaced) vote against every shift: a large
        # field's pairs would otherwise make a square matrix of them
        proposals = shifts[:: max(1, -(-len(shifts) // 2000))]
        close = np.linalg.norm(proposals[:, None, :] - shifts[None, :, :], axis=-1) <= (
            2 * s.position_sd_um
        )
        best = close[int(np.argmax(close.sum(axis=1)))]
        candidates.append(np.median(shifts[best], axis=0))
        shifts = shifts[~best]
    return candidates


def _lineage(
    frames: list[FrameCells],
    steps: list[_Step],
    growth: float,
    drift: np.ndarray,
    gap_links: Sequence[_GapLink] = (),
) -> Lineage:
    """Track ids from the links: a link keeps the id, a division or a start opens new
    ones; a link over a gap keeps the id of the cell two frames before."""
    ids: list[np.ndarray] = [np.arange(1, len(frames[0]) + 1, dtype=np.int64)]
    first = {int(k): 0 for k in ids[0]}
    last = dict(first)
    parent = dict.fromkeys(first, 0)
    costs = []
    gaps: list[tuple[int, int]] = []
    next_id = len(frames[0]) + 1
    for t, step in enumerate(steps):
        cost, match, split = step.cost, step.match, step.split
        now = np.zeros(len(frames[t + 1]), np.int64)
        link_cost = np.full(len(frames[t + 1]), np.nan)
        for i, j in enumerate(match):
            if j >= 0:
                now[j] = ids[t][i]
                link_cost[j] = cost[i, j]
        for k, pair in sorted(split.items()):
            for j in sorted(pair):
                now[j] = next_id
                parent[next_id] = int(ids[t][k])
                next_id += 1
        for gap in (g for g in gap_links if g.t == t):  # from frame t - 1 to t + 1
            track = int(ids[t - 1][gap.cell])
            if len(gap.after) == 1:
                now[gap.after[0]] = track
                link_cost[gap.after[0]] = gap.cost
                gaps.append((track, t))
                continue
            for j in sorted(gap.after):
                now[j] = next_id
                parent[next_id] = track
                next_id += 1
        for j in np.flatnonzero(now == 0):
            now[j] = next_id
            parent[next_id] = 0
            next_id += 1
        for track in now.tolist():
            first.setdefault(track, t + 1)
            last[track] = t + 1
        ids.append(now)
        costs.append(link_cost)
    tracks = np.array(
        [[k, first[k], last[k], parent[k]] for k in sorted(first)], np.int64
    ).reshape(-1, 4)
    return Lineage(tuple(ids), tracks, float(growth), drift, tuple(costs), tuple(sorted(gaps)))
