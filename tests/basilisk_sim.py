"""Recordings made by Basilisk (AVS Lab's spacecraft simulator, PyPI ``bsk``): an independent truth.

The project's own simulator (``synthetic.py``) shares its physics with the diagnosis; Basilisk
does not. Here a spacecraft hub (``spacecraft.Spacecraft``) carries any of
- slosh particles (``linearSpringMassDamper``): a mass on a spring-damper along a fixed direction;
- hinged panels (``hingedRigidBodyStateEffector``): a rigid panel on a torsion spring-damper;
- reaction wheels (``reactionWheelStateEffector``, balanced): their speeds either logged (the
  recording's h columns, h = sum Js Omega g_s, speed relative to the body) or hidden;
- an external torque (``extForceTorque``): commanded bursts (the recording's tau columns) and a
  hidden constant body-frame torque;
and the gyro reading gets a seeded white noise, optionally a bias, a bias random walk (a bias
that drifts) and a per-axis scale error.

The recording looks like a hardware log with a user's sidecar: ``inertia_nominal`` is the hub's
inertia about its own centre of mass, what a user with a hub-only model would write (Basilisk's
convention counts the wheels as part of the hub), so slosh and panel mass make it wrong; its
``body`` says there is no air (the vehicle flies in vacuum, as its user knows). What
was concealed goes under the sidecar key ``basilisk_truth`` (TRUTH_KEY), which the diagnosis
never reads. Basilisk is imported on first use: ``pip install 'inertia-gym[bsk]'``.

Units: SI throughout (kg, m, s, rad, N·m, kg·m²).
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np

from inertia_gym.discrepancy.synthetic import burst_schedule
from inertia_gym.errors import ConfigError
from inertia_gym.recordings import Recording

#: Sidecar key holding what the recording conceals; no part of the diagnosis reads it.
TRUTH_KEY = "basilisk_truth"


def spring_damper(inertia: float, frequency_hz: float, damping_ratio: float) -> tuple[float, float]:
    """Spring and damper of a mass (or rotational inertia) that oscillates at frequency_hz (Hz)
    with damping_ratio: k = m wn^2, c = 2 zeta m wn."""
    wn = 2.0 * np.pi * frequency_hz
    return inertia * wn ** 2, 2.0 * damping_ratio * inertia * wn


@dataclasses.dataclass(frozen=True)
class Slosh:
    """A propellant slosh particle: mass (kg) at position (3,) m from the hub's centre of mass,
    moving along direction (3,) (normalised) on a spring-damper with the natural frequency
    frequency_hz (Hz, on a fixed hub) and damping ratio damping_ratio; rho0 m is its initial
    displacement.
    """

    mass: float
    position: tuple
    direction: tuple
    frequency_hz: float
    damping_ratio: float
    rho0: float = 0.0

    def stiffness_damping(self) -> tuple[float, float]:
        """Spring k (N/m) and damper c (N·s/m) from the frequency and damping ratio."""
        return spring_damper(self.mass, self.frequency_hz, self.damping_ratio)


@dataclasses.dataclass(frozen=True)
class Panel:
    """A hinged rigid panel: mass (kg), principal inertia (3,) kg·m² about its centre of mass
    (panel frame), hinge position (3,) m from the hub's centre of mass, hinge frame dcm_HB (3, 3)
    (rows: hinge axes in body components; the panel turns about the second), arm m from the
    hinge to the panel's centre of mass (along minus the first hinge axis), torsion frequency
    frequency_hz (Hz, on a fixed hub) and damping ratio; theta0 rad the initial deflection.
    """

    mass: float
    inertia: tuple
    hinge: tuple
    dcm_hb: tuple
    arm: float
    frequency_hz: float
    damping_ratio: float
    theta0: float = 0.0

    def stiffness_damping(self) -> tuple[float, float]:
        """Torsion spring k (N·m/rad) and damper c (N·m·s/rad) about the hinge axis."""
        return spring_damper(self.inertia[1] + self.mass * self.arm ** 2, self.frequency_hz,
                             self.damping_ratio)


@dataclasses.dataclass(frozen=True)
class Wheels:
    """Balanced reaction wheels: spin axes (k, 3) body frame, spin inertias js (k,) kg·m²,
    initial speeds speed0 (k,) rad/s relative to the body. logged: their momentum is the
    recording's h columns; otherwise it is concealed. motor_torque N·m: with a value, each
    wheel's motor runs bursts of that size (seeded schedule) so that h changes.
    """

    axes: tuple
    js: tuple
    speed0: tuple
    logged: bool
    motor_torque: float = 0.0


@dataclasses.dataclass(frozen=True)
class SpacecraftCase:
    """One Basilisk run and the recording made of it.

    hub_mass kg; hub_inertia (3, 3) kg·m² about the hub's centre of mass (the sidecar's
    ``inertia_nominal``); omega0 (3,) rad/s and mrp0 (3,) (modified Rodrigues parameters,
    body relative to inertial) the initial state; duration s; sample_dt s between rows;
    integration_dt s (Basilisk's RK4 step; sample_dt must be a multiple); gyro_sigma rad/s;
    quat_sigma (attitude noise; None: no attitude columns); burst_torque N·m commanded bursts
    (0: none; seeded schedule, 2-6 s on and off); hidden_torque (3,) N·m constant, body frame;
    gyro_bias (3,) rad/s and gyro_scale (3,) (reading = (1 + scale) w + bias + noise);
    gyro_bias_walk rad/s/sqrt(s): a bias random walk on each axis (bias instability) added to the
    reading, from its own seeded stream (the cumulative sum of Gaussian steps, zero at the first
    row); slosh,
    panels: tuples of Slosh / Panel; wheels: Wheels or None; seed for noise and schedules.
    """

    name: str
    hub_mass: float
    hub_inertia: tuple
    omega0: tuple
    mrp0: tuple = (0.1, -0.2, 0.3)
    duration: float = 60.0
    sample_dt: float = 0.1
    integration_dt: float = 0.01
    gyro_sigma: float = 2e-4
    quat_sigma: float | None = 1e-3
    burst_torque: float = 0.0
    hidden_torque: tuple = (0.0, 0.0, 0.0)
    gyro_bias: tuple = (0.0, 0.0, 0.0)
    gyro_scale: tuple = (0.0, 0.0, 0.0)
    gyro_bias_walk: float = 0.0
    slosh: tuple = ()
    panels: tuple = ()
    wheels: Wheels | None = None
    seed: int = 0


@dataclasses.dataclass(frozen=True)
class BasiliskRun:
    """A case's recording, its sidecar and Basilisk's noise-free truth at the recording's rows.

    truth_w (n, 3) rad/s and truth_q (n, 4) (body to inertial, scalar first) are the hub's true
    rate and attitude; momentum_inertial (n, 3) kg·m²/s is Basilisk's total rotational angular
    momentum about the system's centre of mass (inertial frame); wheel_momentum (n, 3) kg·m²/s
    the wheels' momentum relative to the body (zeros without wheels); tau (n, 3) N·m the
    commanded torque held from each row on.
    """

    recording: Recording
    sidecar: dict
    truth_w: np.ndarray
    truth_q: np.ndarray
    momentum_inertial: np.ndarray
    wheel_momentum: np.ndarray
    tau: np.ndarray


def _import_basilisk():
    try:
        from Basilisk.architecture import messaging
        from Basilisk.simulation import (
            extForceTorque,
            hingedRigidBodyStateEffector,
            linearSpringMassDamper,
            reactionWheelStateEffector,
            spacecraft,
        )
        from Basilisk.utilities import SimulationBaseClass, macros, simIncludeRW
    except ImportError as exc:
        raise ConfigError(f"Basilisk is not installed ({exc}); install the extra: "
                          "pip install 'inertia-gym[bsk]'") from None
    return dict(messaging=messaging, ext=extForceTorque, hinged=hingedRigidBodyStateEffector,
                slosh=linearSpringMassDamper, rw=reactionWheelStateEffector, sc=spacecraft,
                base=SimulationBaseClass, macros=macros, rw_factory=simIncludeRW)


def _column(v) -> list:
    return [[float(x)] for x in v]


def mrp_to_quat(sigma) -> np.ndarray:
    """(n, 3) MRPs of the body relative to inertial -> (n, 4) body-to-inertial quaternions,
    scalar first and non-negative (the Euler parameters of the same rotation).
    """
    sigma = np.atleast_2d(np.asarray(sigma, float))
    s2 = np.sum(sigma ** 2, axis=1, keepdims=True)
    q = np.hstack([1.0 - s2, 2.0 * sigma]) / (1.0 + s2)
    return q * np.where(q[:, :1] < 0, -1.0, 1.0)


def _steps(case: SpacecraftCase) -> tuple[int, int]:
    """Rows of the recording and integration steps per row; refuses inconsistent timing."""
    for field in ("duration", "sample_dt", "integration_dt"):
        value = getattr(case, field)
        if not (np.isfinite(value) and value > 0):
            raise ConfigError(f"{case.name}: {field} must be a positive number of seconds, got {value}")
    per_row = int(round(case.sample_dt / case.integration_dt))
    if per_row < 1 or abs(per_row * case.integration_dt - case.sample_dt) > 1e-9 * case.sample_dt:
        raise ConfigError(f"{case.name}: sample_dt {case.sample_dt} is not a multiple of integration_dt "
                          f"{case.integration_dt}")
    return int(round(case.duration / case.sample_dt)) + 1, per_row


def _build(bsk, case: SpacecraftCase, at_rest: bool = False):
    """The Basilisk simulation of a case: (sim, spacecraft, commanded-torque effector, wheel
    effector or None, wheel motor message and payload or None, keep-alive list).
    at_rest: slosh and panels start undeflected (for the equilibrium mass properties).
    """
    macros = bsk["macros"]
    sim = bsk["base"].SimBaseClass()
    proc = sim.CreateNewProcess("dynamics")
    proc.addTask(sim.CreateNewTask("step", macros.sec2nano(case.integration_dt)))
    sc = bsk["sc"].Spacecraft()
    sc.ModelTag = "hub"
    sc.hub.mHub = float(case.hub_mass)
    sc.hub.r_BcB_B = _column([0.0, 0.0, 0.0])
    sc.hub.IHubPntBc_B = np.asarray(case.hub_inertia, float).tolist()
    sc.hub.sigma_BNInit = _column(case.mrp0)
    sc.hub.omega_BN_BInit = _column(case.omega0)
    keep = []  # Basilisk holds raw pointers: the Python objects must outlive the run
    for s in case.slosh:
        particle = bsk["slosh"].LinearSpringMassDamper()
        particle.k, particle.c = s.stiffness_damping()
        particle.r_PB_B = _column(s.position)
        direction = np.asarray(s.direction, float)
        particle.pHat_B = _column(direction / np.linalg.norm(direction))
        particle.rhoInit = 0.0 if at_rest else float(s.rho0)
        particle.rhoDotInit = 0.0
        particle.massInit = float(s.mass)
        sc.addStateEffector(particle)
        keep.append(particle)
    for p in case.panels:
        panel = bsk["hinged"].HingedRigidBodyStateEffector()
        panel.mass = float(p.mass)
        panel.IPntS_S = np.diag(np.asarray(p.inertia, float)).tolist()
        panel.d = float(p.arm)
        panel.k, panel.c = p.stiffness_damping()
        panel.r_HB_B = _column(p.hinge)
        panel.dcm_HB = np.asarray(p.dcm_hb, float).tolist()
        panel.thetaInit = 0.0 if at_rest else float(p.theta0)
        panel.thetaDotInit = 0.0
        sc.addStateEffector(panel)
        keep.append(panel)
    wheels = motor = None
    if case.wheels is not None:
        factory = bsk["rw_factory"].rwFactory()
        for i, (axis, js, speed) in enumerate(zip(case.wheels.axes, case.wheels.js, case.wheels.speed0)):
            factory.create("custom", list(map(float, axis)), Js=float(js),
                           Omega=float(speed) / macros.RPM,  # the factory takes rpm
                           RWModel=bsk["rw"].BalancedWheels, useRWfriction=False, useMaxTorque=False,
                           label=f"rw{i}")
        wheels = bsk["rw"].ReactionWheelStateEffector()
        wheels.ModelTag = "wheels"
        factory.addToSpacecraft("wheels", wheels, sc)
        payload = bsk["messaging"].ArrayMotorTorqueMsgPayload()
        payload.motorTorque = [0.0] * len(case.wheels.js)
        message = bsk["messaging"].ArrayMotorTorqueMsg().write(payload)
        wheels.rwMotorCmdInMsg.subscribeTo(message)
        motor = (message, payload)
        keep += [factory, wheels, message, payload]
        sim.AddModelToTask("step", wheels, 2)
    commanded = bsk["ext"].ExtForceTorque()
    commanded.ModelTag = "commanded"
    sc.addDynamicEffector(commanded)
    if any(case.hidden_torque):
        hidden = bsk["ext"].ExtForceTorque()
        hidden.ModelTag = "hidden"
        hidden.extTorquePntB_B = _column(case.hidden_torque)
        sc.addDynamicEffector(hidden)
        keep.append(hidden)
    sim.AddModelToTask("step", sc, 1)
    keep.append(commanded)
    return sim, sc, commanded, wheels, motor, keep


def equilibrium_inertia(case: SpacecraftCase) -> tuple[np.ndarray, float]:
    """The rigid-equivalent inertia (3, 3) kg·m² of the whole vehicle about its centre of mass
    with slosh and panels at rest, and its mass (kg), both as Basilisk computes them.
    Balanced wheels add nothing (Basilisk's hub inertia already counts them).
    """
    bsk = _import_basilisk()
    sim, sc, *_ = _build(bsk, case, at_rest=True)
    log = sc.scMassOutMsg.recorder()
    sim.AddModelToTask("step", log)
    sim.InitializeSimulation()
    sim.ConfigureStopTime(0)
    sim.ExecuteSimulation()
    mass = float(log.massSC[0])
    c = np.asarray(log.c_B[0], float)
    inertia_b = np.asarray(log.ISC_PntB_B[0], float).reshape(3, 3)
    return inertia_b - mass * (c @ c * np.eye(3) - np.outer(c, c)), mass


def _schedules(case: SpacecraftCase, n: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """Commanded body torque (n, 3) N·m and wheel motor torques (n, k) N·m, held per row."""
    tau = burst_schedule(n, case.sample_dt, case.burst_torque, rng) if case.burst_torque > 0 \
        else np.zeros((n, 3))
    k = 0 if case.wheels is None else len(case.wheels.js)
    motor = np.zeros((n, k))
    if k and case.wheels.motor_torque > 0:
        # one burst schedule per wheel: its first component's sign gives the burst direction
        for i in range(k):
            bursts = burst_schedule(n, case.sample_dt, 1.0, rng)[:, 0]
            motor[:, i] = np.sign(bursts) * case.wheels.motor_torque
    return tau, motor


def simulate(case: SpacecraftCase) -> BasiliskRun:
    """Run a case in Basilisk and make the recording a user would log (see the module doc)."""
    bsk = _import_basilisk()
    macros = bsk["macros"]
    n, _ = _steps(case)
    rng = np.random.default_rng(case.seed)
    tau, motor_torque = _schedules(case, n, rng)
    sim, sc, commanded, wheels, motor, keep = _build(bsk, case)
    period = macros.sec2nano(case.sample_dt)
    state_log = sc.scStateOutMsg.recorder(period)
    momentum_log = sc.logger(["totRotAngMomPntC_N"], period)
    logs = [state_log, momentum_log]
    speed_log = None
    if wheels is not None:
        speed_log = wheels.rwSpeedOutMsg.recorder(period)
        logs.append(speed_log)
    for log in logs:
        sim.AddModelToTask("step", log)
    sim.InitializeSimulation()
    change = np.flatnonzero(np.any(np.diff(np.hstack([tau, motor_torque]), axis=0) != 0, axis=1)) + 1
    starts = np.concatenate([[0], change])
    stops = np.concatenate([change, [n - 1]])
    for a, b in zip(starts, stops):  # row a's torques act from row a to row b
        commanded.extTorquePntB_B = _column(tau[a])
        if motor is not None:
            motor[1].motorTorque = motor_torque[a].tolist()
            motor[0].write(motor[1], macros.sec2nano(a * case.sample_dt))
        sim.ConfigureStopTime(macros.sec2nano(b * case.sample_dt))
        sim.ExecuteSimulation()
    t = np.asarray(state_log.times(), float) * 1e-9
    if t.size != n:
        raise RuntimeError(f"{case.name}: Basilisk logged {t.size} rows, expected {n}")
    w_true = np.asarray(state_log.omega_BN_B, float)
    q_true = mrp_to_quat(state_log.sigma_BN)
    h_rel = np.zeros((n, 3))
    if speed_log is not None:
        speeds = np.asarray(speed_log.wheelSpeeds, float)[:, :len(case.wheels.js)]
        axes = np.asarray(case.wheels.axes, float)
        axes = axes / np.linalg.norm(axes, axis=1, keepdims=True)
        h_rel = (speeds * np.asarray(case.wheels.js, float)) @ axes
    gyro = w_true * (1.0 + np.asarray(case.gyro_scale)) + np.asarray(case.gyro_bias) \
        + rng.normal(0.0, case.gyro_sigma, (n, 3))
    if case.gyro_bias_walk:
        steps = np.random.default_rng([case.seed, 1]).normal(
            0.0, case.gyro_bias_walk * np.sqrt(case.sample_dt), (n, 3))
        steps[0] = 0.0
        gyro = gyro + np.cumsum(steps, axis=0)
    q_meas = None
    if case.quat_sigma is not None:
        q_meas = q_true + rng.normal(0.0, case.quat_sigma, (n, 4))
        q_meas /= np.linalg.norm(q_meas, axis=1, keepdims=True)
        q_meas *= np.where(q_meas[:, :1] < 0, -1.0, 1.0)
    sidecar = {"inertia_nominal": np.asarray(case.hub_inertia, float).tolist(),
               "gyro_sigma": case.gyro_sigma, "body": {"air": False},
               "simulator": "Basilisk (bsk) " + _version(), "case": case.name}
    if case.quat_sigma is not None:
        sidecar["quat_sigma"] = case.quat_sigma
    sidecar[TRUTH_KEY] = _truth(case, h_rel[0], w_true[0])
    logged = case.wheels is not None and case.wheels.logged
    rec = Recording(t, gyro, q_meas, tau if case.burst_torque > 0 else None, sidecar, case.name,
                    h=h_rel if logged else None)
    return BasiliskRun(rec, sidecar, w_true, q_true, np.asarray(momentum_log.totRotAngMomPntC_N, float),
                       h_rel, tau)


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("bsk")
    except PackageNotFoundError:
        return "unknown"


def _truth(case: SpacecraftCase, h0: np.ndarray, w0: np.ndarray) -> dict:
    """What the recording conceals, JSON-ready (the sidecar's TRUTH_KEY); h0 (3,) kg·m²/s the
    wheels' momentum relative to the body and w0 (3,) rad/s the rate, both at the first row.

    Free balanced wheels keep their absolute spin momentum Js (Omega + g.w) g: concealed, they
    are the catalogue's internal_momentum with that constant h and the inertia J_hub - Js g g^T.
    """
    inertia, mass = equilibrium_inertia(case)
    truth = {"inertia_equilibrium": inertia.tolist(), "mass": mass, "hub_mass": case.hub_mass,
             "slosh": [dataclasses.asdict(s) for s in case.slosh],
             "panels": [dataclasses.asdict(p) for p in case.panels],
             "hidden_torque": list(case.hidden_torque), "gyro_bias": list(case.gyro_bias),
             "gyro_scale": list(case.gyro_scale), "gyro_bias_walk": case.gyro_bias_walk, "seed": case.seed}
    if case.wheels is not None:
        truth["wheels"] = dataclasses.asdict(case.wheels)
        axes = np.asarray(case.wheels.axes, float)
        axes = axes / np.linalg.norm(axes, axis=1, keepdims=True)
        truth["wheel_momentum_relative_initial"] = h0.tolist()
        spin = np.asarray(case.wheels.js) * (axes @ w0)  # Js g.w per wheel
        truth["wheel_momentum_absolute_initial"] = (h0 + spin @ axes).tolist()
    return json.loads(json.dumps(truth, default=lambda v: np.asarray(v).tolist()))
