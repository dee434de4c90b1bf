"""Timing of named steps, reported as a table, and progress: a bar on a terminal, lines
on a pipe (used by the CLI and the demo)."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, TextIO

__all__ = ["PIPED_PROGRESS_INTERVAL_S", "PipedProgress", "StepTimer", "progress_bar"]


#: Least seconds between two progress lines when stderr is not a terminal.
PIPED_PROGRESS_INTERVAL_S = 10.0


class PipedProgress:
    """Progress as lines on a pipe (a log file, CI, nohup), where a bar would be silent:
    a line when the count moves, at most every :data:`PIPED_PROGRESS_INTERVAL_S`
    seconds, and always the last step."""

    def __init__(self, desc: str, unit: str, stream, *, bound: bool = False) -> None:
        self.desc, self.unit, self.stream = desc, unit, stream
        self.of = " of at most" if bound else " of"
        self.shown = (0, None)
        self.when = -math.inf

    def __call__(self, done: int, total: int | None) -> None:
        now = time.monotonic()
        last = total is not None and done >= total
        due = last or now - self.when >= PIPED_PROGRESS_INTERVAL_S
        if done == 0 or (done, total) == self.shown or not due:
            return
        of = f"{self.of} {total}" if total else ""
        print(f"napari-symbac {self.desc}: {done}{of} {self.unit}", file=self.stream, flush=True)
        self.shown, self.when = (done, total), now

    def close(self) -> None:
        pass


def progress_bar(
    desc: str, total: int | None, unit: str, stream: TextIO, *, bound: bool = False
) -> tuple[Callable[[int, int], None], Any]:
    """``(update, handle)``: a tqdm bar on ``stream`` when it is a terminal, else
    :class:`PipedProgress` lines. ``update(done, total)`` moves it, the total allowed to
    change as the work learns it; ``handle.close()`` ends it. ``bound``: the total is the
    most there can be, and shrinks ("1 of at most 12", then "6 of at most 6")."""
    if not getattr(stream, "isatty", lambda: False)():
        piped = PipedProgress(desc, unit, stream, bound=bound)
        return piped, piped
    from tqdm import tqdm

    desc = f"{desc} (of at most)" if bound else desc
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
