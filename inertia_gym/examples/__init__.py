"""Example recordings shipped with the package, made by the project's own simulator.

Every quick start runs on them, without any data of your own:

* ``cubesat``: a 6U CubeSat's gyro and attitude telemetry, 120 s at 10 Hz, with reaction-wheel
  torque bursts logged (the shipped ``cubesat-6u`` scenario);
* ``thrown-rotor``: a 0.5-s throw of a small device (about 5e-4 kg·m²) logged at 1 kHz, without
  torque, whose rotor's known momentum spins up and down (the h columns) and fixes the scale;
* ``phone-toss``: a phone tossed for 1 s at 100 Hz, without torque, in air: the drag is in the
  data but not in the rigid model (the sidecar's ``effect`` holds the truth, which neither
  ``identify`` nor ``diagnose`` reads).

``path(name)`` gives the shipped CSV (its sidecar JSON beside it); ``make(name)`` simulates the
record again (the shipped files are exactly this, written by ``write(name, folder)``).
"""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

from inertia_gym.discrepancy.synthetic import simulate_recording
from inertia_gym.errors import ConfigError
from inertia_gym.recordings import Recording, write_recording
from inertia_gym.scenario import Scenario

FOLDER = Path(__file__).parent

#: name: (scenario fields over the paper's, simulate_recording's arguments; attitude False: a
#: gyro-only record, as a thrown phone logs)
EXAMPLES: dict[str, tuple[dict, dict]] = {
    "cubesat": ({"__load__": "cubesat-6u"}, {"duration": 120.0, "sample_dt": 0.1, "seed": 1}),
    "thrown-rotor": ({"inertia_true": [[5.2e-4, 2e-6, 1e-6], [2e-6, 2.2e-4, 6e-6], [1e-6, 6e-6, 5.2e-4]],
                      "inertia_guess": [[5e-4, 0, 0], [0, 2.5e-4, 0], [0, 0, 5e-4]],
                      "omega0": [15.0, -6.0, -10.0], "dt": 2.5e-4, "gyro_sigma": 0.01, "tau_max": 1e-4},
                     {"duration": 0.5, "sample_dt": 1e-3, "seed": 2, "torque": False, "rotor_h_max": 2e-3,
                      "attitude": False}),
    "phone-toss": ({"inertia_true": [[1.6e-4, 0, 0], [0, 4.4e-4, 0], [0, 0, 5.8e-4]],
                    "inertia_guess": [[1.7e-4, 0, 0], [0, 4.2e-4, 0], [0, 0, 5.6e-4]],
                    "omega0": [2.0, 12.0, 1.0], "dt": 1e-3, "gyro_sigma": 2e-3, "tau_max": 1e-4},
                   {"duration": 1.0, "sample_dt": 0.01, "seed": 3, "torque": False,
                    "effect_name": "aero_drag", "attitude": False}),
}


def names() -> list[str]:
    """The shipped examples' names."""
    return sorted(EXAMPLES)


def _checked(name: str) -> str:
    if name not in EXAMPLES:
        raise ConfigError(f"no example {name!r}; the examples are {', '.join(names())}")
    return name


def path(name: str) -> Path:
    """The shipped CSV of an example (its sidecar NAME.json beside it)."""
    return FOLDER / f"{_checked(name)}.csv"


def make(name: str) -> tuple[Recording, dict]:
    """The example simulated again: (recording, sidecar)."""
    fields, args = (dict(d) for d in EXAMPLES[_checked(name)])
    scenario = Scenario.load(fields.pop("__load__")) if "__load__" in fields else Scenario()
    attitude = args.pop("attitude", True)
    rec, side = simulate_recording(scenario.replace(**fields) if fields else scenario, **args)
    if not attitude:
        side = {k: v for k, v in side.items() if k != "quat_sigma"}
        rec = dataclasses.replace(rec, q=None, meta=side)
    return rec, side


def write(name: str, folder: str | Path) -> Path:
    """Copy the shipped example into folder (created if needed); returns the CSV's path there."""
    source = path(name)
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    target = folder / source.name
    shutil.copyfile(source, target)
    shutil.copyfile(source.with_suffix(".json"), target.with_suffix(".json"))
    return target


def regenerate(name: str, folder: str | Path = FOLDER) -> Path:
    """Simulate the example and write it into folder (the package's own by default)."""
    rec, side = make(name)
    target = Path(folder) / f"{name}.csv"
    for stale in (target, target.with_suffix(".json")):
        stale.unlink(missing_ok=True)
    write_recording(target, rec, side)
    return target
