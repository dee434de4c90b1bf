"""Cell identity across frames: links, divisions, exits (fit/lineage.py, fit_series)."""

from __future__ import annotations

import numpy as np
import pytest
from _fit_synthetic import PIXEL_UM, START, TRENCH, TRUTH
from _series_synthetic import (
    in_view,
    lineage_relations,
    observe,
    render_pad_series,
    render_trench_series,
    trench_simulation,
    truth_relations,
)

from napari_symbac.fit import LinkSettings, TrenchPlacement, fit_series, link_cells
from napari_symbac.optics import ForwardModel
from napari_symbac.scene import draw_scene
from napari_symbac.settings import AgarPadGeometry, Camera, RenderSettings, SimulationSettings
from napari_symbac.sim import FrameCells, simulate

#: The test trench's image: 128 x 46 px of 65 nm, the trench 0.75 um from the top-left.
IMAGE_UM = (128 * PIXEL_UM, 46 * PIXEL_UM)
PLACEMENT = TrenchPlacement(TRENCH.margin_um, TRENCH.width_um, TRENCH.margin_um)


def _differences(got, want, observed=None, size_um=None, hidden_within_um=0.3):
    """Cells whose relation to the previous frame differs from the truth.

    With ``size_um`` (the field of view): a division read as a link of the mother is
    not counted when the daughter reaches to within ``hidden_within_um`` of the edge:
    her septum, the only sign of the division, is then out of view or within about a
    PSF width (0.3 um) of the edge, and the part in view is the same either way.
    Returns the differences and the number of such hidden divisions.
    """
    wrong, hidden = [], 0
    for t, (ours, theirs) in enumerate(zip(got, want)):
        for j, relation in theirs.items():
            if ours[j] == relation:
                continue
            if size_um is not None and relation[0] == "division":
                cells = observed[t + 1]
                half = cells.length_um[j] / 2
                dx, dy = half * np.sin(cells.angle_rad[j]), half * np.cos(cells.angle_rad[j])
                xs = cells.x_um[j] + np.array([-dx, dx])
                ys = cells.y_um[j] + np.array([-dy, dy])
                m = hidden_within_um
                at_edge = (xs.min() < m or xs.max() > size_um[1] - m or ys.min() < m
                           or ys.max() > size_um[0] - m)  # fmt: skip
                if ours[j] == ("link", relation[1]) and at_edge:
                    hidden += 1
                    continue
            wrong.append((t + 1, j, ours[j], relation))
    return wrong, hidden


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_every_link_and_division_of_a_simulated_trench_is_found(seed):
    """40 frames of a mother machine (~18 divisions, ~16 cells pushed out), the cells
    as a fit reports them: shuffled, renumbered, with 50 nm scatter."""
    simulation = trench_simulation(seed=seed, n_frames=40)
    rng = np.random.default_rng(seed)
    offset = (TRENCH.margin_um, TRENCH.margin_um)
    observed, truth_ids = observe(simulation.frames, rng, offset, noise_um=0.05)
    lineage = link_cells(
        observed, trench=[PLACEMENT] * len(observed), image_size_um=IMAGE_UM
    )
    want = truth_relations(simulation, truth_ids)
    kinds = [relation[0] for step in want for relation in step.values()]
    assert kinds.count("division") >= 20
    assert kinds.count("link") >= 60
    wrong, hidden = _differences(lineage_relations(lineage), want, observed, IMAGE_UM)
    assert wrong == []
    assert hidden <= 4  # of ~20 divisions, those with the septum at the edge
    assert lineage.growth_per_frame == pytest.approx(np.exp(np.log(2) / 25 * 5), rel=0.03)
    # the CTC table: parents end the frame before their daughters begin
    begins = {int(t): int(b) for t, b, _e, _p in lineage.tracks}
    ends = {int(t): int(e) for t, _b, e, _p in lineage.tracks}
    for track, begin, _end, parent in lineage.tracks.tolist():
        if parent:
            assert ends[parent] == begin - 1
        assert track in lineage.track_ids[begin]
        assert track in lineage.track_ids[ends[track]]
    assert begins == {int(t): min(f for f, ids in enumerate(lineage.track_ids) if t in ids)
                      for t in begins}  # fmt: skip


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_every_link_and_division_of_a_drifting_colony_is_found(seed):
    """Colonies on a pad seen through a 16 x 16 um field that drifts ~0.5 um per frame
    (up to 1.3 um), 14 frames: cells divide, and leave or enter at the field's edges."""
    n_frames = 14
    pad = AgarPadGeometry(
        field_width_um=24.0, field_height_um=24.0, n_colonies=3, scattered_cells=2,
        colony_separation_um=6.0, edge_margin_um=4.0,
    )  # fmt: skip
    settings = SimulationSettings(
        n_frames=n_frames, geometry="agar_pad", agar_pad=pad, n_founders=3,
        frame_interval_min=5.0, cell_width_um=0.9, seed=seed,
    )  # fmt: skip
    simulation = simulate(settings)
    rng = np.random.default_rng(seed)
    steps = rng.normal(0.0, 0.3, (n_frames, 2)) + np.array([0.4, -0.3])
    steps[0] = 0
    origin = 4.0 + np.cumsum(steps, axis=0)
    observed, truth_ids = observe(in_view(simulation.frames, origin, (16.0, 16.0)), rng,
                                  noise_um=0.05)  # fmt: skip
    lineage = link_cells(observed, image_size_um=(16.0, 16.0))
    want = truth_relations(simulation, truth_ids)
    kinds = [relation[0] for step in want for relation in step.values()]
    assert kinds.count("division") >= 15
    wrong, hidden = _differences(lineage_relations(lineage), want, observed, (16.0, 16.0))
    assert wrong == []
    assert hidden <= 2
    # the field's shift is measured (the stage moved by -step)
    np.testing.assert_allclose(lineage.drift_um, -np.diff(origin, axis=0), atol=0.5)


def test_a_frame_without_cells_is_a_gap_in_every_track():
    cells = FrameCells(
        ids=[1, 2], x_um=[2.0, 5.0], y_um=[3.0, 3.0], angle_rad=[0.0, 0.0],
        length_um=[2.5, 2.5], width_um=[0.9, 0.9],
    )  # fmt: skip
    frames = [cells, FrameCells.empty(), cells]
    lineage = link_cells(frames, image_size_um=(8.0, 8.0))
    assert [ids.tolist() for ids in lineage.track_ids] == [[1, 2], [], [1, 2]]
    assert lineage.tracks.tolist() == [[1, 0, 2, 0], [2, 0, 2, 0]]
    assert lineage.gaps == ((1, 1), (2, 1))
    # CTC: a track is present from its first to its last frame, so the stretch after
    # the gap is a new label whose parent is the stretch before it
    assert lineage.ctc_text() == "1 0 0 0\n2 0 0 0\n3 2 2 1\n4 2 2 2\n"
    assert [ids.tolist() for ids in lineage.ctc_labels()[1]] == [[1, 2], [], [3, 4]]
    assert lineage.table()[0]["missing_frames"] == [1]
    assert lineage.table(frames=[10, 11, 12])[0] == {
        "track": 1, "first_frame": 10, "last_frame": 12, "parent": 0, "missing_frames": [11]
    }  # fmt: skip
    # without gap closing, every track ends there
    plain = link_cells(frames, LinkSettings(close_gaps=False), image_size_um=(8.0, 8.0))
    assert [ids.tolist() for ids in plain.track_ids] == [[1, 2], [], [3, 4]]
    assert plain.tracks.tolist() == [[1, 0, 0, 0], [2, 0, 0, 0], [3, 2, 2, 0], [4, 2, 2, 0]]
    assert plain.ctc_text() == "1 0 0 0\n2 0 0 0\n3 2 2 0\n4 2 2 0\n"
    assert plain.gaps == ()


def _drop(observed, truth_ids, simulation, every: int = 3):
    """Every ``every``-th frame loses one cell that neither was born in it nor divides
    after it (a cell the fit missed); returns the frames and the ``(frame, id)`` dropped."""
    frames, ids, dropped = list(observed), list(truth_ids), []
    for t in range(2, len(observed) - 2, every):
        keep = [
            k for k, c in enumerate(truth_ids[t].tolist())
            if c in truth_ids[t - 1] and c in truth_ids[t + 1]
            and simulation.lineage[c].end_frame > t + 1
        ]  # fmt: skip
        if not keep:
            continue
        k = keep[len(keep) // 2]
        mask = np.arange(len(observed[t])) != k
        cells = observed[t]
        frames[t] = FrameCells(
            ids=cells.ids[mask], x_um=cells.x_um[mask], y_um=cells.y_um[mask],
            angle_rad=cells.angle_rad[mask], length_um=cells.length_um[mask],
            width_um=cells.width_um[mask],
        )  # fmt: skip
        ids[t] = truth_ids[t][mask]
        dropped.append((t, int(truth_ids[t][k])))
    return frames, ids, dropped


def _same_identities(a, ids_a, b, ids_b):
    """Whether two lineages give the same cells the same tracks and parents (up to the
    tracks' numbering), over the cells present in both."""
    pairs = {}
    for t in range(len(a.track_ids)):
        for cell, track in zip(ids_b[t].tolist(), b.track_ids[t].tolist()):
            other = a.track_ids[t][ids_a[t].tolist().index(cell)]
            if pairs.setdefault(int(other), track) != track:
                return False
    if len(set(pairs.values())) != len(pairs):
        return False
    return all(
        b.parent(pairs[track]) == (pairs[a.parent(track)] if a.parent(track) else 0)
        for track in pairs
    )


def _write_ctc(lineage, frames, folder, pixel_um: float = 0.2):
    """A CTC result folder: each cell a 3 x 3 px square at its centre, labelled as
    :meth:`Lineage.track_mask` labels it."""
    import tifffile

    folder.mkdir(parents=True)
    for t, cells in enumerate(frames):
        labels = np.zeros((200, 200), np.int64)
        for i, x, y in zip(cells.ids, cells.x_um, cells.y_um):
            r, c = int(np.clip(y / pixel_um, 1, 198)), int(np.clip(x / pixel_um, 1, 198))
            labels[r - 1 : r + 2, c - 1 : c + 2] = i
        tifffile.imwrite(folder / f"mask{t:03d}.tif", lineage.track_mask(t, labels, cells.ids))
    (folder / "res_track.txt").write_text(lineage.ctc_text())


@pytest.mark.parametrize("where", ["trench", "colony"])
def test_a_cell_missed_in_one_frame_keeps_its_track(where, tmp_path):
    """The cells as a fit reports them, one cell left out every third frame: each such
    track skips that frame (a gap) instead of ending, and every other identity, link and
    division is as without the misses; the CTC result passes py-ctcmetrics' validator."""
    import contextlib
    import io

    from ctc_metrics import validate_sequence

    rng = np.random.default_rng(4)
    if where == "trench":
        simulation = trench_simulation(seed=1, n_frames=30)
        offset = (TRENCH.margin_um, TRENCH.margin_um)
        observed, truth_ids = observe(simulation.frames, rng, offset, noise_um=0.05)
        options = {"trench": [PLACEMENT] * len(observed), "image_size_um": IMAGE_UM}
    else:
        pad = AgarPadGeometry(
            field_width_um=24.0, field_height_um=24.0, n_colonies=3, scattered_cells=2,
            colony_separation_um=6.0, edge_margin_um=4.0,
        )  # fmt: skip
        simulation = simulate(SimulationSettings(
            n_frames=14, geometry="agar_pad", agar_pad=pad, n_founders=3,
            frame_interval_min=5.0, cell_width_um=0.9, seed=1,
        ))  # fmt: skip
        origin = 4.0 + np.cumsum(np.r_[[[0, 0]], np.full((13, 2), [0.3, -0.2])], axis=0)
        observed, truth_ids = observe(in_view(simulation.frames, origin, (16.0, 16.0)), rng,
                                      noise_um=0.05)  # fmt: skip
        options = {"image_size_um": (16.0, 16.0)}
    complete = link_cells(observed, **options)
    frames, ids, dropped = _drop(observed, truth_ids, simulation)
    assert len(dropped) >= 4
    gappy = link_cells(frames, **options)
    assert _same_identities(complete, truth_ids, gappy, ids)
    gaps = []
    for t, cell in dropped:
        before = gappy.track_ids[t - 1][ids[t - 1].tolist().index(cell)]
        after = gappy.track_ids[t + 1][ids[t + 1].tolist().index(cell)]
        assert before == after  # the same track on both sides of the miss
        gaps.append((int(before), t))
    assert sorted(gaps) == list(gappy.gaps)
    # without gap closing, each miss ends a track and starts another
    plain = link_cells(frames, LinkSettings(close_gaps=False), **options)
    assert len(plain.tracks) == len(gappy.tracks) + len(dropped)
    rows, _labels = gappy.ctc_labels()
    assert len(rows) == len(gappy.tracks) + len(dropped)
    _write_ctc(gappy, frames, tmp_path / "01_RES")
    with contextlib.redirect_stdout(io.StringIO()):
        assert validate_sequence(str(tmp_path / "01_RES"), threads=1)["Valid"] == 1


def test_no_track_crosses_into_another_field():
    """Found as a user: a series of unrelated fields (a stage jump) was linked wherever
    cells happened to lie close. Frames named unrelated start new tracks: no link, no
    division and no link over a gap reaches across them."""
    cells = FrameCells(
        ids=[1, 2], x_um=[2.0, 5.0], y_um=[3.0, 3.0], angle_rad=[0.0, 0.0],
        length_um=[2.5, 2.5], width_um=[0.9, 0.9],
    )  # fmt: skip
    linked = link_cells([cells] * 3, image_size_um=(8.0, 8.0))
    assert linked.tracks.tolist() == [[1, 0, 2, 0], [2, 0, 2, 0]]
    jumped = link_cells([cells] * 3, image_size_um=(8.0, 8.0), unrelated_frames=[2])
    assert [ids.tolist() for ids in jumped.track_ids] == [[1, 2], [1, 2], [3, 4]]
    assert jumped.tracks.tolist() == [[1, 0, 1, 0], [2, 0, 1, 0], [3, 2, 2, 0], [4, 2, 2, 0]]
    # a missing frame between two fields is no gap to close either
    over_gap = link_cells([cells, FrameCells.empty(), cells], image_size_um=(8.0, 8.0),
                          unrelated_frames=[1])  # fmt: skip
    assert over_gap.gaps == ()
    assert [ids.tolist() for ids in over_gap.track_ids] == [[1, 2], [], [3, 4]]
    with pytest.raises(ValueError, match=r"unrelated_frames must name frames 1\.\.2"):
        link_cells([cells] * 3, unrelated_frames=[0])


def test_bad_link_settings_and_inputs_are_refused():
    with pytest.raises(ValueError, match="gate_um must be a positive number"):
        LinkSettings(gate_um=0.0)
    with pytest.raises(ValueError, match="growth_per_frame must be a positive ratio"):
        LinkSettings(growth_per_frame=-1.0)
    with pytest.raises(ValueError, match="at least one frame"):
        link_cells([])
    with pytest.raises(ValueError, match="give one per frame"):
        link_cells([FrameCells.empty()] * 2, trench=[PLACEMENT])


def test_track_masks_and_napari_tracks_keep_each_track_through_gaps_and_divisions():
    """Track 1 is missed in frame 1 (a gap) and seen again in frame 2; track 2 divides
    into 3 and 4 after frame 0; cell id 9 of frame 2 is not a tracked cell. The masks
    keep a track's id across its gap, and the Tracks rows are the centroids, with the
    division as napari's graph."""
    from napari_symbac.fit.lineage import Lineage

    lineage = Lineage(
        track_ids=(np.array([1, 2]), np.array([3, 4]), np.array([1, 3, 4])),
        tracks=np.array([[1, 0, 2, 0], [2, 0, 0, 0], [3, 1, 2, 2], [4, 1, 2, 2]]),
        growth_per_frame=1.1,
        drift_um=np.zeros((2, 2)),
        gaps=((1, 1),),
    )
    frames = np.zeros((3, 20, 30), np.int64)
    frames[0, 2:6, 2:10] = 11  # track 1
    frames[0, 10:14, 2:20] = 12  # track 2
    frames[1, 10:14, 2:10] = 5  # track 3
    frames[1, 10:14, 12:20] = 6  # track 4
    frames[2, 3:7, 3:11] = 7  # track 1 again
    frames[2, 10:14, 2:11] = 8  # track 3
    frames[2, 10:14, 13:21] = 2  # track 4
    frames[2, 16:18, 0:4] = 9  # not tracked
    ids = [np.array([11, 12]), np.array([5, 6]), np.array([7, 8, 2])]
    masks = lineage.track_masks(list(frames), ids)
    assert masks.dtype == np.uint32
    assert masks.shape == frames.shape
    assert [masks[0, 3, 3], masks[2, 4, 4], masks[2, 11, 15]] == [1, 1, 4]
    assert masks[2, 17, 1] == 0
    assert set(np.unique(masks[1])) == {0, 3, 4}
    data, graph = lineage.napari_tracks(masks)
    assert graph == {3: [2], 4: [2]}
    assert data[:, :2].tolist() == [[1, 0], [1, 2], [2, 0], [3, 1], [3, 2], [4, 1], [4, 2]]
    np.testing.assert_allclose(data[0, 2:], [3.5, 5.5])  # rows 2-5, columns 2-9
    np.testing.assert_allclose(data[1, 2:], [4.5, 6.5])
    # napari takes them as they are (the layer's own checks of ids, times and graph)
    from napari.layers import Tracks

    layer = Tracks(data, graph=graph)
    assert layer.graph == graph
    with pytest.raises(ValueError, match="frame 1 has 2 tracked cells but 1 ids"):
        lineage.track_masks(list(frames), [ids[0], ids[1][:1], ids[2]])
    with pytest.raises(ValueError, match="3 frames but 2 masks"):
        lineage.track_masks(list(frames[:2]), ids[:2])
    with pytest.raises(ValueError, match=r"masks must be \(T, Y, X\) with T = 3"):
        lineage.napari_tracks(masks[0])


@pytest.fixture(scope="module")
def trench_series():
    """Frames 11-14 of a simulated trench, rendered and fitted jointly: cells 6 and 7
    grow, 8 is pushed out of the open end after frame 12, 6 divides after frame 12."""
    truth = render_trench_series(trench_simulation(seed=3), first=11, count=4)
    fit = fit_series(
        truth.stack, truth.microscope, START, None, irls_rounds=2, max_iterations=10,
        joint_iterations=5,
    )  # fmt: skip
    return truth, fit


@pytest.mark.slow
def test_fit_series_keeps_identities_through_a_division_and_an_exit(trench_series):
    truth, fit = trench_series
    assert [len(f.cells) for f in fit.frames] == [len(c) for c in truth.cells]
    # each fitted cell matched to the simulator's by its centre
    truth_ids = []
    for frame, cells in zip(fit.frames, truth.cells):
        y_true = cells.y_um + TRENCH.margin_um
        nearest = [int(np.argmin(np.abs(y_true - y))) for y in frame.cells.y_um]
        assert sorted(nearest) == list(range(len(cells)))
        truth_ids.append(cells.ids[nearest])
    want = truth_relations(truth.simulation, truth_ids, first=truth.first_frame)
    assert lineage_relations(fit.lineage) == want
    kinds = {relation[0] for step in want for relation in step.values()}
    assert kinds == {"link", "division"}
    assert len(fit.lineage.divisions()) == 1
    assert len(fit.lineage.tracks) == 5
    # the cell pushed out ends its track at frame 1 (simulator frame 12) without daughters
    exited = [t for t, b, e, p in fit.lineage.tracks.tolist() if e == 1 and
              t not in fit.lineage.divisions()]  # fmt: skip
    assert len(exited) == 1
    assert fit.track_ids is fit.lineage.track_ids


def test_fit_series_names_a_frame_without_cells():
    truth = render_trench_series(trench_simulation(seed=3), first=11, count=1)
    blank = ForwardModel(truth.microscope, TRUTH, Camera()).render(
        draw_scene(FrameCells.empty(), TRENCH, truth.microscope, TRUTH),
        np.random.default_rng(0),
    )
    stack = np.stack([truth.stack[0], blank])
    with pytest.raises(ValueError, match=r"frame 1 of the series: .*no cells.*separate series"):
        fit_series(stack, truth.microscope, START, None, irls_rounds=1, max_iterations=3,
                   moves=False)  # fmt: skip


@pytest.mark.slow
def test_growth_prior_gives_cells_cut_by_the_edge_their_length(trench_series):
    """The bottom cell of frame 1 and the lowest of frame 3 cross the open end: alone,
    their fitted lengths are only what is in view; tied to their grown past (0.1 um),
    they come closer to the truth, and the whole cells stay as they were."""
    truth, plain = trench_series
    tied = fit_series(
        truth.stack, truth.microscope, START, None, irls_rounds=2, max_iterations=10,
        joint_iterations=5, growth_prior_sd_um=0.1,
    )  # fmt: skip

    def errors(fit):
        whole, cut = [], []
        for frame, cells in zip(fit.frames, truth.cells):
            y_true = cells.y_um + TRENCH.margin_um
            for y, length in zip(frame.cells.y_um, frame.cells.length_um):
                k = int(np.argmin(np.abs(y_true - y)))
                crosses = y_true[k] + cells.length_um[k] / 2 > IMAGE_UM[0]
                (cut if crosses else whole).append(abs(length - cells.length_um[k]))
        return np.array(whole), np.array(cut)

    whole_plain, cut_plain = errors(plain)
    whole_tied, cut_tied = errors(tied)
    assert cut_plain.size == cut_tied.size == 3
    assert cut_tied.sum() < 0.6 * cut_plain.sum()
    assert whole_tied.max() < 0.06
    assert whole_plain.max() < 0.06
    np.testing.assert_array_equal(tied.lineage.tracks, plain.lineage.tracks)
    with pytest.raises(ValueError, match="growth_prior_sd_um must be zero"):
        fit_series(truth.stack, truth.microscope, START, None, growth_prior_sd_um=-1.0)


@pytest.fixture(scope="module")
def pad_series():
    """Frames 2-5 of a fluorescence pad (two founders apart, drifting 0.2-0.4 um per
    frame): both founders divide after frame 1 of the four (simulator frame 3), their
    daughters lying end to end."""
    truth = render_pad_series(seed=1, first=2, count=4)
    start = RenderSettings(defocus_sigma_um=0.0)
    return truth, fit_series(truth.stack, truth.microscope, start, None, geometry="open")


@pytest.mark.slow
def test_just_divided_fluorescent_daughters_are_fitted_apart_and_linked(pad_series):
    """The daughters touch end to end: the fluorescence dips at the septum (the
    rounded poles), so a move cuts each mother there the frame they appear (the
    reseed at the blob's finer maxima, else the split at the septum), and every
    relation to the previous frame is the simulator's."""
    truth, fit = pad_series
    frames = truth.simulation.frames[truth.first_frame : truth.first_frame + 4]
    assert [len(f.cells) for f in fit.frames] == [len(c) for c in frames] == [2, 2, 4, 4]
    cuts = [m for m in fit.frames[2].moves if "at its septum" in m or "touching cells" in m]
    assert len(cuts) >= 1
    truth_ids = []
    for frame, cells, origin in zip(fit.frames, frames, truth.origins_um):
        distance = np.hypot(
            frame.cells.x_um[:, None] - (cells.x_um - origin[0])[None, :],
            frame.cells.y_um[:, None] - (cells.y_um - origin[1])[None, :],
        )
        nearest = distance.argmin(axis=1)
        assert sorted(nearest.tolist()) == list(range(len(cells)))
        assert distance.min(axis=1).max() < 0.15  # each fitted cell on its own true cell
        truth_ids.append(cells.ids[nearest])
    want = truth_relations(truth.simulation, truth_ids, first=truth.first_frame)
    assert sum(len(step) for step in want) == 10
    assert lineage_relations(fit.lineage) == want
    assert len(fit.lineage.divisions()) == 2
    assert fit.lineage.gaps == ()


@pytest.mark.slow
def test_a_touching_fluorescent_colony_is_cut_into_its_cells():
    """One colony of two founders (docs/scripts/fit_touching_colony.py), simulator
    frame 4: its four cells touch, so the start's detector sees one blob; the reseed
    move cuts it at the finer maxima and every fitted cell lies on its own true cell
    (before it the fit had 3 rods there, one across two cells)."""
    from napari_symbac.fit import fit_scene
    from napari_symbac.fit.bright_start import bright_instances

    truth = render_pad_series(seed=0, first=1, count=4, colonies=1)
    px = truth.microscope.pixel_size_um
    image = truth.stack[3]
    frames = truth.simulation.frames[truth.first_frame : truth.first_frame + 4]
    cells = in_view(list(frames), truth.origins_um, (96 * px, 96 * px))[3]
    assert bright_instances(image, px).max() == 1
    fit = fit_scene(image, truth.microscope, RenderSettings(defocus_sigma_um=0.0), None,
                    geometry="open")  # fmt: skip
    assert len(fit.cells) == len(cells) == 4
    distance = np.hypot(
        fit.cells.x_um[:, None] - cells.x_um[None, :],
        fit.cells.y_um[:, None] - cells.y_um[None, :],
    )
    assert sorted(distance.argmin(axis=1).tolist()) == [0, 1, 2, 3]
    assert distance.min(axis=1).max() < 0.15
    assert any("touching cells" in move for move in fit.moves)


@pytest.mark.slow
def test_a_series_frame_starts_from_the_previous_frames_cells():
    """The touching colony's frames 5 and 6 (docs/scripts/fit_touching_colony.py): in
    frame 6 two cells meet at a T without a valley between them (in the 7-frame series
    the frame's own start fits 4 cells for 5 there). Started from frame 5's fitted
    cells moved by the drift, the fit is kept by the BIC and puts each of the 5 cells
    in view on its own cell."""
    truth = render_pad_series(seed=0, first=1, count=6, colonies=1)
    px = truth.microscope.pixel_size_um
    size_um = (96 * px, 96 * px)
    frames = truth.simulation.frames[truth.first_frame : truth.first_frame + 6]
    cells = in_view(list(frames), truth.origins_um, size_um)[5]
    fit = fit_series(truth.stack[4:6], truth.microscope, RenderSettings(defocus_sigma_um=0.0),
                     None, geometry="open")  # fmt: skip
    fitted = fit.frames[1].cells
    inside = (fitted.x_um >= 0) & (fitted.x_um <= size_um[1])
    inside &= (fitted.y_um >= 0) & (fitted.y_um <= size_um[0])
    distance = np.hypot(
        fitted.x_um[inside, None] - cells.x_um[None, :],
        fitted.y_um[inside, None] - cells.y_um[None, :],
    )
    assert fit.carried == (False, True)
    assert inside.sum() == len(cells) == 5
    assert sorted(distance.argmin(axis=1).tolist()) == [0, 1, 2, 3, 4]
    assert distance.min(axis=1).max() < 0.15


def test_cells_cut_by_the_edge_of_a_drifting_real_colony_are_not_divisions(real_data_dir):
    """Real masks: three 200 x 200 px windows of the Omnipose colony Sample000193 stepped
    like a drifting stage (one mask image, so a label is one cell throughout and nothing
    divides). A cell cut by the image's edge shows less of itself as the stage drifts;
    told which cells the edge cuts, the linker takes none of them for a division's lone
    daughter (without: 6 divisions), and every label keeps its track: a cell lying along
    the edge shows a sliver of itself, whose width and axis are not the cell's, so they
    are not compared (without: 8 of the 124 restart their track)."""
    import math

    import tifffile

    from napari_symbac.fit.start import cells_from_instances, cut_by_edge

    full = tifffile.imread(real_data_dir / "omnipose" / "Sample000193_cp_masks.tif")
    pixel_um = 0.0745
    windows = [full[r : r + 200, c : c + 200] for r, c in ((208, 300), (204, 305), (200, 312))]
    cells = [cells_from_instances(w, pixel_um, math.inf, keep_labels=True)[0] for w in windows]
    size_um = (200 * pixel_um, 200 * pixel_um)
    flags = [cut_by_edge(w, c.ids) for w, c in zip(windows, cells)]
    assert all(f.any() for f in flags)  # the edge cuts cells in every window
    lineage = link_cells(cells, image_size_um=size_um, cut_by_edge=flags)
    assert lineage.divisions() == {}
    kept = total = 0
    for t in range(2):
        before = dict(zip(cells[t].ids.tolist(), lineage.track_ids[t].tolist()))
        after = dict(zip(cells[t + 1].ids.tolist(), lineage.track_ids[t + 1].tolist()))
        common = set(before) & set(after)
        total += len(common)
        kept += sum(before[k] == after[k] for k in common)
    assert total == 124
    assert kept == total
    with pytest.raises(ValueError, match="one flag per cell"):
        link_cells(cells, image_size_um=size_um, cut_by_edge=flags[:2])

