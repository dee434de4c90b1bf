"""Figure of docs/diagnosis.md, "From diagnosis to dataset": the effects that
``napari-symbac diagnose`` accepted on the SyMBac trench, drawn by ``export``.

Runs, as a user would, ``diagnose`` on ``ecoli_100x_oil_exponential.tiff`` (GPL-2 test
data, read from ``../shared/data/real``; not copied), then ``export --config`` with its
settings.yaml and with the same settings less their ``extra_stages``, and writes
``docs/images/diagnosis/export_with_effects.png``: the recording | an exported frame
without the stages | the same frame with them | their difference, and the column means
of the PDMS rows above the trench's closed end in the recording and in both exports (with
the fitted column offsets, when ``fixed_pattern_noise`` is accepted). Prints the numbers
quoted in the docs. Run from the repository root (about 30 s on the shared 2-core
machine, 2026-11-29).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
from pathlib import Path

import matplotlib
from _args import REAL_DATA, checked_real_data, script_parser

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import tifffile
from PIL import Image

from napari_symbac.cli import main
from napari_symbac.diagnose.effects.fixed_pattern_noise import column_basis
from napari_symbac.settings import PipelineSettings, load_settings, save_settings

ROOT = Path(__file__).resolve().parents[2]
REAL = REAL_DATA / "ecoli_100x_oil_exponential.tiff"
OUT = ROOT / "docs" / "images" / "diagnosis" / "export_with_effects.png"
MICROSCOPE = {"modality": "phase", "pixel_size_um": 0.065, "NA": 1.45, "refractive_index": 1.518,
              "wavelength_um": 0.65, "condenser": "Ph3", "objective": "100x oil"}  # fmt: skip
#: Rows of the recording above the trench's closed end: PDMS only (the end's dark rim
#: starts at row 12), where no cell shapes the column means.
PDMS_ROWS = slice(0, 12)


def export(settings: PipelineSettings, folder: Path) -> np.ndarray:
    config = save_settings(settings, folder.with_suffix(".yaml"))
    code = main(["export", "--config", str(config), "--n-items", "4", "--out", str(folder)])
    if code:
        sys.exit(code)
    return np.stack([tifffile.imread(p) for p in sorted(folder.glob("tiff/*/images/*.tif"))])


def pdms_columns(frames: np.ndarray) -> np.ndarray:
    """``(n, X)`` column means of :data:`PDMS_ROWS` of each frame."""
    return frames[:, PDMS_ROWS].mean(axis=1)


def spreads(frames: np.ndarray) -> tuple[float, float]:
    """Spread (s.d. over the columns, ADU) of the PDMS column means, mean over the frames,
    and the rms of their part in the modes column offsets take (``column_basis``)."""
    means = pdms_columns(frames)
    basis = column_basis(frames.shape[-1], MICROSCOPE["pixel_size_um"])
    stripes = np.sqrt(np.sum((means @ basis) ** 2, axis=1) / frames.shape[-1])
    return float(means.std(axis=1).mean()), float(stripes.mean())


def run() -> None:
    work = Path(tempfile.mkdtemp())
    (work / "microscope.json").write_text(json.dumps(MICROSCOPE))
    out = work / "diagnosis"
    args = ["diagnose", str(REAL), "--microscope", str(work / "microscope.json"), "--out", str(out)]
    if main(args):
        sys.exit("diagnose failed")
    doc = json.loads((out / "diagnosis.json").read_text())
    accepted = {e["name"]: e["params"] for e in doc["effects"] if e["accepted"]}
    diagnosed = load_settings(out / "settings.yaml", PipelineSettings)
    plain = dataclasses.replace(diagnosed, extra_stages=())
    with_stages = export(diagnosed, work / "diagnosed").astype(float)
    without = export(plain, work / "plain").astype(float)
    step = with_stages - without
    offsets = np.asarray(accepted.get("fixed_pattern_noise", {}).get("column_offsets_adu", []))
    real = tifffile.imread(REAL).astype(float)
    print("accepted:", ", ".join(accepted))
    for effect in doc["effects"]:
        confirmation = effect.get("confirmation") or {}
        if confirmation and not confirmation["confirmed"]:
            print(f"not accepted, {effect['name']}: {confirmation['reason']}")
    print("extra stages drawn:", ", ".join(s.name for s in diagnosed.extra_stages))
    print(f"frame {with_stages.shape[1:]}, recording {real.shape}")
    print(f"mean: recording {real.mean():.0f}, export without {without.mean():.0f}, "
          f"with {with_stages.mean():.0f} ADU")  # fmt: skip
    for name, frames in (("recording", real[None]), ("without", without), ("with", with_stages)):
        spread, stripes = spreads(frames)
        print(f"PDMS rows {PDMS_ROWS.start}-{PDMS_ROWS.stop - 1}, {name}: column means spread "
              f"{spread:.1f} ADU, in the column offsets' modes {stripes:.1f} ADU rms")  # fmt: skip
    if offsets.size:
        columns = step.mean(axis=(0, 1))
        r = np.corrcoef(columns - columns.mean(), offsets)[0, 1]
        print(f"column means of the difference vs fitted offsets: r = {r:.3f}")

    fig = plt.figure(figsize=(11, 6.2))
    grid = fig.add_gridspec(1, 6, width_ratios=[1, 1, 1, 1, 0.35, 2.6], wspace=0.55)
    low, high = np.percentile(real, [0.5, 99.5])
    panels = [
        ("recording", real, "gray", (low, high)),
        ("export, no stages", without[0], "gray", (low, high)),
        ("export, diagnosed", with_stages[0], "gray", (low, high)),
        ("difference (ADU)", step[0], "PiYG", (-600, 600)),
    ]
    for k, (title, image, cmap, limits) in enumerate(panels):
        ax = fig.add_subplot(grid[k])
        shown = ax.imshow(image, cmap=cmap, vmin=limits[0], vmax=limits[1])
        ax.set_title(title, fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
        if k == 3:
            fig.colorbar(shown, ax=ax, orientation="horizontal", fraction=0.05, pad=0.03)
    ax = fig.add_subplot(grid[5])  # grid[4]: room for the axis label
    for label, frames, style in (
        ("recording", real[None], "ko-"),
        ("export, no stages", without, "o-"),
        ("export, diagnosed", with_stages, "s-"),
    ):
        means = pdms_columns(frames).mean(axis=0)
        ax.plot(means - means.mean(), style, ms=3, label=label)
    if offsets.size:
        ax.plot(offsets, "^--", ms=3, label="diagnosis: fitted column offsets")
    ax.set_xlabel("column (px)")
    ax.set_ylabel("ADU (mean removed)")
    ax.legend(fontsize=8, loc="lower left")
    ax.set_title(
        f"column means of the PDMS above the closed end\n(rows {PDMS_ROWS.start}-"
        f"{PDMS_ROWS.stop - 1})",
        fontsize=9,
    )
    fig.suptitle(
        "SyMBac trench: diagnose accepted " + ", ".join(accepted) + ";\nexport draws "
        + ", ".join(s.name for s in diagnosed.extra_stages) + " as extra stages",
        fontsize=10,
        y=1.04,
    )
    OUT.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(OUT, dpi=90, bbox_inches="tight")
    plt.close(fig)
    # 256 colours: a fifth of the bytes, the same look (as make_phase_figures.save)
    Image.open(OUT).convert("RGB").quantize(256).save(OUT, optimize=True)
    print("wrote", OUT)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The command line: no arguments (``--help`` prints the docstring above)."""
    parser = script_parser(__doc__)
    args = parser.parse_args(argv)
    checked_real_data(parser, REAL, "the SyMBac trench recording", given="repository", file=True)
    return args


if __name__ == "__main__":
    parse_args()
    run()
