"""fit_colony_series: a phase-colony time-lapse from its masks, optics fitted jointly."""

from __future__ import annotations

import dataclasses

import imageio.v3 as iio
import numpy as np
import pytest
import tifffile

from napari_symbac.fit import fit_colony_series
from napari_symbac.fit.colony import colony_start
from napari_symbac.optics import ForwardModel
from napari_symbac.settings import Camera, Microscope

MICROSCOPE = Microscope(pixel_size_um=0.0745, wavelength_um=0.55, modality="phase")
#: Sample000193 (Omnipose, MIT): half cells, half pad with the halo (as test_colony.py).
ROWS, COLS = slice(80, 176), slice(336, 432)


@pytest.fixture(scope="module")
def sample193(real_data_dir):
    folder = real_data_dir / "omnipose"
    image = np.asarray(iio.imread(folder / "Sample000193.png")[..., 0])  # grey RGB
    masks = np.asarray(tifffile.imread(folder / "Sample000193_cp_masks.tif"), np.int64)
    return image, masks


def _divided(masks: np.ndarray) -> tuple[np.ndarray, int]:
    """``masks`` with its longest whole cell cut in two across its long axis (a
    division): returns the masks and the mother's label."""
    labels = [k for k in np.unique(masks) if k]
    inner = masks[1:-1, 1:-1]

    def extent(k: int) -> float:
        y, x = np.nonzero(masks == k)
        return float(np.ptp(x) + np.ptp(y))

    whole = [k for k in labels if (inner == k).sum() == (masks == k).sum()]
    mother = max(whole, key=extent)
    y, x = np.nonzero(masks == mother)
    points = np.stack([x - x.mean(), y - y.mean()])
    axis = np.linalg.eigh(np.cov(points))[1][:, -1]
    out = masks.copy()
    out[y[axis @ points > 0], x[axis @ points > 0]] = masks.max() + 1
    return out, int(mother)


def test_a_rendered_time_lapse_keeps_its_optics_levels_and_division(sample193):
    """Truth known: the real colony's masks, and the same masks one frame later with a
    cell divided, rendered with chosen optics at two lamp levels. The optics come from
    the joint fit, within 3 of its standard errors of the truth, each frame's level
    within 2 %, both frames at the noise, and the lineage has the division."""
    _, full = sample193
    masks0 = full[ROWS, COLS]
    masks1, mother = _divided(masks0)
    start, _ = colony_start(masks0, MICROSCOPE, 80.0, 1.0)
    truth = dataclasses.replace(
        start, cell_phase_rad=0.45, apodisation_sigma_um=2.6, phase_ring_width_scale=1.15
    )
    rng = np.random.default_rng(3)
    frames = []
    for masks, level in ((masks0, 90.0), (masks1, 80.0)):
        scene = colony_start(masks, MICROSCOPE, 80.0, 1.0)[1]
        lit = dataclasses.replace(
            truth, media_intensity=level, cell_intensity=level, device_intensity=level
        )
        clean = ForwardModel(MICROSCOPE, lit, Camera()).render_clean(scene, cache=False)
        frames.append(clean + rng.normal(0.0, 1.0, clean.shape))
    fit = fit_colony_series(
        np.stack(frames), MICROSCOPE, np.stack([masks0, masks1]), Camera(baseline_adu=0.0)
    )
    shared = fit.shared()
    for name in ("cell_phase_rad", "apodisation_sigma_um", "phase_ring_width_scale"):
        assert shared[name][0] == pytest.approx(getattr(truth, name), rel=0.05), name
        assert shared[name][1] > 0, name
        assert abs(shared[name][0] - getattr(truth, name)) < 3 * shared[name][1], name
    before, after = fit.joint_objective
    assert after <= before
    assert fit.media_levels() == pytest.approx([90.0, 80.0], rel=0.02)
    for frame in fit.frames:
        assert frame.objective_after < 1.3 < frame.objective_before
    assert fit.frames[1].render.cell_phase_rad == fit.render.cell_phase_rad  # shared
    # the division: the mother's track ends in two daughters in frame 1
    mother_index = int(np.flatnonzero(fit.frames[0].cells.ids == mother)[0])
    mother_track = int(fit.lineage.track_ids[0][mother_index])
    assert len(fit.lineage.divisions().get(mother_track, ())) == 2
    n_tracks_continued = int(np.isin(fit.lineage.track_ids[1], fit.lineage.track_ids[0]).sum())
    assert n_tracks_continued == len(fit.frames[0].cells) - 1  # all but the mother


def test_a_drifting_real_colony_is_tracked_through_the_drift(sample193):
    """Real pixels: two windows of the real colony 3 px apart (a stage drift), each
    with its own masks. The second frame drawn with the first's optics fits as well as
    the first (the optics are the microscope's), and every cell whole in both windows
    keeps its track, the drift found."""
    image, full = sample193
    shift_y, shift_x = 3, -2
    later = (
        slice(ROWS.start - shift_y, ROWS.stop - shift_y),
        slice(COLS.start - shift_x, COLS.stop - shift_x),
    )
    stack = np.stack([image[ROWS, COLS], image[later]])
    masks = np.stack([full[ROWS, COLS], full[later]])
    fit = fit_colony_series(stack, MICROSCOPE, masks, max_evaluations=25)
    first, second = (fit.frames[t] for t in (fit.reference, 1 - fit.reference))
    assert second.objective_after < second.objective_before
    assert second.objective_after == pytest.approx(first.objective_after, rel=0.25)
    assert second.render.media_intensity == pytest.approx(first.render.media_intensity, rel=0.03)
    drift_um = fit.lineage.drift_um[0]
    pixel_um = MICROSCOPE.pixel_size_um
    assert drift_um == pytest.approx([shift_x * pixel_um, shift_y * pixel_um], abs=0.5 * pixel_um)
    # the masks' own labels are the truth of the links
    ids0, ids1 = fit.frames[0].cells.ids, fit.frames[1].cells.ids
    tracks0 = dict(zip(ids0.tolist(), fit.lineage.track_ids[0].tolist()))
    tracks1 = dict(zip(ids1.tolist(), fit.lineage.track_ids[1].tolist()))
    whole = [k for k in tracks0 if k in tracks1 and _whole(masks[0], k) and _whole(masks[1], k)]
    assert len(whole) >= 5
    assert all(tracks0[k] == tracks1[k] for k in whole)


def _whole(masks: np.ndarray, label: int) -> bool:
    """A cell not cut by the image's edge."""
    return (masks[1:-1, 1:-1] == label).sum() == (masks == label).sum()


def test_fit_colony_series_refuses_one_frame_and_missing_masks(sample193):
    image, full = sample193
    frame, masks = image[ROWS, COLS], full[ROWS, COLS]
    with pytest.raises(ValueError, match="at least 2 frames"):
        fit_colony_series(frame[None], MICROSCOPE, masks[None])
    with pytest.raises(ValueError, match="1 masks for 2 frames"):
        fit_colony_series(np.stack([frame, frame]), MICROSCOPE, masks[None])
