"""The shipped example recordings (inertia_gym.examples) and `inertia-gym example`: each is what
its simulation writes, reads back as a recording, and identify recovers its body."""

import json

import numpy as np
import pytest

from inertia_gym import examples
from inertia_gym.cli import main
from inertia_gym.errors import ConfigError
from inertia_gym.identification import identify
from inertia_gym.recordings import read_recordings


@pytest.mark.parametrize("name", examples.names())
def test_each_shipped_example_is_its_simulation_written_out(name, tmp_path):
    fresh = read_recordings(examples.regenerate(name, tmp_path))[0]
    shipped = read_recordings(examples.path(name))[0]
    for column in ("t", "w", "q", "tau", "h"):
        a, b = getattr(fresh, column), getattr(shipped, column)
        assert (a is None) == (b is None), column
        if a is not None:  # the CSV keeps 10 significant digits
            np.testing.assert_allclose(a, b, rtol=1e-8, atol=1e-12 * max(1.0, np.abs(b).max()))
    assert fresh.meta.keys() == shipped.meta.keys()


@pytest.mark.parametrize("name", ["thrown-rotor", "cubesat"])
def test_identify_recovers_the_example_bodys_inertia_within_its_intervals(name):
    rec = read_recordings(examples.path(name))[0]
    truth = np.array(json.loads(examples.path(name).with_suffix(".json").read_text())["inertia_nominal"])
    res = identify(rec)
    assert res.estimate.scale_identified
    moments, half = res.estimate.principal().moments, res.estimate.principal().half
    assert np.all(np.abs(moments - np.linalg.eigvalsh(truth)) <= 2 * half)


def test_the_example_command_copies_the_recording_and_its_sidecar(tmp_path, capsys):
    assert main(["example", "phone-toss", "--out", str(tmp_path)]) == 0
    assert (tmp_path / "phone-toss.csv").read_text() == examples.path("phone-toss").read_text()
    assert (tmp_path / "phone-toss.json").exists()
    assert "phone-toss.csv" in capsys.readouterr().out


def test_an_unknown_example_names_the_ones_there_are():
    with pytest.raises(ConfigError, match="the examples are cubesat, phone-toss, thrown-rotor"):
        examples.path("cubesta")
