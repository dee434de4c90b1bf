"""Timing of named steps, reported as a table, and the progress bar shown on a terminal
(used by the CLI and the demo)."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, TextIO

__all__ = ["StepTimer", "terminal_bar"]


def terminal_bar(
    desc: str, total: int | None, unit: str, stream: TextIO
) -> tuple[Callable[[int, int], None], Any]:
    """``(update, bar)``: a tqdm bar on ``stream`` (a terminal) that ``update(done,
    total)`` moves, the total allowed to change as the work learns it; ``bar.close()``
    clears it."""
    from tqdm import tqdm

    bar = tqdm(total=total, desc=desc, unit=unit.rstrip("s"), leave=False, file=stream)

    def update(done: int, total_now: int) -> None:
        bar.total = total_now
        bar.n = done
        bar.refresh()

    return update, bar


class StepTimer:
    """Collects ``(step, seconds)`` pairs and formats them as a table with a total."""

    def __init__(self) -> None:
        self.steps: list[tuple[str, float]] = []

    @contextmanager
    def step(self, name: str) -> Iterator[None]:
        """Time the body of the ``with`` block as step ``name``."""
        start = time.perf_counter()
        yield
        self.steps.append((name, time.perf_counter() - start))

    def report(self) -> str:
        """One indented line per step, then the total."""
        width = max(len(name) for name, _ in self.steps)
        lines = [f"  {name:<{width}}  {seconds:7.2f} s" for name, seconds in self.steps]
        total = sum(seconds for _, seconds in self.steps)
        lines.append(f"  {'total':<{width}}  {total:7.2f} s")
        return "\n".join(lines)
