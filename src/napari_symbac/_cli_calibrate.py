"""The ``napari-symbac calibrate`` command: fit a recording, export a matched dataset.

Inputs are checked (the ``fit`` command's refusals) and the fit runs before anything
is written; the dataset, report.txt, report.png and settings.yaml are made in a hidden
folder beside ``--out`` and moved in only when all of them are complete, so a refusal
or a failure leaves nothing half-written.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import shutil
import sys
from pathlib import Path

import numpy as np

from napari_symbac._timing import StepTimer, progress_bar
from napari_symbac.io import CountsMapping, Recording

__all__ = ["read_frame", "run_calibrate"]

def read_frame(
    path: str, what: str, frame: int | None = None, channel: int | None = None
) -> Recording:
    """One grey 2D frame from a TIFF (with its pixel size and modality) or a PNG
    (:func:`napari_symbac.io.read_image`; the IMAGE, when normalised, as counts, its
    ``counts_mapping`` kept): frame ``frame`` of a ``(T, Y, X)`` series, of channel
    ``channel`` of a TIFF of several."""
    from napari_symbac._cli_fit import read_recording

    recording = read_recording(path, what, counts=what == "IMAGE", channel=channel)
    data = np.asarray(recording.data)
    name = Path(path).name
    if data.ndim == 3 and frame is not None:
        if not 0 <= frame < len(data):
            raise ValueError(
                f"--frame {frame}: {what} {name} has frames 0..{len(data) - 1}"
            )
        data = data[frame]
    elif data.ndim == 3:
        raise ValueError(
            f"{what} {name} holds {len(data)} frames: pass --frame K (0..{len(data) - 1}) "
            "to calibrate on one of them"
        )
    if data.ndim != 2:
        raise ValueError(f"{what} {name} must be one 2D frame, got shape {data.shape}")
    if what == "IMAGE" and frame not in (None, 0) and np.ndim(recording.data) == 2:
        # found as a user: --frame 2 on a single frame was ignored, and calibrate ran on
        # frame 0 with exit 0 (a 2D --masks or --labels serves every frame, as the help says)
        raise ValueError(
            f"--frame {frame}: {what} {name} is one frame (frame 0): leave --frame out, "
            "or give the (T, Y, X) series the frame belongs to"
        )
    return dataclasses.replace(recording, data=data)


def _image_lines(path: str, image: np.ndarray, mapping: CountsMapping | None) -> list[str]:
    """report.txt's image line, and for a normalised image read as counts what its values
    are (``fit``'s report says the same)."""
    lines = [f"image: {path} ({image.shape[0]} x {image.shape[1]} px, {image.dtype})"]
    return lines + ([f"image values: {mapping.note}"] if mapping is not None else [])


def _settings_notes(notes: tuple[str, ...], mapping: CountsMapping | None) -> list[str]:
    """The notes of WHERE THE SETTINGS CAME FROM; for a normalised image read as counts,
    as ``fit``'s report: the camera's note marked as in those units, and a note that
    every ADU and e- is (so that its gain is not taken for a real camera's)."""
    if mapping is None:
        return list(notes)
    from napari_symbac._cli_fit import counts_units_mark, counts_units_note

    marked = [n + counts_units_mark(mapping) if n.startswith("camera:") else n for n in notes]
    return [*marked, counts_units_note(mapping)]


def _refuse_a_trench(image: np.ndarray, modality: str, path: str, args: argparse.Namespace) -> None:
    """calibrate lays a field out as an agar pad; a mother-machine trench (a phase image
    at most :data:`~napari_symbac.fit.preflight.TRENCH_MAX_WIDTH_PX` wide and twice as
    tall, the fit's own rule, :func:`~napari_symbac.fit.preflight.default_geometry`) is
    refused with the commands that match one (found as a user: DeLTA's trench became a
    2 x 17 um pad, and 3 of 4 images held no cell). The commands carry the user's own
    ``--microscope``, ``--pixel-size-um`` and ``--modality`` (they named a placeholder,
    M.yaml, and left out a pixel size given, so that the fit then refused)."""
    from napari_symbac.fit.preflight import default_geometry, lying_trench_problem

    name = Path(path).name
    lying = lying_trench_problem(image.shape, modality, f"IMAGE {name}")
    if lying or default_geometry(image.shape, modality) == "trench":
        given = "".join(
            f" {flag} {value}"
            for flag, value in (
                ("--microscope", args.microscope),
                ("--pixel-size-um", args.pixel_size_um),
                ("--modality", args.modality),
            )
            if value is not None
        )
        shape = (
            f"{lying}; and calibrate does not lay out a trench"
            if lying
            else f"IMAGE {name} is {image.shape[-2]} x {image.shape[-1]} px (rows x "
            "columns), narrow and tall: a mother-machine trench, which calibrate does not "
            "lay out"
        )
        image_path = Path(path)
        fitted = (  # the turned image (found as a user: the command named this one)
            image_path.with_name(f"{image_path.stem}_upright{image_path.suffix}")
            if lying
            else path
        )
        raise ValueError(
            f"{shape} (it matches fields: agar pads and colonies). Fit the trench"
            f"{', turned upright,' if lying else ''} and export from its settings: "
            f"`napari-symbac fit {fitted}{given} --out FIT`, then "
            "`napari-symbac export --config FIT/settings.yaml --out DATASET`"
        )


def _write_png(path: Path, rgb: np.ndarray) -> None:
    import imageio.v3 as iio

    iio.imwrite(path, rgb)


#: Widths (um) --cell-width-um takes: rods are 0.4-2 um wide (B. megaterium ~1.5).
CELL_WIDTH_RANGE_UM = (0.2, 5.0)


def _check_cell_width(cell_width_um: float | None, masks: str | None) -> None:
    """``--cell-width-um``: a positive width, and masks to measure it on."""
    if cell_width_um is None:
        return
    if not (np.isfinite(cell_width_um) and cell_width_um > 0):
        raise ValueError(
            f"--cell-width-um must be positive, got {cell_width_um}: give the cells' width "
            "in um (e.g. 1.0 for E. coli), or leave it out to use the microscope's pixel size"
        )
    if not CELL_WIDTH_RANGE_UM[0] <= cell_width_um <= CELL_WIDTH_RANGE_UM[1]:
        low, high = CELL_WIDTH_RANGE_UM  # found as a user: 1000 (nm) met a misleading error
        raise ValueError(
            f"--cell-width-um {cell_width_um:g} is outside {low:g}-{high:g} um, no bacterium's "
            "width: give it in um (e.g. 1.0 for E. coli, not 1000 nm)"
        )
    if masks is None:
        raise ValueError(
            "--cell-width-um sets the pixel size from the masks' cell widths: pass --masks too"
        )


def _check_inputs(
    args: argparse.Namespace,
    image: np.ndarray,
    masks: np.ndarray | None,
    labels: np.ndarray | None,
) -> None:
    """The fit's refusals of the image, masks and labels, naming the files as ``fit`` does."""
    from napari_symbac.fit.preflight import (
        check_class_labels,
        check_fit_image,
        check_instance_masks,
        refuse_constant,
    )

    name = Path(args.image).name
    check_fit_image(image, name)
    refuse_constant(image, name)
    if masks is not None:
        check_instance_masks(masks, image.shape, f"--masks {Path(args.masks).name}")
    if labels is not None:
        check_class_labels(labels, image.shape, f"--labels {Path(args.labels).name}")


def run_calibrate(args: argparse.Namespace) -> int:
    """Run ``napari-symbac calibrate`` with parsed arguments; returns the exit code."""
    from napari_symbac._cli_fit import check_stain_flags, in_read_units
    from napari_symbac.calibrate import (
        calibrate,
        compare_with_dataset,
        export_settings,
        items_words,
        montage,
    )
    from napari_symbac.diagnose.config import load_microscope_file
    from napari_symbac.export import export_dataset
    from napari_symbac.export.atomic import staging_folder, write_tiff
    from napari_symbac.fit.preflight import (
        modality_doubt,
        not_integer_masks,
        resolve_pixel_size,
    )
    from napari_symbac.settings import (
        Camera,
        load_settings,
        microscope_sets_pixel_size,
        save_settings,
    )

    timer = StepTimer()
    out = Path(args.out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        earlier = out.is_dir() and (out / "export_settings.yaml").is_file()
        raise ValueError(
            f"--out {out} exists and is not an empty folder: give a new folder (calibrate "
            "writes a whole dataset and will not mix it with other files)"
            + (  # found as a user: the same command run twice was refused without a word why
                "; it holds an earlier calibration (export_settings.yaml): delete that "
                "folder to calibrate again into it"
                if earlier
                else ""
            )
        )
    from napari_symbac.export.formats import FORMATS, tracking_formats

    formats = [f.strip().lower() for f in args.formats.split(",") if f.strip()]
    unknown = [f for f in formats if f not in FORMATS]
    if unknown or not formats:
        raise ValueError(
            f"--formats {args.formats!r}: unknown format(s) {', '.join(unknown) or '(none)'}; "
            f"known formats: {', '.join(FORMATS)}"
        )
    tracking = tracking_formats(formats)
    if tracking:  # refused before the fit, in calibrate's words (not ExportSettings.kind's)
        raise ValueError(
            f"--formats {', '.join(tracking)}: tracking ground truth needs a time series, and "
            "calibrate writes single frames; run it with frame formats (e.g. --formats "
            f"tiff), then in the {out / 'export_settings.yaml'} it writes set kind: "
            f"timeseries, formats: [{', '.join(tracking)}], visibility: action: flag (a "
            "track keeps its faint frames) and pipeline: simulation: n_frames to the "
            "frames of each series (a field of lone cells is simulated 1 frame; e.g. 20), "
            "and run `napari-symbac export --config` on that file"
        )
    _check_cell_width(args.cell_width_um, args.masks)
    with timer.step("load"):
        recording = read_frame(args.image, "IMAGE", args.frame, args.channel)
        image = recording.data
        masks = None if args.masks is None else read_frame(args.masks, "--masks", args.frame).data
        labels = (
            None if args.labels is None else read_frame(args.labels, "--labels", args.frame).data
        )
        if masks is not None and not np.issubdtype(masks.dtype, np.integer):
            raise ValueError(not_integer_masks("--masks", masks.dtype))
        _check_inputs(args, image, masks, labels)
        # the camera section the help names (found as a user: refused as an unknown field)
        microscope_file = load_microscope_file(args.microscope)
        microscope, camera = microscope_file.microscope, microscope_file.camera
        if args.camera is not None:
            camera = load_settings(args.camera, Camera)
        if camera is not None:  # an image beyond 16 bits was read divided: its camera too
            camera = in_read_units(camera, recording.counts_mapping)
        if args.cell_width_um is not None:  # calibrate sets it from the masks
            pixel_note = f"from the masks' median width and --cell-width-um {args.cell_width_um}"
        else:
            microscope, pixel_note = resolve_pixel_size(
                recording.pixel_size_um,
                microscope,
                microscope_gives_it=microscope_sets_pixel_size(args.microscope),
                flag_pixel_um=args.pixel_size_um,
                other_way="or, with --masks, --cell-width-um W sets it from the masks' "
                "median cell width (W um: 1.0 for E. coli)",
            )
        modality = args.modality or recording.modality or microscope.modality
        _refuse_a_trench(image, modality, args.image, args)
    # found as a user: unknown keys ignored unsaid
    file_notes = list(microscope_file.notes_for(modality))
    if microscope_file.frame_interval_s is not None:
        file_notes.append("frame_interval_s is not used: calibrate exports single frames")
    for note in file_notes:
        print(f"napari-symbac calibrate: note: {note}", file=sys.stderr, flush=True)
    if (note := modality_doubt(image, modality)) is not None:  # before the fit
        print(f"napari-symbac calibrate: note: {note}", file=sys.stderr, flush=True)
    check_stain_flags(args, modality)  # before the fit
    print("napari-symbac calibrate: fitting", file=sys.stderr, flush=True)
    with timer.step("fit"):
        calibration = calibrate(
            image,
            microscope=microscope,
            masks=masks,
            labels=labels,
            modality=modality,
            camera=camera,
            cell_width_um=args.cell_width_um,
            envelope_stain=args.envelope_stain,
            depth_layers=args.depth_layers,
            pixel_note=pixel_note,
            stage=lambda words: print(
                f"napari-symbac calibrate: {words}", file=sys.stderr, flush=True
            ),
        )
    settings = export_settings(
        calibration, n_items=args.n_items, formats=formats, seed=args.seed
    )
    print("napari-symbac calibrate: comparing real and synthetic", file=sys.stderr, flush=True)
    with timer.step("compare"):
        comparison, items = compare_with_dataset(
            calibration, settings, masks_given=masks is not None
        )
        real = calibration.reference
        fitted = masks is None  # the outlines are then the fit's cells
        picture = montage(
            real, items[0].image, calibration.masks, items[0].labels, real_masks_fitted=fitted
        )
    staging = staging_folder(out)
    try:
        print("napari-symbac calibrate: exporting", file=sys.stderr, flush=True)
        # found as a user: piped, 188 s of a 500-item export passed without a line
        update, bar = progress_bar("export", settings.n_items, "images", sys.stderr)
        with timer.step("export"):
            report = export_dataset(settings, staging / "dataset", workers=1, progress=update)
        bar.close()
        m = calibration.measurements
        px = calibration.settings.microscope.pixel_size_um
        modality_used = calibration.settings.microscope.modality
        notes = _settings_notes(calibration.notes, recording.counts_mapping)
        text = "\n".join(
            [
                "napari-symbac calibrate",
                *_image_lines(args.image, image, recording.counts_mapping),
                *calibration.report_lines(pixel_note, notes),
                "",
                f"REAL AGAINST SYNTHETIC (the dataset's {items_words(len(items))}; each 1-99 % "
                "normalised; report.png shows item 0)",
                comparison.table(),
                "",
                f"dataset: {report.n_items} items in {', '.join(report.formats)} "
                f"({report.seconds:.1f} s)",
            ]
        )
        (staging / "report.txt").write_text(text + "\n", encoding="utf-8")
        _write_png(staging / "report.png", picture)
        save_settings(settings, staging / "export_settings.yaml")
        masks = calibration.masks
        write_tiff(  # with the pixel size calibrated at (found as a user: none recorded)
            staging / "masks.tif",
            masks.astype(np.uint16 if masks.max() <= np.iinfo(np.uint16).max else np.uint32),
            pixel_size_um=calibration.settings.microscope.pixel_size_um,
            kind="labels",
        )
        out.mkdir(parents=True, exist_ok=True)
        for entry in sorted(staging.iterdir()):
            os.replace(entry, out / entry.name)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    # the masks' measurement, said as such (found as a user: "scene fit: 8 cells; ...
    # width 1.52 um" read as the fit's width, which the dataset draws at 1.32 um)
    print(f"{calibration.method}; masks.tif measures {m.summary(px, modality_used)}")
    print(f"real against synthetic: {comparison.verdict()} (report.txt says per quantity)")
    print(f"wrote dataset/ ({report.n_items} items, {', '.join(settings.formats)}), report.txt, "
          f"report.png, export_settings.yaml, masks.tif to {out}")
    print(timer.report())
    for caution in calibration.cautions:  # last, where a user reads first
        print(f"napari-symbac calibrate: warning: {caution}", file=sys.stderr, flush=True)
    return 0
