from pathlib import Path

import numpy as np
import pytest

from inertia_gym.discrepancy.recordings import Recording, read_recordings
from inertia_gym.scenario import Scenario

#: The real racquet tosses beside the repository (or beside the folder holding its worktrees).
RACQUET = next((p / "shared/data/phyphox-racquet" for p in Path(__file__).resolve().parents
                if (p / "shared/data/phyphox-racquet").is_dir()), None)
#: The real rotor throws, found the same way.
ROTOR_THROWS = next((p / "shared/data/rotor-throws" for p in Path(__file__).resolve().parents
                     if (p / "shared/data/rotor-throws").is_dir()), None)


@pytest.fixture(scope="session")
def paper() -> Scenario:
    """The paper's scenario (defaults)."""
    return Scenario()


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


@pytest.fixture(scope="session")
def in_other_units():
    """other(rec, mass, rate) -> the same recording of a body `mass` times heavier whose motion
    runs `rate` times faster: t / rate, w * rate, torque * mass rate^2, momentum * mass rate, the
    sidecar's nominal inertia * mass and gyro noise * rate (the attitude is the same). Physics
    without a hidden scale reads it as the same recording, its results in the new units."""

    def other(rec: Recording, mass: float, rate: float) -> Recording:
        meta = {k: v for k, v in rec.meta.items() if k not in ("effect", "effects", "rotor")}
        if "inertia_nominal" in meta:
            meta["inertia_nominal"] = (np.asarray(meta["inertia_nominal"]) * mass).tolist()
        if "gyro_sigma" in meta:
            meta["gyro_sigma"] = meta["gyro_sigma"] * rate
        return Recording(rec.t / rate, rec.w * rate, rec.q,
                         None if rec.tau is None else rec.tau * mass * rate ** 2, meta, rec.name,
                         h=None if rec.h is None else rec.h * mass * rate)

    return other


@pytest.fixture(scope="session")
def racquet_toss():
    """toss(round_name, segment, shift=(0, 0)) -> the Recording of a real racquet toss's kept
    free-flight window with its start and end moved by shift (s), cut from the raw file (so it
    may widen past the window); the test skips where ../shared/data is absent."""
    if RACQUET is None:
        pytest.skip("development data (../shared/data) absent")

    def toss(round_name: str, segment: int, shift=(0.0, 0.0)) -> Recording:
        for raw in sorted((RACQUET / round_name).glob("*/Raw Data.csv")):
            for rec in read_recordings(raw.parent):
                if rec.meta["segment"] == segment:
                    start, end = rec.meta["window"]
                    table = np.loadtxt(raw, delimiter=",", skiprows=1)
                    keep = (table[:, 0] >= start + shift[0]) & (table[:, 0] <= end + shift[1])
                    return Recording(table[keep, 0], table[keep, 1:4],
                                     name=f"{round_name} segment {segment} {shift}")
        raise LookupError(f"no segment {segment} in {RACQUET / round_name}")

    return toss


@pytest.fixture(scope="session")
def rotor_throw():
    """throw(stem) -> the Recording of a real rotor throw (its h columns as logged); the test
    skips where ../shared/data is absent."""
    if ROTOR_THROWS is None:
        pytest.skip("development data (../shared/data) absent")
    return lambda stem: read_recordings(ROTOR_THROWS / f"{stem}.csv")[0]
