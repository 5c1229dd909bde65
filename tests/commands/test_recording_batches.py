"""`diagnose` and `identify` over a folder of many recordings, as a user brings their tosses: a
refused recording (too short, a fit that does not converge) costs its own result, not the rest
of the batch."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from inertia_gym.cli import main
from inertia_gym.discrepancy.synthetic import simulate_recording
from inertia_gym.recordings import WINDOW_FOUND, write_recording
from inertia_gym.scenario import Scenario


@pytest.fixture(scope="module")
def tosses(tmp_path_factory, write_phyphox) -> Path:
    """round1/<export>: a 2-s torque-free tumble of the paper's body, gyro only (no segments
    file, and free throughout: the whole file is one recording); round2/<export> of the same
    name: 15 rows, too few for either command."""
    root = tmp_path_factory.mktemp("tosses")
    rec, _ = simulate_recording(Scenario(), 2.0, seed=3, torque=False, sample_dt=0.01)
    write_phyphox(root / "round1" / "Gyroscope rotation rate 1", rec.t, rec.w)
    write_phyphox(root / "round2" / "Gyroscope rotation rate 1", rec.t[:15], rec.w[:15])
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
    assert "needs at least" in (bad / "refused.txt").read_text()
    assert len(err) == 2  # one line per refusal, one for the batch
    assert err[0].startswith("round2/Gyroscope rotation rate 1: refused: ")
    assert "1 of 2 recordings refused" in err[1] and "the other 1 are written" in err[1]
    summary = json.loads((out / "summary.json").read_text())  # what they say together
    assert summary["recordings"] == 2 and len(summary["rows"]) == 1
    assert summary["refused"][0]["name"] == "round2/Gyroscope rotation rate 1"
    assert "needs at least" in summary["refused"][0]["reason"]
    assert "Refused: 1 (round2/Gyroscope rotation rate 1: " in (out / "summary.md").read_text()


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
    assert json.loads((out / "summary.json").read_text())["refused"][0]["name"] == "notes"
    assert "notes.csv" in (out / "notes" / "refused.txt").read_text()
    assert len(err) == 2 and err[0].startswith("notes: refused: ")
    assert "1 of 2 recordings refused" in err[1]


def test_the_free_flights_of_a_phone_export_are_diagnosed_and_identified_each(tmp_path, hand_tosses,
                                                                            write_phyphox):
    """A phyphox export as the phone writes it (no segments file) of three tosses between
    which a hand holds the phone: one report per free flight, each saying where the flight was
    found, all rigid (the flights are torque-free); identify's notes say it too."""
    t, w, flights = hand_tosses()
    export = write_phyphox(tmp_path / "Gyroscope rotation rate 1", t, w)
    assert main(["diagnose", str(export), "--out", str(tmp_path / "out"), "--no-plots"]) == 0
    for k, (start, end) in enumerate(flights, start=1):
        folder = tmp_path / "out" / f"Gyroscope_rotation_rate_1_flight_{k}"
        report = json.loads((folder / "report.json").read_text())
        window = report["free_flight_window"]
        assert start <= window["t_start"] < window["t_end"] <= end and window["source"] == WINDOW_FOUND
        assert max(report["fit_after"]["rms_over_noise"]) < 1.5 and not report["explanation"]
        assert "found from the gyro" in (folder / "summary.md").read_text()
    across = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert across["diagnosed"] == 3 and across["leading_effects"] == {"none": 3}
    assert across["valid_fits"] == 3 and across["worst_rms_over_noise"]["after_median"] < 1.5
    assert main(["identify", str(export), "--out", str(tmp_path / "id"), "--no-plots"]) == 0
    result = tmp_path / "id" / "Gyroscope_rotation_rate_1_flight_2" / "identify.json"
    notes = json.loads(result.read_text())["notes"]
    assert any(n.startswith("free flight from t = 4.2") and "found from the gyro" in n for n in notes)
    # the body's shape from the three flights together (each spins near another principal axis)
    shape = json.loads((tmp_path / "id" / "summary.json").read_text())["principal_ratios"]
    truth = [1.0, 19.5 / 20.7, 1.39 / 20.7]
    assert shape["n"] == 3 and shape["source"] != "scatter"  # every flight's intervals usable
    assert all(lo <= r <= hi for r, (lo, hi) in zip(truth, shape["ci95"]))
    assert all(hi - lo < 0.05 for lo, hi in shape["ci95"])


def test_a_recording_named_like_the_summary_gets_its_own_folder(tmp_path):
    """A recording file "summary.md.csv" (named "summary.md") would have its folder where the
    summary of all is written: its folder gets "_" appended."""
    rec, side = simulate_recording(Scenario(), 2.0, seed=3, torque=False, sample_dt=0.01)
    folder = tmp_path / "throws"
    folder.mkdir()
    for name in ("summary.md", "LOG01"):
        write_recording(folder / f"{name}.csv", dataclasses.replace(rec, q=None), side)
    out = tmp_path / "out"
    assert main(["identify", str(folder), "--out", str(out), "--no-plots"]) == 0
    assert (out / "summary.md_" / "identify.json").is_file() and (out / "summary.md").is_file()
    assert json.loads((out / "summary.json").read_text())["identified"] == 2
