"""docs/rendering.md, "The pixel size the fit prefers": the partially coherent fit of each
Omnipose colony (``make_phase_figures.fit_one``) repeated at pixel sizes around the one
that assumes 1 um wide cells (``fit.masks.estimate_pixel_size_um``), with the residual
and the normalised class medians at each.

The Omnipose PNGs record no pixel size, and the wavelength and NA are assumptions too;
only the optics' scale in pixels (``lambda / (NA px)``) reaches the image, so a residual
that falls as the pixel size changes says the image's optics are that much wider or
narrower in pixels than the assumption made them.

Usage (from the repository root, ~4 min per fit on 2 cores):

    python docs/scripts/phase_pixel_size_profile.py Sample000252 1.0 0.8 0.65 0.5 >> lines.jsonl
    python docs/scripts/phase_pixel_size_profile.py --table lines.jsonl

The first form prints one JSON line per fit; the second writes
``docs/images/phase_pixel_profile.json`` and ``docs/images/phase_pixel_profile.png`` from
those lines. Class medians: cells = mask > 0, halo = 1-3 px outside a cell, background =
at least 2 um (at the estimated pixel size) from every cell, so that every pixel size is
judged on the same pixels.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import matplotlib
from _args import checked_real_data, script_parser

matplotlib.use("Agg")
import matplotlib.pyplot as plt

sys.path.insert(0, str(Path(__file__).resolve().parent))
import make_phase_figures as phase

from napari_symbac.fit.masks import class_medians, estimate_pixel_size_um

OUT = phase.OUT


def profile(name: str, factors: list[float]) -> None:
    """Print one JSON line per pixel size: the fit's residual, medians and values."""
    image, labels = phase.load(name)
    estimated = estimate_pixel_size_um(labels)
    far_px = phase.FAR_UM / estimated
    real = class_medians(image, labels, far_px)
    for factor in factors:
        start = time.perf_counter()
        fit = phase.fit_one(image, labels, estimated * factor, "partially_coherent")
        line = {
            "image": name,
            "factor": factor,
            "pixel_size_um": estimated * factor,
            "rms_adu": fit["rms_adu"],
            "medians": class_medians(fit["noisy"], labels, far_px),
            "real_medians": real,
            "fitted": fit["fitted"],
            "warnings": fit["warnings"],
            "seconds": round(time.perf_counter() - start),
        }
        print(json.dumps(line), flush=True)


def table(path: Path) -> None:
    """The JSON and the figure of the profiles in ``path`` (JSON lines)."""
    lines = [json.loads(t) for t in path.read_text().splitlines() if t.strip()]
    by_image: dict[str, list[dict]] = {}
    for line in sorted(lines, key=lambda x: (x["image"], x["factor"])):
        by_image.setdefault(line["image"], []).append(line)
    (OUT / "phase_pixel_profile.json").write_text(json.dumps(by_image, indent=1))
    fig, axes = plt.subplots(2, len(by_image), figsize=(4.2 * len(by_image), 6.4), squeeze=False)
    for k, (name, rows) in enumerate(by_image.items()):
        factors = [r["factor"] for r in rows]
        best = min(rows, key=lambda r: r["rms_adu"])
        top, bottom = axes[0, k], axes[1, k]
        top.plot(factors, [r["rms_adu"] for r in rows], "o-")
        top.axvline(best["factor"], color="0.6", ls=":")
        top.set_title(f"{name}: residual rms", fontsize=9, loc="left")
        top.set_ylabel("ADU")
        for cls, colour in (("cells", "C0"), ("background", "C2"), ("halo", "C1")):
            bottom.plot(factors, [r["medians"][cls] for r in rows], "o-", color=colour,
                        label=f"{cls}, fitted")  # fmt: skip
            bottom.axhline(rows[0]["real_medians"][cls], color=colour, ls="--", lw=1,
                           label=f"{cls}, real")  # fmt: skip
        bottom.axvline(best["factor"], color="0.6", ls=":")
        bottom.set_xlabel("pixel size / the 1-um-cell estimate")
        bottom.set_ylabel("normalised median")
        bottom.set_title("class medians", fontsize=9, loc="left")
    axes[1, 0].legend(fontsize=7, ncol=2)
    fig.tight_layout()
    phase.save(fig, OUT / "phase_pixel_profile.png")
    print("wrote", OUT / "phase_pixel_profile.json", OUT / "phase_pixel_profile.png")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The command line: ``NAME FACTOR ...`` or ``--table PATH``."""
    parser = script_parser(__doc__, usage="%(prog)s [-h] (NAME FACTOR [FACTOR ...] | --table PATH)")
    parser.add_argument(
        "name", nargs="?", metavar="NAME", help="the Omnipose colony to fit, e.g. Sample000252"
    )
    parser.add_argument(
        "factors",
        nargs="*",
        type=float,
        metavar="FACTOR",
        help="pixel sizes to fit at, as multiples of the 1-um-cell estimate",
    )
    parser.add_argument(
        "--table",
        type=Path,
        metavar="PATH",
        help="instead: the JSON lines of earlier runs, to the profile's JSON and figure",
    )
    args = parser.parse_args(argv)
    if args.table is not None:
        if args.name is not None:
            parser.error("pass either --table PATH or NAME FACTOR ..., not both")
        if not args.table.is_file():
            parser.error(f"{args.table} not found: pass the JSON lines NAME FACTOR ... printed")
    elif args.name is None or not args.factors:
        parser.error("pass NAME FACTOR ... (one fit per factor) or --table PATH")
    else:
        checked_real_data(parser, phase.REAL, "the Omnipose colonies", given="repository")
    return args


if __name__ == "__main__":
    args = parse_args()
    if args.table is not None:
        table(args.table)
    else:
        profile(args.name, args.factors)
