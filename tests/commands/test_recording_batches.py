"""`diagnose` and `identify` over a folder of many recordings, as a user brings their tosses: a
refused recording (too short, a fit that does not converge) costs its own result, not the rest
of the batch."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from inertia_gym.cli import main
from inertia_gym.discrepancy.recordings import write_recording
from inertia_gym.discrepancy.synthetic import simulate_recording
from inertia_gym.scenario import Scenario

HEADER = '"Time (s)","Gyroscope x (rad/s)","Gyroscope y (rad/s)","Gyroscope z (rad/s)","Absolute (rad/s)"'


def _export(folder: Path, t, w) -> None:
    """A phyphox gyro export (no segments file: the whole file is one recording)."""
    folder.mkdir(parents=True)
    rows = [",".join(f"{v:.9E}" for v in (ti, *wi, np.linalg.norm(wi))) for ti, wi in zip(t, w)]
    (folder / "Raw Data.csv").write_text("\n".join([HEADER, *rows]) + "\n")


@pytest.fixture(scope="module")
def tosses(tmp_path_factory) -> Path:
    """round1/<export>: a 2-s torque-free tumble of the paper's body, gyro only; round2/<export>
    of the same name: 15 rows, too few for either command."""
    root = tmp_path_factory.mktemp("tosses")
    rec, _ = simulate_recording(Scenario(), 2.0, seed=3, torque=False, sample_dt=0.01)
    _export(root / "round1" / "Gyroscope rotation rate 1", rec.t, rec.w)
    _export(root / "round2" / "Gyroscope rotation rate 1", rec.t[:15], rec.w[:15])
    return root


@pytest.mark.parametrize("command, result", [("diagnose", "report.json"), ("identify", "identify.json")])
def test_a_refused_recording_does_not_stop_the_batch(tosses, tmp_path, capsys, command, result):
    out = tmp_path / "out"
    code = main([command, str(tosses), "--out", str(out), "--no-plots"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    good, bad = out / "round1_Gyroscope_rotation_rate_1", out / "round2_Gyroscope_rotation_rate_1"
    assert (good / result).is_file() and not (good / "refused.txt").exists()
    assert not (bad / result).exists()
    assert f"{command} needs at least" in (bad / "refused.txt").read_text()
    assert len(err) == 2  # one line per refusal, one for the batch
    assert err[0].startswith("round2/Gyroscope rotation rate 1: refused: ")
    assert "1 of 2 recordings refused" in err[1] and "the other 1 are written" in err[1]


@pytest.mark.parametrize("command, result", [("diagnose", "report.json"), ("identify", "identify.json")])
def test_a_folder_of_recording_files_with_an_unreadable_one(tmp_path, capsys, command, result):
    """A folder of the project's CSV recordings (sidecars beside them), as a logger writes
    throws: each is run, and a file that is no recording costs its own result only."""
    rec, side = simulate_recording(Scenario(), 2.0, seed=3, torque=False, sample_dt=0.01)
    folder = tmp_path / "throws"
    folder.mkdir()
    write_recording(folder / "LOG01.csv", dataclasses.replace(rec, q=None), side)
    (folder / "notes.csv").write_text("when,who\nmonday,me\n")
    out = tmp_path / "out"
    code = main([command, str(folder), "--out", str(out), "--no-plots"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert (out / "LOG01" / result).is_file()
    assert "notes.csv" in (out / "notes" / "refused.txt").read_text()
    assert len(err) == 2 and err[0].startswith("notes: refused: ")
    assert "1 of 2 recordings refused" in err[1]
