"""The Basilisk concealed-effect harness's cases and scoring (scripts/basilisk_harness.py runs it;
the tests use it): each case is a spacecraft simulated by Basilisk (basilisk_sim.py): a hub with
slosh particles, hinged panels, reaction wheels, commanded torque bursts, a hidden constant
torque, and a gyro with noise, bias or scale error. The recording carries what a user would log
and the hub-only nominal inertia; the concealed truth sits under the sidecar key
`basilisk_truth`, which `diagnose` does not read. `diagnose` runs on the file read back from
disk, and the case is scored against the table ACCEPTED.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np
from basilisk_sim import TRUTH_KEY, Panel, Slosh, SpacecraftCase, Wheels, simulate

from inertia_gym.discrepancy.report import diagnose
from inertia_gym.discrepancy.summary import DISSIPATIVE_ZETA
from inertia_gym.recordings import read_recordings, write_recording

# What counts as a correct diagnosis of each concealed component: the catalogue names that
# describe physics present in the Basilisk truth (docs/contracts.md, "Effect catalogue").
# - slosh, panel (their mass is missing from the hub-only nominal): `inertia_offset` (the
#   vehicle's rigid-equivalent inertia is not the nominal), `flexible_mode` (the particle on its
#   spring / the panel on its hinge spring is a modal coordinate coupled to the hub),
#   `internal_dissipation` (their dampers take energy and keep the angular momentum). Not
#   `actuator_scale` (the actuator is exact: a scale only mimics the missing inertia's trace)
#   nor `inertia_change` (nothing changes in time).
# - hidden_wheels: free balanced wheels keep their absolute spin momentum: a constant internal
#   momentum, exactly `internal_momentum`.
# - hidden_torque: a constant body-frame torque: `constant_body_torque`.
# - gyro_bias, gyro_scale: added to the reading: `gyro_bias`, `gyro_scale`.
# - gyro_drift: a bias random walk added to the reading: `gyro_bias` (its varying form, on a record
#   long enough for it).
# - slosh_damped: a slosh whose damping ratio is at least DISSIPATIVE_ZETA (no resonance: the
#   particle sheds its energy within about a period): the same names; whether the explanation
#   reads it as dissipation (reads_dissipation) is reported beside.
MASS_LEFT_OUT = ("inertia_offset", "flexible_mode", "internal_dissipation")
ACCEPTED = {
    "slosh": MASS_LEFT_OUT,
    "slosh_damped": MASS_LEFT_OUT,
    "panel": MASS_LEFT_OUT,
    "hidden_wheels": ("internal_momentum",),
    "hidden_torque": ("constant_body_torque",),
    "gyro_bias": ("gyro_bias",),
    "gyro_scale": ("gyro_scale",),
    "gyro_drift": ("gyro_bias",),
}
#: Components that count only in one form of their accepted effect: a drift is the bias's varying
#: form (its constant form leaves the walk in the residual).
FORM = {"gyro_drift": "varying"}

#: Hub classes: mass kg and size m; the hub inertia is mass * size^2 * SHAPE.
#: From a thrown device (largest moment 1e-4 kg·m²) to an upper stage (1e4 kg·m²).
BODIES = {"device": (0.05, 0.1), "cubesat": (4.0, 0.15), "smallsat": (150.0, 1.0), "bus": (1500.0, 2.0),
          "stage": (3000.0, 4.0)}
SHAPE = np.array([[0.21, 0.004, -0.003], [0.004, 0.17, 0.002], [-0.003, 0.002, 0.12]])
RATE = 0.3  # rad/s, the initial tumble rate
ACCEL = 0.01  # rad/s^2: burst torque = ACCEL * largest hub moment
WHEEL_SPIN_SHARE = 1e-4  # a wheel's spin inertia / the largest hub moment
#: The subset `make test` runs (tests/discrepancy/test_basilisk.py), with 30-s recordings.
SMOKE = ("control_smallsat_bursts", "control_bus_free", "slosh_smallsat_bursts", "panel_smallsat_free",
         "wheels_smallsat_free", "torque_smallsat_free", "control_stage_bursts", "slosh_device_bursts")


def hub(body: str) -> tuple[float, np.ndarray]:
    """Hub mass (kg) and inertia (3, 3) kg·m² of a body class."""
    mass, size = BODIES[body]
    return mass, mass * size ** 2 * SHAPE


def components(case: SpacecraftCase) -> list[str]:
    """The concealed components of a case (keys of ACCEPTED); [] for a control."""
    out = []
    if any(p.damping_ratio < DISSIPATIVE_ZETA for p in case.slosh):
        out.append("slosh")
    if any(p.damping_ratio >= DISSIPATIVE_ZETA for p in case.slosh):
        out.append("slosh_damped")
    if case.panels:
        out.append("panel")
    if case.wheels is not None and not case.wheels.logged:
        out.append("hidden_wheels")
    if any(case.hidden_torque):
        out.append("hidden_torque")
    if any(case.gyro_bias):
        out.append("gyro_bias")
    if any(case.gyro_scale):
        out.append("gyro_scale")
    if case.gyro_bias_walk:
        out.append("gyro_drift")
    return out


def _direction(seed: int) -> tuple:
    v = np.random.default_rng(seed).normal(size=3)
    return tuple((v / np.linalg.norm(v)).tolist())


def base(name: str, body: str, seed: int, bursts: bool, **kw) -> SpacecraftCase:
    """A hub of the class `body` tumbling at RATE about a seeded axis, optionally with bursts."""
    mass, inertia = hub(body)
    omega0 = tuple((RATE * np.asarray(_direction(seed))).tolist())
    burst = ACCEL * float(np.linalg.eigvalsh(inertia).max()) if bursts else 0.0
    return SpacecraftCase(name, mass, tuple(map(tuple, inertia.tolist())), omega0, burst_torque=burst,
                          seed=seed, **kw)


def slosh(body: str, mass_share: float, frequency_hz: float, damping_ratio: float, seed: int) -> Slosh:
    """A slosh particle of mass_share x the hub mass, 0.4 size from the centre, seeded direction."""
    mass, size = BODIES[body]
    pos = 0.4 * size * np.asarray(_direction(seed + 100))
    return Slosh(mass_share * mass, tuple(pos.tolist()), _direction(seed + 200), frequency_hz, damping_ratio,
                 rho0=0.02 * size)


def panel(body: str, mass_share: float, frequency_hz: float, damping_ratio: float,
          side: float = 1.0) -> Panel:
    """A solar panel of mass_share x the hub mass hinged at side * 0.5 size on the body x axis,
    extending outwards (arm 0.6 size), turning about the body y axis.
    """
    mass, size = BODIES[body]
    m = mass_share * mass
    inertia = (m * (0.6 * size) ** 2 / 12, m * (1.2 * size) ** 2 / 12, m * (1.4 * size) ** 2 / 12)
    dcm = ((-side, 0.0, 0.0), (0.0, -side, 0.0), (0.0, 0.0, 1.0))  # first hinge axis points inwards
    return Panel(m, inertia, (side * 0.5 * size, 0.0, 0.0), dcm, 0.6 * size, frequency_hz, damping_ratio,
                 theta0=0.05)


def wheels(body: str, momentum_share: float, logged: bool, seed: int, motor: float = 0.0) -> Wheels:
    """Three orthogonal wheels; their momentum is momentum_share x the hub's |J w0| at RATE (spin
    inertia WHEEL_SPIN_SHARE x the largest hub moment, speeds set to match); motor: each wheel's
    motor torque in units of its spin inertia (rad/s², see Wheels.motor_torque).
    """
    _, inertia = hub(body)
    js = WHEEL_SPIN_SHARE * float(np.linalg.eigvalsh(inertia).max())
    h = momentum_share * RATE * float(np.linalg.eigvalsh(inertia).max()) * np.asarray(_direction(seed + 300))
    return Wheels(((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)), (js, js, js), tuple((h / js).tolist()),
                  logged, motor * js)


def torque(body: str, accel: float, seed: int) -> tuple:
    """A hidden constant body torque of accel (rad/s^2) x the largest hub moment, seeded axis."""
    _, inertia = hub(body)
    size = accel * float(np.linalg.eigvalsh(inertia).max())
    return tuple((size * np.asarray(_direction(seed + 400))).tolist())


def cases(duration: float) -> list[SpacecraftCase]:
    """The harness's cases: 17 controls, 38 single concealed components, 10 pairs."""
    d = dict(duration=duration)
    c = [
        base("control_cubesat_free", "cubesat", 1, False, **d),
        base("control_smallsat_free", "smallsat", 2, False, **d),
        base("control_bus_free", "bus", 3, False, **d),
        base("control_cubesat_bursts", "cubesat", 4, True, **d),
        base("control_smallsat_bursts", "smallsat", 5, True, **d),
        base("control_bus_bursts", "bus", 6, True, **d),
        base("control_smallsat_logged_wheels", "smallsat", 7, False,
             wheels=wheels("smallsat", 0.1, True, 7, 5.0), **d),
        base("control_bus_logged_wheels_bursts", "bus", 8, True, wheels=wheels("bus", 0.1, True, 8, 5.0),
             **d),
        base("control_smallsat_no_attitude", "smallsat", 9, True, quat_sigma=None, **d),
        base("control_smallsat_20hz", "smallsat", 10, True, sample_dt=0.05, duration=duration / 2),
        base("control_cubesat_steady_wheels", "cubesat", 11, False, wheels=wheels("cubesat", 0.2, True, 11),
             **d),
        base("control_bus_short", "bus", 12, False, duration=min(duration, 30.0)),
        # slosh: hub-only nominal, propellant mass left out
        base("slosh_smallsat_free", "smallsat", 21, False, slosh=(slosh("smallsat", 0.1, 0.3, 0.05, 21),),
             **d),
        base("slosh_smallsat_bursts", "smallsat", 22, True, slosh=(slosh("smallsat", 0.1, 0.3, 0.05, 22),),
             **d),
        base("slosh_bus_bursts", "bus", 23, True, slosh=(slosh("bus", 0.05, 0.15, 0.2, 23),), **d),
        base("slosh_cubesat_free", "cubesat", 24, False, slosh=(slosh("cubesat", 0.15, 0.5, 0.3, 24),), **d),
        base("slosh_bus_small_free", "bus", 25, False, slosh=(slosh("bus", 0.03, 0.2, 0.02, 25),), **d),
        # slosh damped past resonance (a propellant management device, a viscous damper)
        base("slosh_damped_smallsat_free", "smallsat", 26, False,
             slosh=(slosh("smallsat", 0.1, 0.3, 1.0, 26),), **d),
        base("slosh_damped_smallsat_bursts", "smallsat", 27, True,
             slosh=(slosh("smallsat", 0.1, 0.3, 1.0, 27),), **d),
        base("slosh_damped_bus_bursts", "bus", 28, True, slosh=(slosh("bus", 0.05, 0.15, 3.0, 28),), **d),
        base("slosh_damped_cubesat_free", "cubesat", 29, False,
             slosh=(slosh("cubesat", 0.15, 0.5, 2.0, 29),), **d),
        # hinged panels: panel mass left out
        base("panel_smallsat_free", "smallsat", 31, False, panels=(panel("smallsat", 0.04, 0.5, 0.02),), **d),
        base("panel_smallsat_bursts", "smallsat", 32, True, panels=(panel("smallsat", 0.04, 0.5, 0.02),),
             **d),
        base("panel_bus_pair_bursts", "bus", 33, True,
             panels=(panel("bus", 0.03, 0.3, 0.05), panel("bus", 0.03, 0.3, 0.05, side=-1.0)), **d),
        base("panel_cubesat_bursts", "cubesat", 34, True, panels=(panel("cubesat", 0.05, 1.0, 0.05),), **d),
        base("panel_bus_damped_free", "bus", 35, False, panels=(panel("bus", 0.02, 0.4, 0.4),), **d),
        # reaction wheels spinning, their momentum not logged
        base("wheels_smallsat_free", "smallsat", 41, False, wheels=wheels("smallsat", 0.05, False, 41), **d),
        base("wheels_smallsat_bursts", "smallsat", 42, True, wheels=wheels("smallsat", 0.05, False, 42), **d),
        base("wheels_bus_bursts", "bus", 43, True, wheels=wheels("bus", 0.1, False, 43), **d),
        base("wheels_cubesat_free", "cubesat", 44, False, wheels=wheels("cubesat", 0.03, False, 44), **d),
        # a constant body torque (magnetic residual dipole, outgassing, a leak)
        base("torque_smallsat_free", "smallsat", 51, False, hidden_torque=torque("smallsat", 1e-4, 51), **d),
        base("torque_bus_bursts", "bus", 52, True, hidden_torque=torque("bus", 2e-4, 52), **d),
        base("torque_cubesat_small_free", "cubesat", 53, False, hidden_torque=torque("cubesat", 2e-5, 53),
             **d),
        base("torque_smallsat_small_bursts", "smallsat", 54, True, hidden_torque=torque("smallsat", 3e-5, 54),
             **d),
        # gyro errors added to the reading
        base("bias_smallsat_free", "smallsat", 61, False, gyro_bias=(1e-3, -6e-4, 4e-4), **d),
        base("bias_bus_bursts", "bus", 62, True, gyro_bias=(-5e-4, 8e-4, 3e-4), **d),
        base("bias_cubesat_bursts", "cubesat", 63, True, gyro_bias=(2e-3, 1e-3, -1.5e-3), **d),
        base("scale_smallsat_bursts", "smallsat", 71, True, gyro_scale=(0.01, -0.005, 0.008), **d),
        base("scale_bus_bursts", "bus", 72, True, gyro_scale=(-0.008, 0.004, 0.012), **d),
        base("scale_cubesat_free", "cubesat", 73, False, gyro_scale=(0.015, -0.01, 0.0), **d),
        # pairs
        base("pair_slosh_bias", "smallsat", 81, True, slosh=(slosh("smallsat", 0.08, 0.3, 0.1, 81),),
             gyro_bias=(8e-4, -5e-4, 6e-4), **d),
        base("pair_panel_torque", "bus", 82, True, panels=(panel("bus", 0.03, 0.4, 0.05),),
             hidden_torque=torque("bus", 1e-4, 82), **d),
        base("pair_wheels_slosh", "smallsat", 83, False, wheels=wheels("smallsat", 0.05, False, 83),
             slosh=(slosh("smallsat", 0.08, 0.3, 0.1, 83),), **d),
        base("pair_wheels_scale", "bus", 84, True, wheels=wheels("bus", 0.05, False, 84),
             gyro_scale=(0.01, -0.008, 0.005), **d),
        base("pair_torque_bias", "smallsat", 85, True, hidden_torque=torque("smallsat", 1e-4, 85),
             gyro_bias=(6e-4, 6e-4, -8e-4), **d),
        base("pair_panel_wheels", "smallsat", 86, False, panels=(panel("smallsat", 0.04, 0.5, 0.05),),
             wheels=wheels("smallsat", 0.05, False, 86), **d),
        base("pair_slosh_panel", "bus", 87, True, slosh=(slosh("bus", 0.05, 0.2, 0.1, 87),),
             panels=(panel("bus", 0.03, 0.4, 0.05),), **d),
        base("pair_torque_slosh", "cubesat", 88, False, hidden_torque=torque("cubesat", 1e-4, 88),
             slosh=(slosh("cubesat", 0.1, 0.4, 0.1, 88),), **d),
    ]
    # a slow upper stage logged for 20 min at 2 Hz, its propellant sloshing at 0.02 Hz (a
    # period of 50 s: under a fixed 0.05-Hz screening floor, out of reach)
    slow = base("slosh_stage_slow_bursts", "stage", 960, True, slosh=(slosh("stage", 0.1, 0.02, 0.05, 960),),
                **d)
    c.append(dataclasses.replace(slow, omega0=tuple((np.asarray(slow.omega0) * 0.02 / RATE).tolist()),
                                 burst_torque=slow.burst_torque * 0.02, sample_dt=0.5,
                                 duration=20 * duration, gyro_sigma=2e-5))
    # ten times as long at 2 Hz: long enough for a bias that drifts (knots 30 s apart); a control
    # of that length, bias random walks of about 4 and 6 noise levels over the record, and one
    # beside a hidden torque
    long = dict(duration=10 * duration, sample_dt=0.5)
    walk = SpacecraftCase.gyro_sigma / np.sqrt(long["duration"])  # 1 noise level over the record
    c += [
        base("control_smallsat_long_free", "smallsat", 91, False, **long),
        base("drift_smallsat_long_free", "smallsat", 92, False, gyro_bias_walk=4 * walk, **long),
        base("drift_bus_long_bursts", "bus", 93, True, gyro_bias_walk=6 * walk, gyro_bias=(4e-4, -3e-4, 2e-4),
             **long),
        base("pair_drift_torque_long", "smallsat", 94, False, gyro_bias_walk=4 * walk,
             hidden_torque=torque("smallsat", 1e-4, 94), **long),
    ]
    for body, seed in (("stage", 900), ("device", 950)):  # the extremes of scale, one case of each kind
        c += [
            base(f"control_{body}_free", body, seed + 1, False, **d),
            base(f"control_{body}_bursts", body, seed + 2, True, **d),
            base(f"slosh_{body}_bursts", body, seed + 3, True,
                 slosh=(slosh(body, 0.1, 0.3, 0.05, seed + 3),), **d),
            base(f"panel_{body}_bursts", body, seed + 4, True, panels=(panel(body, 0.04, 0.5, 0.02),), **d),
            base(f"wheels_{body}_free", body, seed + 5, False,
                 wheels=wheels(body, 0.05, False, seed + 5), **d),
            base(f"torque_{body}_free", body, seed + 6, False,
                 hidden_torque=torque(body, 1e-4, seed + 6), **d),
            base(f"bias_{body}_bursts", body, seed + 7, True, gyro_bias=(1e-3, -6e-4, 4e-4), **d),
            base(f"scale_{body}_bursts", body, seed + 8, True, gyro_scale=(0.01, -0.005, 0.008), **d),
        ]
    return c


def named_effects(report: dict, count: int) -> list[str]:
    """The names the report gives: its compound `explanation` where present, else its leading
    `count` significant single effects (where the explanation is empty).
    """
    if report.get("explanation"):
        return [e["name"] for e in report["explanation"]]
    return [e["name"] for e in report["effects"] if e["significant"]][:count]


def reads_dissipation(report: dict) -> bool:
    """Whether the explanation reads as internal dissipation: internal_dissipation in it, or a
    flexible_mode damped past resonance (the summary's reading, DISSIPATIVE_ZETA).
    """
    expl = report.get("explanation") or []
    return any(e["name"] == "internal_dissipation" or (
        e["name"] == "flexible_mode" and float(e.get("params", {}).get("zeta", 0.0)) >= DISSIPATIVE_ZETA)
        for e in expl)


def score(case: SpacecraftCase, report: dict) -> dict:
    """Correctness of one report (see ACCEPTED): a control must name nothing and detect no
    mismatch; a single component must lead; each component of a pair must be among the names
    given; a component in FORM, in that form in the explanation. Beside it: the names given for
    physics the truth does not hold (outside_truth: padding) and whether the explanation reads
    as internal dissipation (reads_dissipation).
    """
    parts = components(case)
    significant = [e for e in report["effects"] if e["significant"]]
    named = named_effects(report, max(1, len(parts)))
    forms = {(e["name"], e.get("form")) for e in report.get("explanation") or []}
    if any((name, FORM[p]) not in forms for p in parts if p in FORM for name in ACCEPTED[p]):
        correct = False
    elif not parts:
        correct = not significant and not report.get("explanation") and not report["mismatch_detected"]
    elif len(parts) == 1:
        correct = bool(named) and named[0] in ACCEPTED[parts[0]]
    else:
        correct = all(any(n in ACCEPTED[p] for n in named) for p in parts)
    top = significant[0] if significant else None
    truth = {n for p in parts for n in ACCEPTED[p]}
    return {
        "case": case.name, "components": parts, "accepted": {p: list(ACCEPTED[p]) for p in parts},
        "named": named, "correct": bool(correct), "mismatch_detected": bool(report["mismatch_detected"]),
        "outside_truth": [n for n in named if n not in truth], "reads_dissipation": reads_dissipation(report),
        "top_effect": top["name"] if top else None, "top_delta_bic": top["delta_bic"] if top else None,
        "significant": [e["name"] for e in significant],
        "delta_bic": {e["name"]: e["delta_bic"] for e in report["effects"]},
        "rms_over_noise_after": report["fit_after"].get("rms_over_noise"),
    }


def run_case(case: SpacecraftCase, folder: Path, stamp_scatter: float = 0.0, gyro_step: float = 0.0) -> dict:
    """Simulate, write the recording, read it back, diagnose it and score the report.
    nominal_error: ||J_vehicle - J_nominal||_F / ||J_nominal||_F, J_vehicle Basilisk's
    rigid-equivalent inertia with slosh and panels at rest. stamp_scatter: the logged time
    stamps are off the sampling instants by uniform draws within +-stamp_scatter x the
    interval (a logger stamping when software reads the gyro; seeded by the case). gyro_step:
    the gyro's rates rounded to a lattice of gyro_step x its noise level (telemetry read
    coarsely; the sidecar keeps its gyro_sigma, as a datasheet gives it); 0: in full.
    """
    t0 = time.perf_counter()
    run = simulate(case)
    t1 = time.perf_counter()
    rec = run.recording
    if stamp_scatter > 0:
        scatter = np.random.default_rng([case.seed, 7]).uniform(-stamp_scatter, stamp_scatter, rec.t.size)
        rec = dataclasses.replace(rec, t=rec.t + scatter * case.sample_dt)
    if gyro_step > 0:
        step = gyro_step * case.gyro_sigma
        rec = dataclasses.replace(rec, w=np.round(rec.w / step) * step)
    path = folder / f"{case.name}.csv"
    write_recording(path, rec, run.sidecar)
    (rec,) = read_recordings(path)
    report = diagnose(rec).report
    row = score(case, report)
    nominal = np.asarray(run.sidecar["inertia_nominal"])
    truth = np.asarray(run.sidecar[TRUTH_KEY]["inertia_equilibrium"])
    row.update(simulate_s=t1 - t0, diagnose_s=time.perf_counter() - t1, samples=int(rec.t.size),
               nominal_error=float(np.linalg.norm(truth - nominal) / np.linalg.norm(nominal)))
    return row
