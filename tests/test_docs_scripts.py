"""The developer scripts of docs/scripts: ``--help`` prints a usage line and does no work,
and a data folder that is not there is a usage error, not a traceback."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: The scripts, not the module they share (``_args.py``, which has no command line).
SCRIPTS = sorted((ROOT / "docs" / "scripts").glob("[!_]*.py"))
#: Only a guard against a hang: ``--help`` takes seconds (its imports) where the work takes
#: minutes, and the work would write under docs/images, which the test checks. Generous,
#: so that a loaded machine's slow imports never fail it.
TIMEOUT_S = 600


def _run(script: Path, *args: str) -> subprocess.CompletedProcess[str]:
    """Run ``script`` with ``args`` from the repository root, as the docs do."""
    return subprocess.run(
        [sys.executable, str(script), *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
    )


def _images() -> dict[Path, int]:
    """Every file under docs/images (where the scripts write) and its modification time."""
    return {p: p.stat().st_mtime_ns for p in (ROOT / "docs" / "images").rglob("*")}


def test_scripts_found():
    assert len(SCRIPTS) > 10


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_help_prints_usage(script: Path):
    before = _images()
    result = _run(script, "--help")
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("usage:"), result.stdout
    assert _images() == before


def test_missing_data_folder_is_a_usage_error(tmp_path: Path):
    folder = tmp_path / "nonexistent" / "folder"
    result = _run(ROOT / "docs" / "scripts" / "fit_trench_residual.py", str(folder))
    assert result.returncode == 2, result.stderr
    assert f"{folder} not found" in result.stderr
    assert "usage:" in result.stderr
    assert "Traceback" not in result.stderr
