"""Concealed-effect benchmark of the diagnosis (issue 11).

Run: ``python benchmarks/bench_diagnose.py [--setting trench-0.7 ...] [--bootstrap 30]
[--fitted N] [--seed 1000] [--out table.md]`` (default: all four settings; case ``i`` uses
seed ``SEED + i``, its control ``SEED + 4000 + i``: another ``--seed`` draws fresh cases).

Every catalogued effect is hidden in a rendered recording by
:func:`napari_symbac.diagnose.concealed.make_case` (phase and fluorescence; a 256 x 46
trench and a 144 x 144 field with 6 cells; the largest single-pixel change of the noise-free image
0.3 or 0.7 noise s.d.; the field at 0.5 s.d. and "masked" cases, in the effect's first
modality only, where intensities 3-8 % and defocus 0.05 um off
the starting settings sit on top), with as many no-effect controls as effect cases.
The diagnosis starts from the true scene geometry (**oracle geometry**) and the base
render settings; with ``--fitted N`` the first N trench cases (and N controls) start
from :func:`~napari_symbac.fit.fit_scene` instead. Prints a markdown table; asserts
nothing.
"""

from __future__ import annotations

import argparse
import math
import time
from collections import defaultdict

import numpy as np

from napari_symbac.diagnose.concealed import base_settings, make_case
from napari_symbac.diagnose.effects import CATALOGUE
from napari_symbac.diagnose.model import build_design
from napari_symbac.diagnose.run import diagnose

SETTINGS = ("trench-0.7", "trench-0.3", "field-0.5", "masked-0.5")


def cases(setting: str) -> list[dict]:
    """The effect cases of one setting (field and masked: each effect's first modality)."""
    geometry, fraction = setting.split("-")
    out = []
    for name, cls in CATALOGUE.items():
        modalities = cls.modalities if geometry == "trench" else cls.modalities[:1]
        for modality in modalities:
            spec = {
                "effect": name,
                "modality": modality,
                "geometry": "field" if geometry == "field" else "trench",
                "fraction_of_sd": float(fraction),
            }
            if geometry == "masked":
                spec["masked"] = True
            out.append(spec)
    return out


def fitted_design(case):
    """The base model from fit_scene's geometry instead of the truth."""
    from napari_symbac.fit import fit_scene

    microscope, render, camera = base_settings(case.modality)
    scenes = []
    for frame in case.images:
        fit = fit_scene(frame, microscope, render, camera, geometry="trench")
        scenes.append(fit.scene)
        render = fit.render
    return build_design(scenes, microscope, render, camera)


def run_case(spec: dict, seed: int, fitted: bool, n_bootstrap: int = 30) -> dict:
    case = make_case(seed=seed, **spec)
    design = fitted_design(case) if fitted else case.design
    start = time.process_time()
    result = diagnose(
        case.images, design, n_bootstrap=n_bootstrap, rng=np.random.default_rng(seed + 1)
    )
    cpu = time.process_time() - start
    accepted = [e.name for e in result.accepted]
    row = dict(spec, seed=seed, accepted=accepted, cpu_s=cpu, truth=case.true_magnitude)
    target = next((e for e in result.effects if e.name == spec["effect"]), None)
    if target is not None and target.accepted:
        eff = CATALOGUE[target.name](design.geometry)
        fitted_mag = (
            eff.magnitude(target.params)
            if target.name != "saturation"
            else target.params["clip_level_adu"]
        )
        row["rel_error"] = abs(fitted_mag - case.true_magnitude) / max(
            abs(case.true_magnitude), 1e-12
        )
        row["gain_nats"] = target.held_out_gain_nats
        row["dev_before"], row["dev_after"] = target.held_out_before, target.held_out_after
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--setting", choices=SETTINGS, action="append")
    parser.add_argument("--bootstrap", type=int, default=30, help="replicates per held-out check")
    parser.add_argument("--fitted", type=int, default=0)
    parser.add_argument("--seed", type=int, default=1000, help="seed of the first case")
    parser.add_argument("--out")
    args = parser.parse_args()
    specs = [c for setting in args.setting or SETTINGS for c in cases(setting)]
    rows, controls = [], []
    for i, spec in enumerate(specs):
        rows.append(run_case(spec, args.seed + i, False, args.bootstrap))
        control = dict(spec, effect=None)
        controls.append(run_case(control, args.seed + 4000 + i, False, args.bootstrap))
        print(
            f"[{i + 1}/{len(specs)}] {spec} -> {rows[-1]['accepted']}; "
            f"control -> {controls[-1]['accepted']}",
            flush=True,
        )
    fitted_rows = []
    trench = [
        s
        for s in specs
        if s["geometry"] == "trench"
        and not s.get("masked")
        and s["effect"] not in ("photobleaching", "stage_drift")
    ]
    for i, spec in enumerate(trench[: args.fitted]):
        fitted_rows.append(run_case(spec, 9000 + i, True))
        fitted_rows.append(run_case(dict(spec, effect=None), 9500 + i, True))
        print(
            f"[fitted {i + 1}] {spec} -> {fitted_rows[-2]['accepted']}; "
            f"control -> {fitted_rows[-1]['accepted']}",
            flush=True,
        )
    lines = table(rows, controls, "oracle geometry")
    if fitted_rows:
        lines += [
            "",
            *table(
                [r for r in fitted_rows if r["effect"]],
                [r for r in fitted_rows if not r["effect"]],
                "fitted geometry (fit_scene)",
            ),
        ]
    text = "\n".join(lines)
    print(text)
    if args.out:
        with open(args.out, "w") as handle:
            handle.write(text + "\n")


def table(rows: list[dict], controls: list[dict], title: str) -> list[str]:
    groups: dict[str, list[dict]] = defaultdict(list)
    for r in rows:
        groups[r["effect"]].append(r)
    lines = [
        f"Concealed effects, {title}: {len(rows)} cases, {len(controls)} no-effect controls",
        "",
        "| effect | cases | named (first accepted) | accepted at all | median rel. error "
        "| median held-out gain (nats) | median CPU s |",
        "|---|---|---|---|---|---|---|",
    ]

    def pct(n, d):
        return f"{100 * n / d:.0f} %" if d else "-"

    for name, rs in groups.items():
        first = sum(1 for r in rs if r["accepted"][:1] == [name])
        anyacc = sum(1 for r in rs if name in r["accepted"])
        errs = [r["rel_error"] for r in rs if "rel_error" in r and math.isfinite(r["rel_error"])]
        gains = [r["gain_nats"] for r in rs if "gain_nats" in r]
        lines.append(
            f"| {name} | {len(rs)} | {pct(first, len(rs))} | {pct(anyacc, len(rs))} | "
            f"{np.median(errs) if errs else float('nan'):.2f} | "
            f"{np.median(gains) if gains else float('nan'):.1f} | "
            f"{np.median([r['cpu_s'] for r in rs]):.1f} |"
        )
    first = sum(1 for r in rows if r["accepted"][:1] == [r["effect"]])
    errs = [r["rel_error"] for r in rows if "rel_error" in r]
    within = sum(1 for e in errs if e <= 0.25)
    false = sum(1 for c in controls if c["accepted"])
    lines += [
        f"| **all** | {len(rows)} | {pct(first, len(rows))} | "
        f"{pct(sum(1 for r in rows if r['effect'] in r['accepted']), len(rows))} | "
        f"{np.median(errs) if errs else float('nan'):.2f} ({within}/{len(errs)} within 25 %) | | |",
        "",
        f"False acceptances on no-effect controls: {false} of {len(controls)} "
        f"({pct(false, len(controls))}); "
        f"accepted: {[c['accepted'] for c in controls if c['accepted']]}",
    ]
    by_frac = defaultdict(list)
    for r in rows:
        key = ("masked " if r.get("masked") else "") + f"{r['geometry']} {r['fraction_of_sd']} sd"
        by_frac[key].append(r["accepted"][:1] == [r["effect"]])
    lines.append(
        "Named by setting: "
        + ", ".join(f"{k}: {pct(sum(v), len(v))}" for k, v in sorted(by_frac.items()))
    )
    return lines


if __name__ == "__main__":
    main()
