import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import settings

from inertia_gym.recordings import PHYPHOX_COLUMNS, Recording, read_recordings
from inertia_gym.scenario import Scenario

# The suite draws the same examples on every run (a test passes or fails on the code, not on the
# draw) and prints the blob that reproduces a failure; `pytest --hypothesis-profile explore` draws
# new ones, as a study.
settings.register_profile("suite", derandomize=True, database=None, print_blob=True)
settings.register_profile("explore", print_blob=True)
settings.load_profile("suite")

# the suite's xdist workers already fill the cores: diagnose's fits run without helper processes
# (tests/test_executors.py switches them on where it tests them)
os.environ["INERTIA_GYM_HELPERS"] = "0"

#: The kernels most workers need, compiled once before the workers start, in two parallel
#: processes; each worker then loads them from numba's on-disk cache instead of compiling the
#: same code beside the other worker. The first process compiles three of the simulation loop's
#: four kernels (the first of them also compiles the callees all four share, most of the loop's
#: compile time). The second runs `identify` (its three methods) and `diagnose` on the shipped
#: examples and one step of the environment (the information metric), then the loop's fourth
#: kernel and the batch propagator of both integrators, by when the first process has cached the
#: callees they share: the two take about equally long (under a minute each on 2 cores, with an empty cache).
WARM_UP = (
    "from inertia_gym.simulation import compile_loop; "
    "compile_loop(('_segment_one', '_segment_lanes', '_segment_tasks'))",
    "import gymnasium as gym; import numpy as np; "
    "from inertia_gym import examples, identify, read_recordings as read; "
    "from inertia_gym.discrepancy.report import diagnose; "
    "rec = read(examples.path('thrown-rotor'))[0]; [identify(rec, m) for m in ('ml', 'ekf', 'ukf')]; "
    "diagnose(read(examples.path('phone-toss'))[0]); "
    "env = gym.make('InertiaGym/Excitation-v0'); env.reset(seed=0); env.step(env.action_space.sample()); "
    "from inertia_gym.simulation import compile_loop; compile_loop(('_segment_tasks_one_lane',)); "
    "from inertia_gym.dynamics import propagate_batch; "
    "[propagate_batch(np.array([[1.0, 0, 0, 0]]), np.array([[0.1, 1, 0.2]]), np.eye(3), "
    "np.zeros((1, 3, 3)), 0.01, method=m) for m in ('rk4', 'gauss')]",
)


def pytest_sessionstart(session):
    """Warm numba's cache (:data:`WARM_UP`) when the run fans out over xdist workers; a worker
    (which has ``workerinput``) and a one-process run compile as they go. A warm-up that fails
    changes no result (the tests that need the kernel compile it and report any error
    themselves), but the run is slower: its last error line is printed."""
    config = session.config
    if hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", None):
        return
    env = dict(os.environ, MPLBACKEND="Agg")
    # each process's errors go to a file of its own: a pipe left unread while the other process
    # is awaited could fill and stall it
    logs = [tempfile.TemporaryFile("w+") for _ in WARM_UP]
    procs = [subprocess.Popen([sys.executable, "-c", code], env=env, stdout=subprocess.DEVNULL,
                              stderr=log) for code, log in zip(WARM_UP, logs)]
    reporter = config.pluginmanager.get_plugin("terminalreporter")
    for i, (proc, log) in enumerate(zip(procs, logs)):
        proc.wait()
        log.seek(0)
        lines = log.read().strip().splitlines() or ["no error output"]
        log.close()
        if proc.returncode and reporter is not None:
            reporter.write_line(f"warm-up {i} failed (the workers compile its kernels): {lines[-1]}")


def pytest_configure(config):
    """An xdist worker runs its compiled loops, BLAS and torch on its share of the cores: two
    workers each running two threads on two cores time-slice every parallel section (the suite
    takes about 10 % longer so). Tests that need more threads raise the limit around themselves."""
    workers = getattr(config, "workerinput", {}).get("workercount")
    if not workers:
        return
    import numba
    import torch
    from threadpoolctl import threadpool_limits

    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    share = max(1, cores // int(workers))
    numba.set_num_threads(min(share, numba.config.NUMBA_NUM_THREADS))
    torch.set_num_threads(share)
    threadpool_limits(share)


def pytest_collection_modifyitems(config, items):
    """The slow tests first (a stable sort: each group keeps its order). xdist hands the tests
    out in this order, so the long ones start while there is still work to balance them; last in
    file order, the two validate tests (50 s each alone, 3 minutes each beside other work) would
    leave one worker running them while the other sits idle."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)


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


@pytest.fixture
def kept_fits(monkeypatch) -> list:
    """The fits of every diagnosis the test runs, as report._fits returns them (data, nominal,
    singles, chosen), kept in this list: a test reads them beside the report of one diagnosis
    instead of fitting the record again."""
    from inertia_gym.discrepancy import report

    kept, fits = [], report._fits
    monkeypatch.setattr(report, "_fits", lambda prep: kept.append(fits(prep)) or kept[-1])
    return kept


#: The header of phyphox's gyro export (its "Absolute" column after the recordings' own).
PHYPHOX_HEADER = ",".join(f'"{name}"' for name in (*PHYPHOX_COLUMNS, "Absolute (rad/s)"))


@pytest.fixture(scope="session")
def write_phyphox():
    """write(folder, t (n,) s, w (n, 3) rad/s, segments=None) -> folder: a phyphox gyro export
    there, its "Raw Data.csv" and, where segments (the text of a meta/segments.csv) is given,
    that file (phyphox itself writes none)."""

    def write(folder: Path, t, w, segments: str | None = None) -> Path:
        folder.mkdir(parents=True, exist_ok=True)
        rows = [",".join(f"{v:.9E}" for v in (ti, *wi, np.linalg.norm(wi))) for ti, wi in zip(t, w)]
        (folder / "Raw Data.csv").write_text("\n".join([PHYPHOX_HEADER, *rows]) + "\n")
        if segments is not None:
            (folder / "meta").mkdir(exist_ok=True)
            (folder / "meta" / "segments.csv").write_text(segments)
        return folder

    return write


@pytest.fixture(scope="session")
def hand_tosses():
    """tosses(rate=1) -> (t (n,) s, w (n, 3) rad/s, flights): a phone's gyro through three tosses
    of a racquet-like body (moments 20.7, 19.5, 1.39 g·m², 100 Hz, noise 2e-3 rad/s): a hand
    turning it at 1-4 Hz, a 0.1-s throw up to a spin near one principal axis, 1 s of torque-free
    flight, a 0.05-s catch, and so on; flights [(t_start, t_end)] of the free flights. rate
    runs the whole motion that many times faster (t / rate, w * rate, noise * rate)."""
    from inertia_gym.dynamics import propagate

    def tosses(rate: float = 1.0):
        rng = np.random.default_rng(7)
        dt, inertia = 0.01, np.diag([20.7e-3, 19.5e-3, 1.39e-3])
        spins = ([0.3, 10.0, 0.2], [0.2, 0.4, 25.0], [12.0, 0.5, 0.3])  # rad/s: near each axis
        pieces, flights, now = [], [], 0.0

        def add(w):
            nonlocal now
            pieces.append(w)
            now += dt * len(w)

        for spin in spins:
            hand_t = np.arange(150) * dt
            phases = rng.uniform(0, 2 * np.pi, (3, 3))
            add(sum(0.6 * np.sin(2 * np.pi * f * hand_t[:, None] + phases[k])
                    for k, f in enumerate((1.0, 2.3, 3.7))))
            add(np.linspace(pieces[-1][-1], spin, 11)[1:])  # the throw: 0.1 s
            _, w = propagate([1, 0, 0, 0], spin, inertia, np.zeros((100, 3)), dt)
            flights.append((now, now + dt * 100))
            add(w)
            add(np.linspace(w[-1], 0.0, 6)[1:])  # the catch: 0.05 s
        add(np.zeros((100, 3)))  # put down
        w = np.concatenate(pieces) + rng.normal(0, 2e-3, (sum(map(len, pieces)), 3))
        t = np.arange(w.shape[0]) * dt
        return t / rate, w * rate, [(a / rate, b / rate) for a, b in flights]

    return tosses
