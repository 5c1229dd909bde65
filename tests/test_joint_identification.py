"""identify_joint: one inertia from several recordings of one body, and the command's --joint."""

import dataclasses
import json

import numpy as np
import pytest

from inertia_gym.cli import main
from inertia_gym.discrepancy.synthetic import simulate_recording
from inertia_gym.errors import RecordingError
from inertia_gym.joint_identification import identify_joint
from inertia_gym.recordings import write_recording
from inertia_gym.scenario import Scenario

BODY = [[5.2e-4, 2e-6, 1e-6], [2e-6, 2.2e-4, 6e-6], [1e-6, 6e-6, 5.2e-4]]


def _throws(count, rotor=2e-3, body=BODY):
    """0.5-s, 4-kHz gyro-only throws of one body from different spins, a rotor spinning up."""
    out = []
    for seed in range(count):
        sc = Scenario(inertia_true=body, inertia_guess=body, omega0=[15.0, -6.0 + seed, -10.0],
                      dt=0.00025, gyro_sigma=0.01, tau_max=1e-4)
        rec, _ = simulate_recording(sc, 0.5, seed=seed, torque=False, rotor_h_max=rotor)
        out.append(dataclasses.replace(rec, q=None, name=f"throw-{seed}"))
    return out


def test_one_body_in_several_throws_is_one_inertia_within_its_intervals_and_agrees():
    joint = identify_joint(_throws(4))
    truth = np.array(BODY)
    theta = np.array([truth[0, 0], truth[0, 1], truth[0, 2], truth[1, 1], truth[1, 2], truth[2, 2]])
    assert joint.estimator == "output error"  # the simulator's own model: the lack of fit passes
    assert np.all(np.abs(joint.estimate.theta - theta) <= 3.5 * joint.estimate.sigma)
    assert joint.agreement_p > 1e-3 and joint.agreement_dof == 18
    # tighter than any one throw's intervals
    assert max(np.trace(joint.estimate.theta_cov) / np.trace(s.estimate.theta_cov) for s in joint.singles) < 1


def test_two_bodies_are_told_apart_by_the_agreement_test():
    other = np.diag([3e-4, 4e-4, 5e-4])
    joint = identify_joint(_throws(2) + _throws(2, body=other.tolist()))
    assert joint.agreement_p < 1e-3
    assert any("disagree beyond their intervals" in n for n in joint.notes)


def test_a_joint_fit_needs_two_recordings_and_one_kind_of_scale():
    throws = _throws(2)
    with pytest.raises(RecordingError, match="at least two"):
        identify_joint(throws[:1])
    free = _throws(1, rotor=None)
    with pytest.raises(RecordingError, match="fix the inertia's scale"):
        identify_joint([throws[0], free[0]])


def test_identify_joint_cli_writes_joint_json_and_markdown(tmp_path, capsys, monkeypatch):
    """--joint writes joint.json and joint.md and prepares each record once (the joint fit takes
    the prepared records of the single fits)."""
    import inertia_gym.commands.identify as command
    import inertia_gym.identification as identification
    import inertia_gym.joint_identification as joint_module

    folder = tmp_path / "throws"
    folder.mkdir()
    for rec in _throws(3):
        write_recording(folder / f"{rec.name}.csv", rec, {"gyro_sigma": 0.01})
    out = tmp_path / "out"
    calls = []
    real = command.prepared

    def counted(rec):
        calls.append(rec.name)
        return real(rec)

    for module in (command, identification, joint_module):
        monkeypatch.setattr(module, "prepared", counted)
    assert main(["identify", str(folder), "--joint", "--no-plots", "--out", str(out)]) == 0
    assert sorted(calls) == ["throw-0", "throw-1", "throw-2"]
    summary = json.loads((out / "joint.json").read_text())
    assert summary["names"] == ["throw-0", "throw-1", "throw-2"]
    assert len(summary["per_recording"]) == 3 and summary["scale_identified"] is True
    assert np.array(summary["inertia"]).shape == (3, 3)
    assert "One inertia from 3 recordings" in (out / "joint.md").read_text()
    assert "joint (3 recordings" in capsys.readouterr().out
    assert main(["identify", str(folder), "--joint", "--method", "ekf", "--out", str(tmp_path / "e")]) == 2
