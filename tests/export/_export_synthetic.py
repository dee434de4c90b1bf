"""Synthetic items for the export tests: ellipses in a mask, a small known lineage.

Kept apart from the tests so that a subprocess (the kill test) and dask workers (pickled by
value with ``cloudpickle.register_pickle_by_value``) can use the same source.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import numpy as np
from skimage.draw import ellipse

from napari_symbac.export import ExportItem, unit_rng

SHAPE = (64, 40)

#: Series lineage: cell 1 divides into 2 and 3 after frame 2; cell 4 (no parent) is in
#: frames 0-4; cells 2 and 3 are in frames 3-5.
LINEAGE_PARENTS = {1: 0, 2: 1, 3: 1, 4: 0}
TIMESERIES_FRAMES = 6
PRESENT = {
    1: range(0, 3),
    2: range(3, 6),
    3: range(3, 6),
    4: range(0, 5),
}
#: Ellipse centre row, column and semi-axes per cell
GEOMETRY = {1: (14, 20, 9, 5), 2: (8, 20, 6, 5), 3: (21, 20, 6, 5), 4: (45, 20, 10, 5)}


def draw_labels(
    cells: dict[int, tuple[int, int, int, int]], shape=SHAPE, offset: int = 0
) -> np.ndarray:
    labels = np.zeros(shape, np.uint32)
    for cell, (r, c, a, b) in cells.items():
        rr, cc = ellipse(r + offset, c, a, b, shape=shape)
        labels[rr, cc] = cell
    return labels


def render(labels: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    image = np.where(labels > 0, 800.0, 2400.0) + rng.normal(0, 40, labels.shape)
    return np.clip(np.rint(image), 0, 65535).astype(np.uint16)


class SyntheticSource:
    """An ItemSource of synthetic frames or time series, optionally slow or failing."""

    def __init__(
        self,
        n_units: int = 6,
        *,
        kind: str = "frames",
        seed: int = 0,
        val_every: int = 3,
        fail_at: int | None = None,
        fail_flag: str | None = None,
        delay_s: float = 0.0,
        id_offset: int = 0,
        record_dir: str | None = None,
    ) -> None:
        self._n = n_units
        self.kind = kind
        self.seed = seed
        self.val_every = val_every
        self.fail_at = fail_at
        self.fail_flag = fail_flag  # fail only while this file exists
        self.delay_s = delay_s
        self.id_offset = id_offset
        self.record_dir = record_dir  # an empty file "UNIT-PID" per unit made

    @property
    def n_units(self) -> int:
        return self._n

    def unit_names(self, unit: int) -> list[str]:
        if self.kind == "frames":
            return [f"{unit:06d}"]
        return [f"s{unit:04d}_t{t:04d}" for t in range(TIMESERIES_FRAMES)]

    def header(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "seed": self.seed,
            "settings": {"synthetic": True, "n": self._n, "id_offset": self.id_offset},
        }

    def _split(self, unit: int) -> str:
        return "val" if self.val_every and unit % self.val_every == self.val_every - 1 else "train"

    def _sequence(self, unit: int) -> int:
        """Rank of the unit among the units of its split."""
        n_val_before = unit // self.val_every if self.val_every else 0
        return n_val_before if self._split(unit) == "val" else unit - n_val_before

    def make_unit(self, unit: int) -> list[ExportItem]:
        armed = self.fail_flag is None or Path(self.fail_flag).exists()
        if self.fail_at is not None and unit == self.fail_at and armed:
            raise RuntimeError(f"injected fault in unit {unit}")
        if self.delay_s:
            time.sleep(self.delay_s)
        if self.record_dir is not None:
            Path(self.record_dir, f"{unit}-{os.getpid()}").touch()
        rng = unit_rng(self.seed, unit)
        if self.kind == "frames":
            n_cells = 1 + unit % 3
            cells = {}
            for k in range(n_cells):
                cell = self.id_offset + 1 + k + unit
                cells[cell] = (10 + 20 * k + int(rng.integers(0, 2)), 20, 11, 6)
            labels = draw_labels(cells)
            return [
                ExportItem(
                    name=self.unit_names(unit)[0],
                    index=unit,
                    image=render(labels, rng),
                    labels=labels,
                    split=self._split(unit),
                    params={"unit": unit, "draw": float(rng.random())},
                )
            ]
        items = []
        names = self.unit_names(unit)
        for t in range(TIMESERIES_FRAMES):
            cells = {
                self.id_offset + cell: GEOMETRY[cell] for cell in PRESENT if t in PRESENT[cell]
            }
            labels = draw_labels(cells)
            present = [int(c) for c in np.unique(labels) if c]
            parents = {
                c: (LINEAGE_PARENTS[c - self.id_offset] + self.id_offset)
                if LINEAGE_PARENTS[c - self.id_offset]
                else 0
                for c in present
            }
            items.append(
                ExportItem(
                    name=names[t],
                    index=unit * TIMESERIES_FRAMES + t,
                    image=render(labels, rng),
                    labels=labels,
                    split=self._split(unit),
                    series=unit,
                    sequence=self._sequence(unit),
                    frame=t,
                    n_frames=TIMESERIES_FRAMES,
                    parents=parents,
                    max_label=self.id_offset + 4,
                    pixel_size_um=0.065,
                    frame_interval_min=3.0,
                    params={"unit": unit},
                )
            )
        return items


def tree_digest(root: Path) -> dict[str, bytes]:
    """Relative path -> bytes of every file under ``root``."""
    return {
        p.relative_to(root).as_posix(): p.read_bytes()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }
