"""A user's own `agents.py` in the working directory must not break any command (issue 12).

Each command runs as `python -m inertia_gym.cli`, which puts the working directory first on
sys.path: the worst case for a module name the package might import. The user's agents.py
raises on import, so any import of it fails the command.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from inertia_gym.cli import COMMANDS

REPO = Path(__file__).resolve().parents[1]

#: Each command with the smallest budgets that still run it end to end.
COMMAND_LINES = {
    "simulate": ["simulate", "--duration", "5", "--out", "rec.csv"],
    "validate": ["validate", "--xi", "none", "--duration", "5", "--seeds", "1", "--out", "val"],
    "optimize": ["optimize", "--agent", "random", "--budget", "2", "--no-progress", "--out", "opt"],
    "benchmark": ["benchmark", "--agents", "random", "--seeds", "1", "--budget", "2", "--grid-points", "2",
                  "--eval-seeds", "1", "--val-seeds", "1", "--val-duration", "5", "--workers", "1",
                  "--no-progress", "--out", "bench"],
    "diagnose": ["diagnose", "rec.csv", "--no-plots", "--out", "diag"],
    "identify": ["identify", "rec.csv", "--no-plots", "--out", "ident"],
    "example": ["example", "thrown-rotor", "--out", "ex"],
}


@pytest.fixture(scope="module")
def user_folder(tmp_path_factory) -> Path:
    """A working directory holding an agents.py that raises on import."""
    folder = tmp_path_factory.mktemp("user")
    (folder / "agents.py").write_text('raise RuntimeError("the user\'s own agents.py was imported")\n')
    return folder


def _run(folder: Path, argv: list[str]) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(REPO), MPLBACKEND="Agg")
    env.pop("INERTIA_GYM_DEBUG", None)
    return subprocess.run([sys.executable, "-m", "inertia_gym.cli", *argv], cwd=folder, env=env,
                          capture_output=True, text=True, timeout=1800)


def test_every_command_is_covered():
    assert set(COMMAND_LINES) == set(COMMANDS)


@pytest.mark.slow
@pytest.mark.parametrize("command", [pytest.param(c, marks=pytest.mark.science) if c == "validate" else c
                                     for c in COMMAND_LINES])  # simulate first: the others read its file
def test_each_command_runs_beside_a_user_agents_module(user_folder, command):
    if command in ("diagnose", "identify") and not (user_folder / "rec.csv").exists():
        assert _run(user_folder, COMMAND_LINES["simulate"]).returncode == 0
    done = _run(user_folder, COMMAND_LINES[command])
    assert done.returncode == 0, done.stderr
    assert "agents.py was imported" not in done.stderr and "Traceback" not in done.stderr
    outputs = {"simulate": "rec.json", "validate": "val", "optimize": "opt", "benchmark": "bench",
               "diagnose": "diag/report.json", "identify": "ident/identify.json",
               "example": "ex/thrown-rotor.json"}
    out = user_folder / outputs[command]
    assert out.exists()
    if out.suffix == ".json":
        json.loads(out.read_text())
    else:
        assert any(out.iterdir())
