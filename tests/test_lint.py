"""The whole tree passes the linter the project configures (pyproject.toml's ``[tool.ruff]``: pycodestyle, pyflakes,
import order, pyupgrade, bugbear; lines of at most 120 characters).  Run as a test so that ``make test`` and CI
hold every commit to it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def ruff(*args: str, text: str | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", "--output-format", "concise", *args],
                          cwd=REPO, capture_output=True, text=True, input=text, timeout=120)


def test_ruff_finds_nothing_in_the_tree():
    result = ruff(".")
    assert result.returncode == 0, result.stdout + result.stderr


def test_the_linter_reads_the_projects_configuration():
    # the limit is the configured 120 characters, not ruff's default of 88: 120 passes, 121 is refused
    line = "x = 1  # "
    fits = ruff("--stdin-filename", "cgp_core/_probe.py", "-", text=line + "a" * (120 - len(line)) + "\n")
    assert fits.returncode == 0, fits.stdout + fits.stderr
    too_long = ruff("--stdin-filename", "cgp_core/_probe.py", "-", text=line + "a" * (121 - len(line)) + "\n")
    assert too_long.returncode == 1 and "line-too-long" in too_long.stdout, too_long.stdout + too_long.stderr
