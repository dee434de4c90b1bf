"""Moves that change the number of cells, accepted by the BIC.

A fitted scene can hold a cell too many (a short duplicate hidden inside a longer
rod: the scene takes the thickest chord per pixel, so it changes nothing), two
rods where there is one cell, one rod where a septum shows two, or miss a cell.
Each move is proposed where the model or the residual says so and kept when the
Bayesian information criterion ``BIC = chi^2 / phi + k ln N`` falls (``k``
parameters, ``N`` valid pixels; one cell costs ``per_cell * ln N``; ``phi >= 1`` the
residual's overdispersion, :func:`dispersion`, measured where the move changes the
model):

* **remove** a cell whose removal raises ``chi^2`` by less than its price (a hidden
  duplicate raises it by about 0);
* **merge** two aligned neighbours (axes within 0.5 rad, pole-to-pole segments
  within a cell width, overlapping or end to end) into one rod between the two
  poles furthest apart;
* **split** a rod longer than 1.6 times the median cell length in two halves;
* **reseed** (fluorescence) a bright blob of the image that holds fewer rods than
  its finer maxima show touching cells
  (:func:`~napari_symbac.fit.bright_start.touching_cells`): its rods replaced by one
  per watershed basin (a touching colony is one blob at the start's smoothing, and
  a rod across two cells of different pairs is neither split nor merged right);
* **add** a cell on a blob of significant residual of the cells' polarity where the
  model has no cell but room for one (media: inside the trench, on the pad); in
  fluorescence the blobs are those of the start's detector
  (:func:`~napari_symbac.fit.bright_start.bright_instances`) on the residual, which
  leaves out spots smaller than a cell.

Merged, split and added cells are refitted locally (their own parameters only)
before the comparison, and, when that brings them close to acceptance but short of
it, with every parameter free. A refused merge is not proposed again at the same
place: the evidence against it is local, and an accepted move elsewhere leaves it.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from napari_symbac.fit.bright_start import bright_instances, touching_cells
from napari_symbac.fit.lm import State
from napari_symbac.fit.overlap import segment_distance
from napari_symbac.fit.problem import Problem
from napari_symbac.fit.start import cells_from_instances
from napari_symbac.optics.forward import block_average

__all__ = ["improve_scene", "prune_cells"]

#: An added cell fitted dimmer than ``1 + DIM_CELL`` times the cells' intensity is a
#: glow or background structure, not a cell (with per-cell brightness).
DIM_CELL = -0.5
#: Iterations of the local refit of a proposed cell.
LOCAL_ITERATIONS = 8
#: A proposal refused after its local refit but within this many cell prices of
#: acceptance is refitted with every parameter free before the BIC decides.
GLOBAL_MARGIN = 10.0


@dataclass
class _Context:
    """What the passes share: the dispersion, the log and the accepted moves."""

    dispersion: float
    log: list[str] = field(default_factory=list)
    history: list[tuple[str, float, float]] = field(default_factory=list)
    refused: list[tuple[str, float, float, float]] = field(default_factory=list)

    def near(self, kind: str, x: float, y: float, radius_um: float = 0.6) -> bool:
        """Whether a move of ``kind`` was accepted within ``radius_um`` of ``(x, y)``."""
        return any(k == kind and math.hypot(x - a, y - b) < radius_um for k, a, b in self.history)

    def accept(self, kind: str, x: float, y: float, message: str) -> None:
        self.history.append((kind, x, y))
        self.log.append(message)

    def reject(self, kind: str, x: float, y: float, offset_um: float) -> None:
        """Remember a refused proposal (not tried again at the same place).

        ``offset_um``: what tells proposals at one place apart (a septum's offset
        from the rod's centre, a merged rod's length).
        """
        self.refused.append((kind, x, y, offset_um))

    def tried(self, kind: str, x: float, y: float, offset_um: float) -> bool:
        """Whether a proposal of ``kind`` was refused within 0.3 um of this one."""
        return any(
            k == kind and math.hypot(x - a, y - b) < 0.3 and abs(offset_um - o) < 0.3
            for k, a, b, o in self.refused
        )


def dispersion(
    problem: Problem, state: State, block_px: int = 4, where: np.ndarray | None = None
) -> float:
    """Overdispersion of the standardised residual from its spatial correlation.

    ``16 var(mean of z over 4 x 4 blocks)``: 1 for white noise, larger when the
    residual holds structure the model misses (its pixels are then not independent
    and a chi-square difference overstates the evidence). At least 1. With ``where``
    (camera pixels), only the blocks wholly inside it, their spread taken robustly
    (1.4826 x their median absolute deviation); ``nan`` when fewer than 10.
    """
    rows, cols = problem.shape
    z = ((problem.y - state.mu) * np.sqrt(problem.w)).reshape(rows, cols)
    used = (problem.w > 0).reshape(rows, cols)
    if where is not None:
        used = used & where
    r, c = rows // block_px * block_px, cols // block_px * block_px
    if r == 0 or c == 0:
        return 1.0 if where is None else math.nan
    blocks = z[:r, :c].reshape(r // block_px, block_px, c // block_px, block_px)
    full = used[:r, :c].reshape(blocks.shape).all(axis=(1, 3))
    means = blocks.mean(axis=(1, 3))[full]
    if means.size < 10:
        return 1.0 if where is None else math.nan
    if where is None:
        return float(max(block_px**2 * np.var(means), 1.0))
    # Locally, robustly: a few blocks of an unmodelled neighbour (a spot, another
    # cell's misfit) must not set the price of the move.
    spread = 1.4826 * float(np.median(np.abs(means - np.median(means))))
    return float(max(block_px**2 * spread**2, 1.0))


def _local_dispersion(problem: Problem, state: State, trial: State, ctx: _Context) -> float:
    """The dispersion where a move changes the model (more than 0.1 noise s.d.).

    The residual's structure is local: a bright cell's misfit says nothing about
    the evidence for a dim cell elsewhere. Where the move changes too few pixels
    (a hidden duplicate), the whole image's dispersion.
    """
    changed = np.abs(trial.mu - state.mu) * np.sqrt(problem.w) > 0.1
    if not changed.any():
        return ctx.dispersion
    local = dispersion(problem, state, where=changed.reshape(problem.shape))
    return ctx.dispersion if math.isnan(local) else local


def _poles(block: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    cx, cy, angle, length = block[:4]
    d = np.array([math.sin(angle), math.cos(angle)]) * length / 2
    c = np.array([cx, cy])
    return c - d, c + d


def _rod(p: np.ndarray, q: np.ndarray, template: np.ndarray) -> np.ndarray:
    """A cell block from pole ``p`` to pole ``q`` (other entries from ``template``)."""
    block = template.copy()
    d = q - p
    if d[1] < 0:
        d = -d
    block[0], block[1] = (p + q) / 2
    block[2] = math.atan2(d[0], d[1])
    block[3] = float(np.hypot(*d))
    block[4:] = 0.0
    return block


def _local_free(problem: Problem, n: int, cells: list[int]) -> np.ndarray:
    pc = problem.layout.per_cell
    free = np.zeros(n * pc + len(problem.layout.global_names), bool)
    for i in cells:
        free[i * pc : (i + 1) * pc] = True
    return free


def _try(
    problem: Problem,
    state: State,
    blocks: np.ndarray,
    shared: np.ndarray,
    refit: list[int],
    ctx: _Context,
) -> State:
    trial = problem.evaluate(Problem.join(blocks, shared))
    if refit:
        trial, _ = problem.refit(trial, _local_free(problem, len(blocks), refit), LOCAL_ITERATIONS)
        dn = len(blocks) - problem.n_cells(state.x)
        price = problem.bic_per_cell * ctx.dispersion
        close = trial.cost + dn * price < state.cost + GLOBAL_MARGIN * price
        if close and not _accept(problem, state, trial, dn, ctx):
            # Close: let the neighbours, the width and the optics settle too. (An
            # accepted move is settled by the fit's next round.)
            trial, _ = problem.refit(trial, None, LOCAL_ITERATIONS)
    return trial


def _accept(problem: Problem, state: State, trial: State, dn: int, ctx: _Context) -> bool:
    phi = _local_dispersion(problem, state, trial, ctx)
    return (trial.cost - state.cost) / phi + dn * problem.bic_per_cell < 0


def _remove_pass(problem: Problem, state: State, ctx: _Context) -> tuple[State, bool]:
    blocks, shared = problem.blocks(state.x)
    n = len(blocks)
    if n <= 1:
        return state, False
    best = None
    for i in range(n):
        trial = problem.evaluate(Problem.join(np.delete(blocks, i, axis=0), shared))
        if _accept(problem, state, trial, -1, ctx) and (best is None or trial.cost < best[1].cost):
            best = (i, trial)
    if best is None:
        return state, False
    x, y = blocks[best[0], :2]
    ctx.accept("remove", x, y, f"removed cell at ({x:.2f}, {y:.2f}) um")
    return best[1], True


def _merge_pass(problem: Problem, state: State, ctx: _Context) -> tuple[State, bool]:
    blocks, shared = problem.blocks(state.x)
    n = len(blocks)
    width = shared[0]
    for i in range(n):
        for j in range(i + 1, n):
            pi, pj = _poles(blocks[i]), _poles(blocks[j])
            turn = abs((blocks[i, 2] - blocks[j, 2] + math.pi / 2) % math.pi - math.pi / 2)
            if turn > 0.5 or segment_distance(pi, pj) > width:
                continue
            poles = [*pi, *pj]
            far = max(
                ((a, b) for ia, a in enumerate(poles) for b in poles[ia + 1 :]),
                key=lambda pair: float(np.hypot(*(pair[0] - pair[1]))),
            )
            merged = _rod(far[0], far[1], blocks[i])
            if ctx.near("split", merged[0], merged[1]):
                continue  # no undoing a split
            if ctx.tried("merge", merged[0], merged[1], merged[3]):
                continue
            trial_blocks = np.delete(blocks, j, axis=0)
            trial_blocks[i] = merged
            trial = _try(problem, state, trial_blocks, shared, [i], ctx)
            if _accept(problem, state, trial, -1, ctx):
                message = f"merged cells at y = {blocks[i, 1]:.2f} and {blocks[j, 1]:.2f} um"
                ctx.accept("merge", merged[0], merged[1], message)
                return trial, True
            ctx.reject("merge", merged[0], merged[1], merged[3])
    return state, False


#: A septum is proposed where the rod's model exceeds the image by this many noise
#: s.d. of the mean over a strip across the axis (the window of :func:`septum_along`),
#: the s.d. widened by the residual's dispersion.
SEPTUM_Z = 4.0


def septum_along(
    problem: Problem, state: State, block: np.ndarray, polarity: str
) -> tuple[float, float]:
    """Where along a rod the image falls short of its model most: a septum.

    Two daughters lying end to end fitted as one rod: at the septum the rounded
    poles thin the cells (the chord ``2 sqrt(r^2 - d^2)`` of eq. OPL2 falls to 0 at
    the pole), so the image there holds less cell than a rod's uniform middle, and
    the standardised residual, signed so that positive is "less cell than the
    model" (fluorescence: darker, phase: brighter), peaks there. It is averaged
    over a strip across the axis (half the width wide, two pixels long) at every
    half pixel along the axis, leaving each side at least 0.6 widths of rod in view
    (:func:`_cuttable_span`).

    Returns
    -------
    offset_um, z
        The peak's distance from the rod's centre along its axis (towards the pole at
        ``+axis``) and the strip's mean residual times the square root of its pixels
        (a noise s.d. of about 1 for white noise); ``(0, 0)`` for a rod too short, or
        too little of it in view.
    """
    rows, cols = problem.shape
    px = problem.microscope.pixel_size_um
    width = problem.blocks(state.x)[1][0]
    sign = -1.0 if polarity == "dark" else 1.0
    short = -sign * (problem.y - state.mu) * np.sqrt(problem.w)
    cx, cy, angle = block[:3]
    low, high = _cuttable_span(block, width, (cols * px, rows * px))
    if high - low <= 2 * px:
        return 0.0, 0.0
    u = np.array([math.sin(angle), math.cos(angle)])
    n = np.array([u[1], -u[0]])
    along = np.arange(low, high + 1e-9, px / 2)
    across = np.linspace(-width / 4, width / 4, max(round(width / 2 / px) + 1, 2))
    ahead = np.array([-px / 2, 0.0, px / 2])
    points = (
        np.array([cx, cy])[None, None, None, :]
        + along[:, None, None, None] * u
        + ahead[None, :, None, None] * u
        + across[None, None, :, None] * n
    )
    coords = [points[..., 1].ravel() / px - 0.5, points[..., 0].ravel() / px - 0.5]
    z = ndimage.map_coordinates(short.reshape(rows, cols), coords, order=1, mode="nearest")
    strip = z.reshape(along.size, -1).mean(axis=1)
    # pixels in one strip: its area over a pixel's (independent noise per pixel)
    pixels = max((2 * px) * (width / 2) / px**2, 1.0)
    k = int(np.argmax(strip))
    return float(along[k]), float(strip[k] * math.sqrt(pixels))


def _cuttable_span(
    block: np.ndarray, width_um: float, size_um: tuple[float, float]
) -> tuple[float, float]:
    """The offsets from a rod's centre along its axis (um, towards the pole at
    ``+axis``) at which a split may cut it, the view being the image (``size_um``: its
    width and height).

    A rod wholly in view keeps 0.6 widths on each side of the cut. A rod that the
    image's edge cuts is seen only up to the edge: its piece past the edge must show a
    quarter of a width in view, and its piece wholly in view must be a rod
    (:data:`RESEED_ASPECT` widths long, as :func:`_are_rods` asks of a split's cells,
    which cannot judge it once the refinement has moved it past the edge). Found as a
    user: the 0.6 um of a cell that a drifting trench showed at the image's bottom was
    cut at a "septum" 0.2 um from the edge into a round cell and a rod beyond the image
    (frame 3 of the real trench shifted down the frames, fitted as a series; the
    linking then read the pieces as a division). ``low > high``: no such cut.
    """
    cx, cy, angle, length = (float(v) for v in block[:4])
    low, high = -length / 2, length / 2
    axis = ((cx, math.sin(angle), size_um[0]), (cy, math.cos(angle), size_um[1]))
    for centre, step, size in axis:
        if abs(step) < 1e-12:
            if not 0.0 <= centre <= size:
                return 0.0, -1.0
            continue
        ends = sorted(((0.0 - centre) / step, (size - centre) / step))
        low, high = max(low, ends[0]), min(high, ends[1])
    past_low, past_high = low > -length / 2, high < length / 2
    in_view = 0.6 if not (past_low or past_high) else RESEED_ASPECT
    low += width_um * (0.25 if past_low else in_view)
    high -= width_um * (0.25 if past_high else in_view)
    return low, high


def _split_at(blocks: np.ndarray, i: int, offset_um: float) -> np.ndarray:
    """Rod ``i`` cut in two at ``offset_um`` from its centre along its axis."""
    p, q = _poles(blocks[i])
    length = float(np.hypot(*(q - p)))
    u = (q - p) / max(length, 1e-9)
    # _poles: p is the pole at -axis; the axis of septum_along points from p to q
    cut = (p + q) / 2 + offset_um * u
    gap = 0.05 * u
    a, b = _rod(p, cut - gap, blocks[i]), _rod(cut + gap, q, blocks[i])
    return np.insert(np.delete(blocks, i, axis=0), i, [a, b], axis=0)


def _split_pass(
    problem: Problem, state: State, ctx: _Context, polarity: str = "bright"
) -> tuple[State, bool]:
    """Split a rod in two: where its image shows a septum, or at mid-length if it is
    much longer than the others (both accepted by the BIC alone)."""
    blocks, shared = problem.blocks(state.x)
    n = len(blocks)
    if n == 0:
        return state, False
    width = shared[0]
    limit = 1.6 * float(np.median(blocks[:, 3]))
    rows, cols = problem.shape
    view_um = (cols * problem.microscope.pixel_size_um, rows * problem.microscope.pixel_size_um)
    for i in np.argsort(-blocks[:, 3], kind="stable"):
        x, y = blocks[i, :2]
        if ctx.near("merge", x, y):
            continue  # no undoing a merge
        threshold = max(limit, 2.2 * width) if n > 1 else 2.2 * width
        cuts = []
        offset, z = septum_along(problem, state, blocks[i], polarity)
        if z > SEPTUM_Z * math.sqrt(ctx.dispersion) and not ctx.tried("septum", x, y, offset):
            cuts.append(("septum", offset))
        low, high = _cuttable_span(blocks[i], width, view_um)
        middle_in_view = low <= 0.0 <= high
        if blocks[i, 3] >= threshold and middle_in_view and not (cuts and abs(offset) < 0.1):
            cuts.append(("middle", 0.0))
        for kind, offset in cuts:
            trial_blocks = _split_at(blocks, int(i), offset)
            trial = _try(problem, state, trial_blocks, shared, [int(i), int(i) + 1], ctx)
            if _are_rods(problem, trial.x, [int(i), int(i) + 1]) and _accept(
                problem, state, trial, +1, ctx
            ):
                where = f" at its septum ({offset:+.2f} um from its centre)" * (
                    kind == "septum"
                )
                ctx.accept("split", x, y, f"split the cell at ({x:.2f}, {y:.2f}) um{where}")
                return trial, True
            if kind == "septum":
                ctx.reject("septum", x, y, offset)
    return state, False


#: Each cell of an accepted reseed or split is at least this many widths long: touching
#: bacteria are rods (newborns about twice as long as wide). A cut that leaves a
#: round piece is texture inside one wide cell (two bright foci of a ColiCoords ds1
#: cell, field 1, fitted 1.34 and 2.31 um long at 1.36 um wide; a bright pole of a ds3
#: frame 1 cell split off as a "cell" 0.78 um long at 0.91 um wide), not a septum. A
#: cell on the image's edge is exempt (the edge may cut it shorter).
RESEED_ASPECT = 1.25


def _are_rods(problem: Problem, x: np.ndarray, cells: list[int] | range) -> bool:
    """Whether the fitted ``cells`` of parameters ``x`` are rods
    (:data:`RESEED_ASPECT`), each unless its rod reaches past the image's edge (where
    the edge may show it shorter): the one rule of a split's and a reseed's cells."""
    blocks, shared = problem.blocks(x)
    lay = problem.layout
    rows, cols = problem.shape
    px = problem.microscope.pixel_size_um
    for k in cells:
        width = shared[0] + (blocks[k, lay.i_dwidth] if lay.per_cell_width else 0.0)
        poles = np.array(_poles(blocks[k]))  # rows (x, y), um
        far = np.array([cols, rows]) * px - width / 2
        inside = bool(((poles >= width / 2) & (poles <= far)).all())
        if inside and blocks[k, 3] < RESEED_ASPECT * width:
            return False
    return True


def _under(labels: np.ndarray, x_um: np.ndarray, y_um: np.ndarray, px: float) -> np.ndarray:
    """The label under each centre (a centre off the image: its nearest edge pixel)."""
    rows, cols = labels.shape
    return labels[
        np.clip((y_um / px).astype(int), 0, rows - 1),
        np.clip((x_um / px).astype(int), 0, cols - 1),
    ]


def _touching_proposals(problem: Problem) -> tuple[np.ndarray, np.ndarray]:
    """The image's bright blobs and their cut into touching cells, for the reseed.

    They depend on the image alone, not on the model: found once per
    :func:`improve_scene`, not once per pass.
    """
    rows, cols = problem.shape
    px = problem.microscope.pixel_size_um
    image = problem.y.reshape(rows, cols)
    used = problem.w.reshape(rows, cols) > 0
    blobs = bright_instances(image, px, valid=used)
    return blobs, touching_cells(image, px, blobs, valid=used)


def _reseed_pass(
    problem: Problem,
    state: State,
    ctx: _Context,
    blobs: np.ndarray,
    all_parts: np.ndarray,
) -> tuple[State, bool]:
    """Replace the rods of a bright blob by one per touching cell its finer maxima
    show (``blobs``, ``all_parts``: :func:`_touching_proposals`), when they are more
    than the rods: accepted by the BIC when every new cell off the image's edge is a
    rod (:data:`RESEED_ASPECT`)."""
    blocks, shared = problem.blocks(state.x)
    px = problem.microscope.pixel_size_um
    rod_blob = _under(blobs, blocks[:, 0], blocks[:, 1], px)
    for index, box in enumerate(ndimage.find_objects(blobs), start=1):
        if box is None:
            continue
        cy, cx = ((sl.start + sl.stop) / 2 * px for sl in box)
        if ctx.near("reseed", cx, cy) or ctx.tried("reseed", cx, cy, 0.0):
            continue
        inside = np.flatnonzero(rod_blob == index)
        cut = all_parts[box][blobs[box] == index]
        if np.unique(cut[cut > 0]).size <= inside.size:
            continue
        parts = np.where(blobs == index, all_parts, 0)
        try:
            new, _ = cells_from_instances(parts, px, max_cell_length_um=math.inf)
        except ValueError:
            continue
        if len(new) <= inside.size:
            continue
        added = np.zeros((len(new), problem.layout.per_cell))
        added[:, 0], added[:, 1], added[:, 2] = new.x_um, new.y_um, new.angle_rad
        added[:, 3] = np.maximum(new.length_um, shared[0])
        kept = np.delete(blocks, inside, axis=0)
        trial_blocks = np.vstack([kept, added])
        refit = list(range(len(kept), len(trial_blocks)))
        trial = _try(problem, state, trial_blocks, shared, refit, ctx)
        dn = len(new) - inside.size
        if _are_rods(problem, trial.x, refit) and _accept(problem, state, trial, dn, ctx):
            for x, y in zip(new.x_um, new.y_um):
                ctx.history.append(("split", float(x), float(y)))
            if inside.size:
                message = (
                    f"cut the blob at ({cx:.2f}, {cy:.2f}) um into {len(new)} touching cells "
                    f"(it held {inside.size})"
                )
            else:  # a blob no cell covered: its cells are new
                cells = "a cell" if len(new) == 1 else f"{len(new)} touching cells"
                message = f"added {cells} in the unexplained blob at ({cx:.2f}, {cy:.2f}) um"
            ctx.accept("reseed", cx, cy, message)
            return trial, True
        ctx.reject("reseed", cx, cy, 0.0)
    return state, False


def _add_pass(
    problem: Problem, state: State, ctx: _Context, polarity: str, max_tries: int = 4
) -> tuple[State, bool]:
    blocks, shared = problem.blocks(state.x)
    rows, cols = problem.shape
    px = problem.microscope.pixel_size_um
    sign = -1.0 if polarity == "dark" else 1.0
    z = sign * (problem.y - state.mu) * np.sqrt(problem.w)
    # Smoothed by 1 px, white noise keeps 0.282 of its s.d.; x 2 and a threshold of 3
    # ask a blob to stand 5.3 s.d. of the smoothed noise out.
    z = ndimage.gaussian_filter(z.reshape(rows, cols), 1.0) * 2.0

    model_cells = block_average(state.scene.interior(state.scene.cells), state.scene.upsample)
    scene = state.scene
    room = block_average(scene.interior(scene.media + scene.cells), scene.upsample)
    empty = (model_cells < 0.05) & (room > 0.5)
    used = problem.w.reshape(rows, cols) > 0
    if polarity == "bright":
        # Fluorescence: the start's detector on the residual, so that a bright spot
        # (smaller than a cell at half its peak) is not taken for a missing cell.
        residual = (problem.y - state.mu).reshape(rows, cols)
        labels = bright_instances(residual, px, valid=used, region=empty)
        count = int(labels.max())
        blob = labels > 0
    else:
        blob = ndimage.binary_opening((z > 3.0) & empty & used)
        labels, count = ndimage.label(blob)
    if count == 0:
        return state, False
    min_px = max(int(0.3 / px**2), 6)
    sizes = ndimage.sum(blob, labels, range(1, count + 1))
    order = np.argsort(-sizes, kind="stable")[:max_tries]
    for index in order:
        if sizes[index] < min_px:
            break
        one = (labels == index + 1).astype(np.int64)
        try:
            new, _ = cells_from_instances(one, px, max_cell_length_um=math.inf)
        except ValueError:
            continue
        block = np.zeros(problem.layout.per_cell)
        block[:4] = new.x_um[0], new.y_um[0], new.angle_rad[0], max(new.length_um[0], shared[0])
        trial_blocks = np.vstack([blocks, block]) if len(blocks) else block[None]
        trial = _try(problem, state, trial_blocks, shared, [len(trial_blocks) - 1], ctx)
        lay = problem.layout
        added = problem.blocks(trial.x)[0][-1]
        if lay.per_cell_brightness and added[lay.i_brightness] < DIM_CELL:
            continue  # a glow or background structure, not a cell
        row, col = int(added[1] / px), int(added[0] / px)
        if not (0 <= row < rows and 0 <= col < cols) or room[row, col] <= 0.5:
            continue  # the refit moved it into the device or out of the image
        if _accept(problem, state, trial, +1, ctx):
            x, y = block[:2]
            ctx.accept("add", x, y, f"added a cell at ({x:.2f}, {y:.2f}) um")
            return trial, True
    return state, False


def improve_scene(
    problem: Problem, state: State, polarity: str, max_moves: int = 20
) -> tuple[State, list[str], float]:
    """Apply (fluorescence: reseed,) remove, merge, split and add moves while the BIC
    falls.

    The chi-square differences are divided by the residual's :func:`dispersion`
    where the move changes the model (a quasi-likelihood BIC): where the model
    misses structure, a move must explain more to be kept. A move is not undone at
    the same place (no split of a merged cell, no merge of a split one).

    Returns
    -------
    state, log, dispersion
        The final state, the accepted moves in plain words, and the dispersion used.
    """
    ctx = _Context(dispersion(problem, state))
    split = functools.partial(_split_pass, polarity=polarity)  # its septum's sign
    passes = [_remove_pass, _merge_pass, split]
    if polarity == "bright":
        # before the merges: a rod across two cells of different pairs merged with
        # its neighbour is not split right again
        blobs, parts = _touching_proposals(problem)
        passes.insert(0, functools.partial(_reseed_pass, blobs=blobs, all_parts=parts))
    for _ in range(max_moves):
        for move in passes:
            state, changed = move(problem, state, ctx)
            if changed:
                break
        else:
            state, changed = _add_pass(problem, state, ctx, polarity)
        if not changed:
            break
    return state, ctx.log, ctx.dispersion


def prune_cells(problem: Problem, state: State) -> tuple[State, list[str]]:
    """Remove, one at a time, the cells the BIC no longer supports after the last round.

    The moves run after the first round; the later rounds can leave a cell that pays
    for nothing: an added cell pushed by the overlap penalty off its neighbour and out
    of the image, where it changes no pixel (found on ColiCoords ds3 frame 0: three
    cells parked at the field's edge bound, x = -2 um). The rule is the remove move's,
    with the dispersion of the final residual.

    Returns
    -------
    state, log
        The state without those cells, and a line for each removed.
    """
    ctx = _Context(dispersion(problem, state))
    while True:
        state, removed = _remove_pass(problem, state, ctx)
        if not removed:
            return state, ctx.log
