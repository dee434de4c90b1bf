"""Pieces of the fit command: input checks, the figure, the report, atomic writing."""

from __future__ import annotations

import math
from types import SimpleNamespace

import imageio.v3 as iio
import numpy as np
import pytest
import tifffile

from napari_symbac.figure_layout import panel_scale
from napari_symbac.fit.figure import before_after_figure
from napari_symbac.fit.preflight import (
    check_class_labels,
    check_fit_image,
    check_instance_masks,
    check_modality,
    image_polarity,
    modality_doubt,
    resolve_pixel_size,
)
from napari_symbac.fit.report import cells_records, fit_problems, report_text, write_atomically
from napari_symbac.settings import Microscope


def test_polarity_of_real_images(real_data_dir):
    root = real_data_dir / "colicoords" / "test_data" / "ds1"
    fluorescence = tifffile.imread(root / "fluorescence" / "00001.tif")
    brightfield = tifffile.imread(root / "brightfield" / "00001.tif")
    trench = tifffile.imread(real_data_dir / "ecoli_100x_oil_exponential.tiff")
    assert image_polarity(fluorescence) == "bright cells"
    assert image_polarity(brightfield) == "dark cells"
    assert image_polarity(trench) == "unclear"  # phase: dark cells with bright halos
    assert check_modality(trench, "phase") == "unclear"
    with pytest.raises(ValueError, match="--modality fluorescence"):
        check_modality(fluorescence, "phase")
    with pytest.raises(ValueError, match="--modality phase"):
        check_modality(brightfield, "fluorescence")


def test_bright_field_given_as_phase_is_noted(real_data_dir):
    """Found as a user: ColiCoords' bright field calibrated as phase passed the check
    (its masked cells are darker than their ring, as phase's are) and failed after the
    fit, "the image is flat between its percentiles". It shows no phase halo, nothing
    brighter than its background: said as a note (a sparse phase field with faint halos
    reads the same, so it is not refused), and the real phase colonies get none."""
    root = real_data_dir / "colicoords" / "test_data" / "ds1"
    brightfield = tifffile.imread(root / "brightfield" / "00001.tif")
    note = modality_doubt(brightfield, "phase")
    assert note is not None
    assert "if it is bright field, pass --modality brightfield" in note
    assert modality_doubt(brightfield, "brightfield") is None
    for colony in ("Sample000033", "Sample000193", "Sample000252"):  # phase, halos
        image = np.asarray(iio.imread(real_data_dir / "omnipose" / f"{colony}.png"))
        assert modality_doubt(image if image.ndim == 2 else image[..., 0], "phase") is None
    trench = tifffile.imread(real_data_dir / "ecoli_100x_oil_exponential.tiff")
    assert modality_doubt(trench, "phase") is None


def test_phase_contrast_given_as_bright_field_is_noted(real_data_dir):
    """Found as a user: SyMBac's phase trench fitted as bright field ended with exit 0
    and no word; its bright halos beside dark cells are phase contrast's look, which
    ColiCoords' bright-field fields (2 noise SDs above their median at most) lack."""
    trench = tifffile.imread(real_data_dir / "ecoli_100x_oil_exponential.tiff")
    assert "if it is phase contrast, pass --modality phase" in modality_doubt(
        trench, "brightfield"
    )
    for colony in ("Sample000033", "Sample000193", "Sample000252"):
        image = np.asarray(iio.imread(real_data_dir / "omnipose" / f"{colony}.png"))
        grey = image if image.ndim == 2 else image[..., 0]
        assert modality_doubt(grey, "brightfield") is not None
    for field in ("00001", "00002", "00003", "00004"):
        root = real_data_dir / "colicoords" / "test_data" / "ds1" / "brightfield"
        assert modality_doubt(tifffile.imread(root / f"{field}.tif"), "brightfield") is None


def test_labels_settle_the_polarity():
    rng = np.random.default_rng(0)
    image = rng.normal(1000, 10, (40, 40))
    labels = np.full((40, 40), 2, np.uint8)
    labels[10:20, 10:30] = 1
    image[labels == 1] += 300  # bright cells
    assert check_modality(image, "fluorescence", labels=labels) == "bright cells"
    with pytest.raises(ValueError, match="painted cells \\(1\\) are brighter than the media"):
        check_modality(image, "phase", labels=labels)


def test_input_checks_name_the_problem():
    def image(values) -> np.ndarray:  # each value an 8 x 8 px block: the least fitted
        return np.kron(np.array(values), np.ones((8, 8), np.array(values).dtype))

    with pytest.raises(ValueError, match="negative values"):
        check_fit_image(image([[-1.0, 2.0]]))
    with pytest.raises(ValueError, match=r"shape \(8, 7\) is too small to fit"):
        check_fit_image(image([[3.0, 17.0]])[:, :7])
    # a flattened image (ColiCoords' bright field: 0.89..1.12) is no camera's counts
    flattened = image(np.array([[0.8906, 1.0], [1.0031, 1.124]], np.float32))
    with pytest.raises(ValueError, match=r"normalised values .*napari_symbac\.io\.as_counts"):
        check_fit_image(flattened)
    check_fit_image(flattened.astype(np.float64) * 10000)  # as as_counts reads it: counts
    check_fit_image(image([[3.0, 17.0]]))  # whole numbers stored as floats: counts
    labels = np.ones((4, 4), np.uint8)
    with pytest.raises(ValueError, match="no media class"):
        check_class_labels(labels, (4, 4))
    with pytest.raises(ValueError, match="classes \\[7\\]"):
        check_class_labels(np.full((4, 4), 7, np.uint8), (4, 4))
    with pytest.raises(ValueError, match="has shape \\(4, 4\\)"):
        check_class_labels(labels, (5, 4))
    with pytest.raises(ValueError, match="no cell"):
        check_instance_masks(np.zeros((4, 4), np.uint16), (4, 4))
    with pytest.raises(ValueError, match="no background"):
        check_instance_masks(np.ones((4, 4), np.uint16), (4, 4))


def test_a_binary_mask_of_any_value_is_split_into_its_cells(real_data_dir):
    """Found as a user: ColiCoords' masks saved 0/255 (ImageJ's binary) were one cell of
    id 255 over 8 separate regions; calibrate then said after its fit that the cells
    were not brighter than the background. 0/1, boolean and 0/255 now give the same
    cells, and instance masks stay as they are."""
    from napari_symbac.calibrate.measure import instance_masks
    from napari_symbac.fit.preflight import as_instance_ids

    folder = real_data_dir / "colicoords" / "test_data" / "ds1" / "binary"
    masks = tifffile.imread(folder / "00001_Probabilities_filtered.tif")
    n_cells = np.count_nonzero(np.unique(masks))
    assert n_cells > 2
    for binary in (masks > 0, (masks > 0).astype(np.uint8), (masks > 0) * np.uint8(255)):
        ids, n_regions = as_instance_ids(binary)
        assert n_regions == n_cells
        np.testing.assert_array_equal(ids > 0, masks > 0)
        assert np.count_nonzero(np.unique(instance_masks(binary))) == n_cells
    same, n_regions = as_instance_ids(masks)
    assert n_regions is None
    assert same is masks


def test_a_binary_mask_of_touching_cells_is_refused(real_data_dir):
    """Found as a user: Omnipose's colony Sample000193 as a 0/1 mask was calibrated as one
    cell 8.9 um long (its connected region). Each real colony as 0/1 is refused (its
    region covers 2.3-4.5 times its width x length), every real mask of separate cells
    (ColiCoords' fields and single cell, as 0/1 too) and every instance mask passes."""
    real = real_data_dir
    colonies = sorted((real / "omnipose").glob("*_cp_masks.tif"))
    separate = [
        *sorted((real / "colicoords" / "test_data").glob("ds*/binary/*.tif")),
        real / "colicoords" / "test_data" / "ds3" / "binary.tif",
        real / "colicoords" / "01" / "binary.tif",
    ]
    assert len(colonies) == 3
    assert len(separate) == 14
    for path in [*colonies, *separate]:
        masks = tifffile.imread(path)
        masks = masks[0] if masks.ndim == 3 else masks
        check_instance_masks(masks, masks.shape)
        binary = (masks > 0).astype(np.uint8)
        if path in colonies:
            with pytest.raises(ValueError, match=r"cell/background mask.*Give instance masks"):
                check_instance_masks(binary, masks.shape, "--masks bin.tif")
        else:
            check_instance_masks(binary, masks.shape)


def test_instance_masks_given_as_class_labels_are_said_in_one_short_line():
    """Found as a user: `fit colony.png --labels colony_cp_masks.tif` listed all 113 cell
    numbers of the masks in the refusal."""
    masks = np.arange(120, dtype=np.uint16).reshape(10, 12) % 117
    with pytest.raises(ValueError, match="an instance mask goes to --masks") as refused:
        check_class_labels(masks, (10, 12), "--labels colony_cp_masks.tif")
    message = str(refused.value)
    assert "classes [4, 5, 6, 7, 8, ..., 116] (113 values)" in message
    assert len(message) < 250
    assert "--masks" in message


def test_the_pixel_size_comes_from_the_flag_or_files_that_agree():
    microscope = Microscope(pixel_size_um=0.065)
    same, note = resolve_pixel_size(0.0651, microscope)
    assert same is microscope
    assert "agree" in note
    kept, note = resolve_pixel_size(None, microscope)
    assert kept is microscope
    assert "records none" in note
    tiffs, note = resolve_pixel_size(0.08, microscope, microscope_gives_it=False)
    assert (tiffs.pixel_size_um, note) == (0.08, "pixel size 0.08 um from the TIFF")
    flagged, note = resolve_pixel_size(0.08, microscope, flag_pixel_um=0.1)
    assert (flagged.pixel_size_um, note) == (0.1, "pixel size 0.1 um from --pixel-size-um")


@pytest.mark.parametrize(
    ("file_um", "unset"), [(0.13, False), (1.0, True)]
)  # fmt: skip
def test_files_that_disagree_on_the_pixel_size_are_refused_naming_the_flag(file_um, unset):
    """Found as a user: the TIFF's value won over the microscope file's, so a TIFF saved
    with a 1 um scale (none set) fitted no cells, and one of 2 x 2 binning metadata on an
    unbinned image fitted cells of half their width, with exit 0."""
    with pytest.raises(ValueError, match="records a pixel size") as refused:
        resolve_pixel_size(file_um, Microscope(pixel_size_um=0.065))
    message = str(refused.value)
    assert f"records a pixel size of {file_um:g} um" in message
    assert f"--pixel-size-um 0.065 (or {file_um:g})" in message
    assert ("a scale that was never set" in message) == unset


@pytest.mark.parametrize(
    ("file_um", "given_um", "source"),
    [(None, 8.0, "from --microscope"), (6.5, 0.065, "recorded in the image file"),
     (None, 0.005, "from --microscope")],
)  # fmt: skip
def test_an_implausible_pixel_size_is_refused_with_the_fix(file_um, given_um, source):
    """A camera pixel given for the sample's (6.5 um), or nm read as um: the fit would
    place sub-pixel cells and exit 0 with nonsense (found by trying the CLI as a user)."""
    with pytest.raises(ValueError, match=f"um \\({source}.*camera pixel divided by"):
        resolve_pixel_size(file_um, Microscope(pixel_size_um=given_um))


def test_figure_is_upscaled_titled_and_has_a_colour_bar():
    rng = np.random.default_rng(1)
    real = rng.normal(1000, 30, (60, 20))
    residual = np.zeros_like(real)
    residual[:5] = 100.0  # a red stripe
    figure = before_after_figure(real, real, residual, start=real)
    scale = panel_scale(real.shape)
    assert scale == 10
    assert figure.dtype == np.uint8
    assert figure.shape[0] > 60 * scale  # panels plus a title row
    # four tall panels side by side, then the colour bar
    assert figure.shape[1] > 4 * 20 * scale
    bar = figure[28 : 28 + 60 * scale, 4 * (20 * scale + 8) + 5]  # below the title row
    assert bar[0, 0] > bar[0, 2]  # red (positive) at the top
    assert bar[-1, 2] > bar[-1, 0]  # blue at the bottom
    assert (figure < 100).all(axis=-1)[:28].any()  # dark title text
    wide = before_after_figure(rng.normal(size=(20, 60)), np.zeros((20, 60)), np.zeros((20, 60)))
    assert wide.shape[0] > wide.shape[1] / 3  # wide fields in two columns
    # a residual of thousands of ADU: its labels fit beside the bar (found as a user:
    # "+1.26e+04" was cut off at the figure's edge)
    for factor in (126.0, 12600.0):  # +12,600 and +1,260,000 ADU at the bar's top
        large = before_after_figure(real, real, residual * factor, start=real)
        text = (large[:, 4 * (20 * scale + 8) + 30 :] < 100).all(axis=-1)
        assert text.any()
        assert not text[:, -3:].any()  # nothing cut at the figure's edge
    assert large.shape[1] > figure.shape[1]  # widened for the longest label


def _result(**extra):
    cells = {
        "ids": [1, 2],
        "x_um": [1.0, 2.0],
        "length_um": [2.5, 3.0],
        "x_um_se": [0.01, math.nan],
    }
    base = {
        "cells": [0, 1],
        "cells_table": lambda: cells,
        "objective_before": 3.0,
        "objective_after": 1.1,
        "terms": {"pixel": (3.0, 1.1)},
    }
    return SimpleNamespace(**{**base, **extra})


def test_cells_records_and_report_say_what_went_wrong():
    result = _result(
        warnings=("round 2 stopped at the iteration limit",), at_bounds=("cell2.angle_rad",)
    )
    records = cells_records(result)
    assert records[1] == {"id": 2, "x_um": 2.0, "length_um": 3.0, "x_um_se": None}
    problems = fit_problems(result)
    assert any("iteration limit" in p for p in problems)
    assert any("at a bound" in p and "cell2.angle_rad" in p for p in problems)
    text = report_text(result, {"image": "x.tif"})
    assert "cells fitted: 2" in text
    assert "- warning: round 2" in text
    worse = _result(objective_after=4.0, warnings=(), at_bounds=())
    assert any("worse than its start" in p for p in fit_problems(worse))
    assert any("misses structure" in p for p in fit_problems(worse))
    # the engine's own warnings of both are said once each, with where to look
    engine = _result(
        objective_after=4.0,
        at_bounds=(),
        warnings=(
            "the fit is worse than its start (reduced chi-square 4 > 3)",
            "reduced chi-square 4: the model misses structure of the image, so the standard "
            "errors are too small",
        ),
        standard_errors=[0.1],
    )
    said = fit_problems(engine, residual_hint="see the residual layer")
    assert sum("worse than its start" in p for p in said) == 1
    assert [p for p in said if "reduced chi-square 4" in p and "misses" in p] == [
        "reduced chi-square 4 > 2: the model misses structure beyond the camera noise, so the "
        "standard errors are too small (see the residual layer)"
    ]
    clean = report_text(_result(warnings=(), at_bounds=()), {})
    assert "none: converged, nothing at a bound" in clean
    # a noise model far wider than the image's (a camera offset taken as 100 ADU)
    from napari_symbac.settings import Camera

    wide = _result(objective_after=0.22, warnings=(), at_bounds=(), camera=Camera())
    [said_wide] = [p for p in fit_problems(wide) if "< 0.5" in p]
    assert "baseline 100 ADU" in said_wide
    assert "too noisy" in said_wide
    assert not [p for p in fit_problems(_result(warnings=(), at_bounds=())) if "< 0.5" in p]
    assert "no convergence diagnostics" in report_text(_result(), {})


def test_the_report_names_the_closed_end_among_the_fits_choices_only_when_it_chose_one():
    """Found as a user: a trench whose closed end was out of view had "what the fit chose
    (the trench's closed end; ...)" over lines of merged cells only."""
    merged = report_text(_result(moves=("merged cells at y = 3.1 um",)), {})
    assert "  what the fit chose (cells added, removed, split or merged" in merged
    assert "closed end" not in merged
    both = report_text(_result(moves=("closed end: round, which fits better", "x")), {})
    assert "what the fit chose (the trench's closed end; cells added" in both


def test_a_wrong_pixel_size_is_said_through_the_cells_width(truth):
    """Found as a user: a trench of 0.065 um pixels fitted at 0.13 um gave 1.8 um wide,
    9-10 um long cells at the chi-square of the right pixel size, and nothing said it.
    The report now says the width is unusual for bacteria; at the right size it does not."""
    from napari_symbac.fit import fit_scene

    options = {"geometry": "trench", "irls_rounds": 1, "max_iterations": 4, "moves": False}
    said = {}
    for pixel_um in (truth.microscope.pixel_size_um, 2 * truth.microscope.pixel_size_um):
        microscope = Microscope(pixel_size_um=pixel_um)
        fit = fit_scene(truth.image, microscope, truth.render, truth.camera, **options)
        said[pixel_um] = [p for p in fit_problems(fit) if "unusual for bacteria" in p]
    assert said[truth.microscope.pixel_size_um] == []
    assert len(said[2 * truth.microscope.pixel_size_um]) == 1
    assert "check the pixel size" in said[2 * truth.microscope.pixel_size_um][0]


def test_atomic_write_leaves_nothing_on_failure(tmp_path):
    out = tmp_path / "out"

    def fail(path):
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        write_atomically(out, {"a.txt": lambda p: p.write_text("a"), "b.txt": fail})
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []
    writers = {"a.txt": lambda p: p.write_text("a"), "d/b.txt": lambda p: p.write_text("b")}
    written = write_atomically(out, writers)
    assert sorted(p.relative_to(out).as_posix() for p in written) == ["a.txt", "d/b.txt"]
    assert (out / "d" / "b.txt").read_text() == "b"


def test_a_cell_cut_by_the_image_edge_is_no_problem_one_wholly_outside_is():
    """Found as a user: a routine fit of SyMBac's trench listed "cell 4 has its centre
    outside the image" for a cell leaving the trench's open end, drawn into the image."""
    from _fit_synthetic import TRUTH, make_cells

    from napari_symbac._cli_fit import _cell_problems
    from napari_symbac.scene import Field, draw_scene
    from napari_symbac.settings import TrenchGeometry

    microscope, shape = Microscope(pixel_size_um=0.08), (64, 48)
    height_um, width_um = shape[0] * 0.08, shape[1] * 0.08
    cells = make_cells(y_um=[2.0, height_um + 0.4, height_um + 4.0], x_um=[1.9, 1.9, 1.9],
                       angle_rad=[0.0, 0.0, 0.0], length_um=[2.3, 2.2, 2.2])  # fmt: skip
    field = Field(width_um, height_um)
    scene = draw_scene(cells, TrenchGeometry(), microscope, TRUTH, field=field)
    assert set(np.unique(scene.camera_labels())) == {0, 1, 2}  # the cut cell is drawn
    fitted = SimpleNamespace(cells=cells, scene=scene)
    problems = _cell_problems(fitted, shape, microscope.pixel_size_um, None)
    assert len(problems) == 1
    assert problems[0].startswith("cell 3 lies outside the image")
