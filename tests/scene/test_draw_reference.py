"""The fast drawing gives the same bits as the original per-cell algorithm.

``reference_scene`` below is the drawing and mask code of ``scene/_draw.py`` as it
was before the drawing was vectorised (commit d154b16): a loop over the cells that
computes each cell's chord in its bounding box, keeps the thickest cell per pixel
and converts thickness to fractions, then the camera masks from the labels. It is
kept here, and only here, as the specification that the fast code in ``src`` must
match bit for bit: cells, media and labels at render resolution, and the instance
and semantic masks at camera resolution, for trench, round-ended trench, placed
trench, agar-pad and outline scenes with straight, tilted, axis-aligned, curved,
overlapping, coincident (exact ties) and partly outside cells, several seeds each.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from napari_symbac.scene import Field, draw_scene
from napari_symbac.scene._draw import _trench_images
from napari_symbac.scene._field import field_images
from napari_symbac.scene._raster import chord
from napari_symbac.settings import Microscope, RenderSettings, TrenchGeometry

MIC = Microscope()


# ---------------------------------------------------------------- the reference


def _ref_chord(xc, yc, centre_um, angle_rad, length_um, width_um, curvature):
    r = width_um / 2
    half = max(length_um / 2 - r, 0.0)
    dx = xc - centre_um[0]
    dy = yc - centre_um[1]
    sin_a, cos_a = math.sin(angle_rad), math.cos(angle_rad)
    s = np.add((dy * cos_a)[:, None], (dx * sin_a)[None, :])
    t = np.subtract((dx * cos_a)[None, :], (dy * sin_a)[:, None])
    if curvature is not None:
        a_um, b, c = curvature
        ell = np.clip((s + length_um / 2) / length_um, 0.0, 1.0)
        t -= a_um * np.sin(ell * math.pi / b + c)
    d = np.maximum(s, -half)
    np.minimum(d, half, out=d)
    np.subtract(s, d, out=d)
    np.square(d, out=d)
    np.square(t, out=t)
    np.add(d, t, out=d)
    np.sqrt(d, out=d)
    np.multiply(d, d, out=d)
    np.subtract(r * r, d, out=d)
    np.maximum(d, 0.0, out=d)
    np.sqrt(d, out=d)
    return np.multiply(2, d, out=np.empty(d.shape, np.float32), casting="same_kind")


def _ref_camera_masks(inner, u, camera_shape):
    rows, cols = camera_shape
    labels = np.array(inner[::u, ::u], np.uint32)
    if u > 1:
        mixed = np.zeros((rows, cols), bool)
        for dy in range(u):
            for dx in range(u):
                if dy or dx:
                    mixed |= inner[dy::u, dx::u] != labels
        ri, ci = np.nonzero(mixed)
        if ri.size:
            blocks = inner.reshape(rows, u, cols, u)[ri, :, ci, :].reshape(ri.size, u * u)
            counts = np.zeros(blocks.shape, np.uint8 if u * u < 256 else np.int64)
            for k in range(u * u):
                counts += blocks == blocks[:, k : k + 1]
            labels[ri, ci] = blocks[np.arange(ri.size), np.argmax(counts, axis=-1)]
    padded = np.pad(labels, 1)
    conflict = np.zeros((rows, cols), bool)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dy or dx:
                neighbour = padded[1 + dy : 1 + dy + rows, 1 + dx : 1 + dx + cols]
                conflict |= (neighbour > 0) & (neighbour < labels)
    semantic = ((labels > 0) & ~conflict).astype(np.uint8)
    return labels, semantic


def reference_scene(cells, trench, microscope, render, curvature=None, *, field=None,
                    trench_origin_um=None, camera_shape=None):
    """(cells, media, labels, camera labels, semantic) as drawn before vectorising."""
    ids = np.asarray(cells.ids).astype(np.int64)
    n = ids.shape[0]
    x, y, angle, length, width = (
        np.asarray(getattr(cells, k), np.float64)
        for k in ("x_um", "y_um", "angle_rad", "length_um", "width_um")
    )
    curv = {int(k): tuple(float(v) for v in val) for k, val in (curvature or {}).items()}
    curv = {k: v for k, v in curv.items() if v[0] != 0}
    u = render.upsample
    border = render.psf_radius_px
    cam_px = microscope.pixel_size_um
    px = cam_px / u
    if field is None:
        m = trench.margin_um
        off_x = off_y = m
        rows = round((trench.length_um + m) / cam_px)
        cols = round((trench.width_um + 2 * m) / cam_px)
        if trench_origin_um is not None:
            off_x, off_y = (float(v) for v in trench_origin_um)
        if camera_shape is not None:
            rows, cols = (int(v) for v in camera_shape)
        depth_um = trench.depth_um
    else:
        off_x, off_y = -field.origin_um[0], -field.origin_um[1]
        rows = round(field.height_um / cam_px)
        cols = round(field.width_um / cam_px)
        depth_um = field.depth_um
    shape = (rows * u + 2 * border, cols * u + 2 * border)
    yc = (np.arange(shape[0]) - border + 0.5) * px
    xc = (np.arange(shape[1]) - border + 0.5) * px
    if field is None:
        trench_frac, _, _ = _trench_images(
            shape, border, px, off_x, off_y, trench.width_um, trench.closed_end
        )
    else:
        trench_frac, _ = field_images(field, shape, border, px)

    boxes = []
    for i in range(n):
        r = width[i] / 2
        cx, cy = off_x + x[i], off_y + y[i]
        bend = curv.get(int(ids[i]))
        half_len = length[i] / 2
        half_wid = r + (abs(bend[0]) if bend else 0.0)
        sin_a, cos_a = abs(math.sin(angle[i])), abs(math.cos(angle[i]))
        reach_x = min(half_len * sin_a + half_wid * cos_a, half_len + half_wid) + 2 * px
        reach_y = min(half_len * cos_a + half_wid * sin_a, half_len + half_wid) + 2 * px
        j0 = max(math.floor((cx - reach_x) / px) + border, 0)
        j1 = min(math.ceil((cx + reach_x) / px) + border + 1, shape[1])
        i0 = max(math.floor((cy - reach_y) / px) + border, 0)
        i1 = min(math.ceil((cy + reach_y) / px) + border + 1, shape[0])
        if j0 < j1 and i0 < i1:
            boxes.append((i, i0, i1, j0, j1, cx, cy, bend))

    cells_frac = np.zeros(shape, np.float32)
    labels = np.zeros(shape, np.uint32)
    media = trench_frac.copy()
    if boxes:
        top = min(b[1] for b in boxes)
        bottom = max(b[2] for b in boxes)
        left = min(b[3] for b in boxes)
        right = max(b[4] for b in boxes)
        covered = sum((b[2] - b[1]) * (b[4] - b[3]) for b in boxes)
        dense = (bottom - top) * (right - left) <= 2 * covered
        if dense:
            thickness = np.zeros((bottom - top, right - left), np.float32)
            work_labels = np.zeros(thickness.shape, np.uint32)
            regions = [(slice(top, bottom), slice(left, right))]
        else:
            top = left = 0
            thickness = np.zeros(shape, np.float32)
            work_labels = labels
            regions = [(slice(b[1], b[2]), slice(b[3], b[4])) for b in boxes]
        for i, i0, i1, j0, j1, cx, cy, bend in boxes:
            local = (slice(i0 - top, i1 - top), slice(j0 - left, j1 - left))
            chord = _ref_chord(xc[j0:j1], yc[i0:i1], (cx, cy), angle[i], length[i], width[i], bend)
            box_t = thickness[local]
            take = chord > box_t
            np.maximum(box_t, chord, out=box_t)
            np.putmask(work_labels[local], take, np.uint32(ids[i]))
        depth = np.float32(depth_um)
        for region in regions:
            local = (
                slice(region[0].start - top, region[0].stop - top),
                slice(region[1].start - left, region[1].stop - left),
            )
            trench_box = np.array(trench_frac[region])
            frac = thickness[local] / depth
            np.minimum(frac, np.float32(1.0), out=frac)
            np.minimum(frac, trench_box, out=frac)
            cells_frac[region] = frac
            box_l = work_labels[local]
            np.putmask(box_l, frac <= 0, np.uint32(0))
            if dense:
                labels[region] = box_l
            np.subtract(trench_box, frac, out=trench_box)
            media[region] = np.maximum(trench_box, np.float32(0.0), out=trench_box)
    b = border
    inner = labels[b : shape[0] - b, b : shape[1] - b]
    cam_labels, semantic = _ref_camera_masks(inner, u, (rows, cols))
    return cells_frac, media, labels, cam_labels, semantic


# ---------------------------------------------------------------- the cases


def _random_cells(rng, n, x_range, y_range, *, tilt=math.pi, lengths=(1.2, 4.5)):
    width = rng.uniform(0.7, 1.2, n)
    return SimpleNamespace(
        ids=rng.permutation(np.arange(1, 3 * n + 1))[:n],
        x_um=rng.uniform(*x_range, n),
        y_um=rng.uniform(*y_range, n),
        angle_rad=rng.uniform(-tilt, tilt, n),
        length_um=np.maximum(rng.uniform(*lengths, n), width),
        width_um=width,
    )


def _with_ties(cells, rng):
    """Copy some cells onto others (same place, shape: equal chords) and add a bend."""
    n = cells.ids.size
    src = rng.choice(n, size=max(1, n // 6), replace=False)
    dst = (src + 1) % n
    for name in ("x_um", "y_um", "angle_rad", "length_um", "width_um"):
        getattr(cells, name)[dst] = getattr(cells, name)[src]
    curvature = {
        int(cells.ids[k]): (float(rng.uniform(-0.3, 0.3)), float(rng.uniform(0.5, 2)), 0.4)
        for k in rng.choice(n, size=max(1, n // 4), replace=False)
    }
    return cells, curvature


def _assert_same(scene, expected):
    cells, media, labels, cam_labels, semantic = expected
    for name, got, want in (
        ("cells", scene.cells, cells),
        ("media", scene.media, media),
        ("labels", scene.labels, labels),
        ("camera_labels", scene.camera_labels(), cam_labels),
        ("semantic_mask", scene.semantic_mask(), semantic),
    ):
        assert got.dtype == want.dtype, name
        assert got.shape == want.shape, name
        mismatch = np.flatnonzero(got.view(np.uint8) != want.view(np.uint8))
        assert mismatch.size == 0, f"{name}: {mismatch.size} bytes differ"


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
@pytest.mark.parametrize("closed_end", ["square", "round"])
def test_trench_scene_is_bit_identical(seed, closed_end):
    rng = np.random.default_rng(seed)
    trench = TrenchGeometry(length_um=12.0, width_um=1.4, margin_um=0.8, closed_end=closed_end)
    render = RenderSettings(upsample=3, psf_radius_px=14)
    cells, curvature = _with_ties(
        _random_cells(rng, 6, (0.2, 1.2), (-1.0, 14.0), tilt=0.25), rng
    )
    cells.x_um[0] = -0.4  # reaches into the PDMS wall: labels there are zeroed
    scene = draw_scene(cells, trench, MIC, render, curvature)
    _assert_same(scene, reference_scene(cells, trench, MIC, render, curvature))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_placed_trench_and_camera_shape_are_bit_identical(seed):
    rng = np.random.default_rng(10 + seed)
    trench = TrenchGeometry(length_um=10.0, width_um=1.3, margin_um=0.5)
    render = RenderSettings(upsample=2, psf_radius_px=9)
    cells, curvature = _with_ties(_random_cells(rng, 5, (0.0, 1.3), (0.0, 11.0)), rng)
    kwargs = {"trench_origin_um": (1.1, -0.4), "camera_shape": (150, 50)}
    scene = draw_scene(cells, trench, MIC, render, curvature, **kwargs)
    _assert_same(scene, reference_scene(cells, trench, MIC, render, curvature, **kwargs))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_agar_pad_scene_is_bit_identical(seed):
    rng = np.random.default_rng(20 + seed)
    field = Field(20.0, 16.0, origin_um=(-1.0, 0.5))
    render = RenderSettings(upsample=3, psf_radius_px=11)
    # Many cells, some overlapping and some partly or wholly outside the field.
    cells, curvature = _with_ties(_random_cells(rng, 60, (-3.0, 22.0), (-2.0, 19.0)), rng)
    scene = draw_scene(cells, TrenchGeometry(), MIC, render, curvature, field=field)
    expected = reference_scene(cells, TrenchGeometry(), MIC, render, curvature, field=field)
    _assert_same(scene, expected)
    assert len(np.unique(scene.labels)) > 40


@pytest.mark.parametrize("seed", [0, 1])
def test_cells_along_and_across_the_rows_are_bit_identical(seed):
    """Axes along the rows or the columns exactly and within 1e-9 rad of them (the
    compiled drawing's row spans treat those apart), straight and bent."""
    rng = np.random.default_rng(70 + seed)
    field = Field(16.0, 12.0)
    render = RenderSettings(upsample=3, psf_radius_px=7)
    cells, curvature = _with_ties(_random_cells(rng, 36, (-1.0, 17.0), (-1.0, 13.0)), rng)
    aligned = np.array([0.0, math.pi / 2, math.pi, -math.pi / 2, 1e-12, -1e-10, 2e-9])
    cells.angle_rad = aligned[np.arange(36) % 7] + np.repeat([0.0, 0.0, 0.0, math.pi / 2], 9)
    scene = draw_scene(cells, TrenchGeometry(), MIC, render, curvature, field=field)
    expected = reference_scene(cells, TrenchGeometry(), MIC, render, curvature, field=field)
    _assert_same(scene, expected)
    assert len(np.unique(scene.labels)) > 25


@pytest.mark.parametrize("first_id", [60_000, 4_000_000_000])
def test_labels_beyond_uint16_are_bit_identical(first_id):
    """Ids that fit uint16 are drawn into a uint16 image and ids beyond it into a uint32
    one; either way the labels read back are uint32 and the same bits."""
    rng = np.random.default_rng(60)
    field = Field(10.0, 8.0)
    render = RenderSettings(upsample=3, psf_radius_px=6)
    cells, curvature = _with_ties(_random_cells(rng, 25, (-1.0, 11.0), (-1.0, 9.0)), rng)
    cells.ids = cells.ids + first_id
    curvature = {k + first_id: v for k, v in curvature.items()}
    scene = draw_scene(cells, TrenchGeometry(), MIC, render, curvature, field=field)
    expected = reference_scene(cells, TrenchGeometry(), MIC, render, curvature, field=field)
    narrow = cells.ids.max() <= np.iinfo(np.uint16).max
    assert ("labels" in scene.__dict__) != narrow  # uint32 labels made on first read
    cam = scene.camera_labels()
    assert cam.min() == 0
    assert cam.max() > first_id  # no wrap-around
    assert np.isin(cam, np.append(cells.ids, 0)).all()
    _assert_same(scene, expected)


@pytest.mark.parametrize("depth_um", [0.8, 1.2])
def test_agar_pad_shallower_or_deeper_than_the_cells_is_bit_identical(depth_um):
    """A pad whose depth is below some cells' width (fractions capped at 1) or above all."""
    rng = np.random.default_rng(25)
    field = Field(14.0, 12.0, depth_um=depth_um)
    render = RenderSettings(upsample=3, psf_radius_px=8)
    cells, curvature = _with_ties(_random_cells(rng, 40, (-1.0, 15.0), (-1.0, 13.0)), rng)
    scene = draw_scene(cells, TrenchGeometry(), MIC, render, curvature, field=field)
    expected = reference_scene(cells, TrenchGeometry(), MIC, render, curvature, field=field)
    _assert_same(scene, expected)
    assert (scene.cells.max() == 1.0) == (cells.width_um.max() > depth_um)


@pytest.mark.parametrize("seed", [0, 1])
def test_outline_scene_is_bit_identical(seed):
    rng = np.random.default_rng(30 + seed)
    walls = (((0.0, 10.0), (0.0, 0.0), (6.0, 0.0), (6.0, 10.0)), ((2.0, 4.0), (4.5, 6.5)))
    field = Field(8.0, 12.0, origin_um=(-1.0, -1.0), walls_um=walls, wall_thickness_um=0.6)
    render = RenderSettings(upsample=4, psf_radius_px=10)
    cells, curvature = _with_ties(_random_cells(rng, 25, (-0.5, 6.5), (-0.5, 10.5)), rng)
    scene = draw_scene(cells, TrenchGeometry(), MIC, render, curvature, field=field)
    expected = reference_scene(cells, TrenchGeometry(), MIC, render, curvature, field=field)
    _assert_same(scene, expected)


def test_upsample_one_and_no_cells_are_bit_identical():
    rng = np.random.default_rng(40)
    trench = TrenchGeometry(length_um=8.0, width_um=1.4, margin_um=0.6)
    render = RenderSettings(upsample=1, psf_radius_px=5)
    cells, curvature = _with_ties(_random_cells(rng, 4, (0.2, 1.2), (0.0, 9.0)), rng)
    scene = draw_scene(cells, trench, MIC, render, curvature)
    _assert_same(scene, reference_scene(cells, trench, MIC, render, curvature))
    empty = _random_cells(rng, 0, (0.0, 1.0), (0.0, 1.0))
    scene = draw_scene(empty, trench, MIC, render)
    _assert_same(scene, reference_scene(empty, trench, MIC, render))


@pytest.mark.parametrize("geometry", ["trench", "agar_pad"])
def test_simulated_frames_are_bit_identical(geometry):
    """Frames of a real (short) simulation, curvature and all, as the pipeline draws them."""
    from napari_symbac.pipeline import _curvature
    from napari_symbac.scene import field_of
    from napari_symbac.settings import AgarPadGeometry, SimulationSettings
    from napari_symbac.sim import simulate

    settings = SimulationSettings(
        geometry=geometry,
        n_frames=40,
        seed=7,
        do_transformation=True,
        agar_pad=AgarPadGeometry(14.0, 12.0),
    )
    simulation = simulate(settings)
    render = RenderSettings(upsample=3, psf_radius_px=20)
    curvature = _curvature(simulation)
    assert curvature  # bent cells are drawn too
    field = field_of(simulation)
    for index in (5, 25, 39):
        frame = simulation.frames[index]
        scene = draw_scene(frame, settings.trench, MIC, render, curvature, field=field)
        expected = reference_scene(frame, settings.trench, MIC, render, curvature, field=field)
        _assert_same(scene, expected)
    assert len(frame.ids) > 3


@pytest.mark.parametrize("chunk_pixels", [1, 700, 5000])
def test_masks_computed_in_bands_are_bit_identical(monkeypatch, chunk_pixels):
    """Large frames compute the masks a band of rows at a time: bands of 1 to ~20 rows."""
    from napari_symbac.scene import _draw

    monkeypatch.setattr(_draw, "_MASK_CHUNK_PIXELS", chunk_pixels)
    rng = np.random.default_rng(50)
    field = Field(9.0, 7.0)
    render = RenderSettings(upsample=3, psf_radius_px=6)
    cells, curvature = _with_ties(_random_cells(rng, 30, (-1.0, 10.0), (-1.0, 8.0)), rng)
    scene = draw_scene(cells, TrenchGeometry(), MIC, render, curvature, field=field)
    expected = reference_scene(cells, TrenchGeometry(), MIC, render, curvature, field=field)
    _assert_same(scene, expected)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_bent_chord_near_the_axis_only_equals_the_whole_formula(seed):
    """Bends up to and beyond the radius, any phase: the sine is skipped only where it
    cannot matter, and every pixel keeps the full formula's bits."""
    rng = np.random.default_rng(seed)
    px = 0.065 / 3
    xc = np.arange(-150, 150) * px + rng.uniform(0, px)
    yc = np.arange(-160, 160) * px + rng.uniform(0, px)
    for _ in range(12):
        width = rng.uniform(0.5, 1.2)
        length = rng.uniform(width, 5.0)
        bend = (rng.uniform(-0.8, 0.8), rng.uniform(0.3, 2.0), rng.uniform(-1.0, 2.0))
        args = ((rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5)), rng.uniform(-4, 4), length, width)
        got = chord(xc, yc, *args, bend)
        want = _ref_chord(xc, yc, *args, bend)
        assert got.tobytes() == want.tobytes()
        assert np.count_nonzero(got) > 100
