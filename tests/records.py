"""Record families the tests specify behaviour on, each made with scipy or the project's own
simulator: thin, nearly flat bodies tumbling freely or pushed by logged torques, near-flat tosses
and a small satellite with torque pulses (scipy's DOP853, no inertia_gym code in the truth), with
the scores identify is held to on them; a slow, long tumble with effects concealed in it, and
that tumble read by a coarse gyro. scripts/identify_tables.py families runs the families at length.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
from scipy import stats
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

from inertia_gym.discrepancy.effects import REGISTRY
from inertia_gym.discrepancy.fit import MODE_REACH, Data, Fit, Layout, Probe, fit_model
from inertia_gym.discrepancy.synthetic import simulate_recording
from inertia_gym.recordings import Recording, read_csv_recording
from inertia_gym.scenario import Scenario

SIGMA = 2e-3  # rad/s


def write_record(path: Path, inertia, w0, duration: float, rng, mirrored: bool) -> None:
    """A torque-free tumble of `inertia` (3, 3) from w0 (3,) rad/s, 100 Hz, with gyro noise."""
    t = np.arange(0, duration, 0.01)
    sol = solve_ivp(lambda _, w: np.linalg.solve(inertia, -np.cross(w, inertia @ w)), (0, t[-1]), w0,
                    t_eval=t, rtol=1e-11, atol=1e-12, method="DOP853")
    w = sol.y.T + SIGMA * rng.standard_normal((t.size, 3))
    if mirrored:
        w = w[:, [1, 0, 2]]
    np.savetxt(path, np.column_stack([t, w]), delimiter=",", header="t,wx,wy,wz", comments="", fmt="%.9g")
    path.with_suffix(".json").write_text(json.dumps({"gyro_sigma": SIGMA}))


def cases():
    """(name, rng seed, moments (3,), duration s, rate rad/s, near the middle axis)."""
    for k, s in enumerate([0.01, 0.02, 0.03, 0.05]):
        for e in (0.0, 0.005):
            for seed in range(4):
                yield (f"s{s}_e{e}_d1.2_seed{seed}", 1000 * k + 10 * seed + int(e * 1000),
                       np.array([1.0, 1 - s + e, s]) * 5e-3, 1.2, 15.0, seed % 2 == 0)
    for k, (s, e, duration, rate) in enumerate([(0.01, 0.0, 6, 15), (0.02, 0.005, 6, 15), (0.01, 0.0, 20, 3),
                                                (0.03, 0.005, 20, 3)]):
        for seed in range(3):
            yield (f"s{s}_e{e}_d{duration}_seed{seed}", 5000 + 100 * k + seed,
                   np.array([1.0, 1 - s + e, s]) * 40.0, duration, rate, seed % 2 == 0)


def _turned(moments, rng) -> tuple[np.ndarray, np.ndarray]:
    """(inertia (3, 3) kg·m² of principal moments `moments` (3,) along axes turned at random, the
    turn (3, 3)), the turn drawn from rng."""
    turn = Rotation.random(random_state=rng).as_matrix()
    return turn @ np.diag(moments) @ turn.T, turn


def thin_body_record(path: Path, seed: int, moments, duration: float, rate: float, middle: bool,
                     mirrored: bool = False):
    """One case written to path (a CSV and its sidecar): principal moments `moments` (3,) kg·m²
    turned at random (rng seeded with `seed`), `rate` rad/s near the middle axis (middle) or about
    a random direction. Returns the true inertia (3, 3) kg·m².
    """
    rng = np.random.default_rng(seed)
    inertia, turn = _turned(moments, rng)
    near = np.array([0.15, 1.0, 0.1])
    u = turn @ (near + 0.2 * rng.standard_normal(3)) if middle else rng.standard_normal(3)
    write_record(path, inertia, rate * u / np.linalg.norm(u), duration, rng, mirrored)
    return inertia


def forced_record(path: Path, seed: int, moments, duration: float = 8.0) -> np.ndarray:
    """A thin body (principal moments `moments` (3,) kg·m², axes turned at random) pushed by
    logged torque bursts (0.5 s on every 2 s from 0.5 s, each about trace/3 x 2 rad/s² along a
    random direction, held per row), 3 rad/s about a random direction, 100 Hz, gyro noise SIGMA,
    no attitude; each row's interval integrated by DOP853. Returns the true inertia (3, 3)."""
    rng = np.random.default_rng(seed)
    inertia, _ = _turned(moments, rng)
    t = np.arange(0, duration, 0.01)
    tau = np.zeros((t.size, 3))
    for start in np.arange(0.5, duration, 2.0):
        tau[(t >= start) & (t < start + 0.5)] = np.trace(inertia) / 3 * 2.0 * rng.standard_normal(3)
    u = rng.standard_normal(3)
    w = [3.0 * u / np.linalg.norm(u)]
    for i in range(t.size - 1):
        sol = solve_ivp(lambda _, x, i=i: np.linalg.solve(inertia, tau[i] - np.cross(x, inertia @ x)),
                        (t[i], t[i + 1]), w[-1], rtol=1e-11, atol=1e-13, method="DOP853")
        w.append(sol.y[:, -1])
    w = np.array(w) + SIGMA * rng.standard_normal((t.size, 3))
    np.savetxt(path, np.column_stack([t, w, tau]), delimiter=",", header="t,wx,wy,wz,tau_x,tau_y,tau_z",
               comments="", fmt="%.10g")
    path.with_suffix(".json").write_text(json.dumps({"gyro_sigma": SIGMA}))
    return inertia


def thin_body(folder: Path, name: str):
    """(recording, true inertia (3, 3) kg·m²) of the case `name` of cases(), written in folder."""
    _, seed, moments, duration, rate, middle = next(c for c in cases() if c[0] == name)
    inertia = thin_body_record(folder / f"{name}.csv", seed, moments, duration, rate, middle)
    return read_csv_recording(folder / f"{name}.csv"), inertia


def slow_tumble(effects, seed: int, omega_seed: int, duration: float = 300.0,
                noise: float = 5e-4) -> tuple[Recording, dict]:
    """`duration` s at 10 Hz of a small body tumbling at ~0.3 rad/s (initial rates drawn with
    omega_seed), no torque, gyro noise `noise` rad/s, with the effects (None, a name or a list,
    drawn with seed), the true inertia as the sidecar's nominal and no gyro_sigma in it; and the
    effects' true parameters by name."""
    rng = np.random.default_rng(omega_seed)
    inertia = ((0.1, 0.002, -0.001), (0.002, 0.12, 0.003), (-0.001, 0.003, 0.05))
    sc = Scenario(inertia_true=inertia, inertia_guess=inertia, omega0=tuple(rng.normal(0, 0.15, 3)),
                  gyro_sigma=noise, dt=0.1, tau_max=2e-4)
    rec, side = simulate_recording(sc, duration, effects, seed=seed, torque=False, sample_dt=0.1)
    meta = {k: v for k, v in rec.meta.items() if k not in ("effect", "effects", "gyro_sigma")}
    truth = {e["name"]: e["params"] for e in side.get("effects") or [side["effect"]] if e}  # None: no effect
    return dataclasses.replace(rec, meta=meta), truth


def fitted_truth(truth: dict, d: Data, nominal: Fit) -> Fit:
    """The model of the true effects (name -> true parameters, simplest forms, in that order)
    fitted on d with the inertia and the segments' rates, started at the true parameters (and
    each segment's rates the nominal fit's or its first gyro sample's, whichever fit it better);
    each effect added to the fit of those before it, as the diagnosis adds them."""
    fit = nominal
    names = list(truth)
    for i in range(1, len(names) + 1):
        part, forms = names[:i], ("",) * i
        mode = truth.get("flexible_mode") if "flexible_mode" in part else None
        reach = MODE_REACH * float(mode["omega_n"]) if mode else fit.layout.omega_max
        layout = Layout.of(part, forms, d, reach)
        x0 = np.concatenate([nominal.x[:6], *(REGISTRY[n].pack(truth[n]) for n in part), nominal.x[6:]])
        x0 = Probe(layout, d, fit).with_segment_rates([x0])[0]
        fit = fit_model(part, forms, d, fit, start=x0, omega_max=reach)
    return fit


def true_gains(truth: dict, d: Data, nominal: Fit) -> dict:
    """Per true effect, the BIC the truth's fitted model gains over the same model without it
    (fitted_truth both): what the record shows of that effect beside the others."""
    whole = fitted_truth(truth, d, nominal)
    return {name: fitted_truth({n: p for n, p in truth.items() if n != name}, d, nominal).bic - whole.bic
            for name in truth}


def slow_tumble_read_coarsely(seed: int, effect: str | None, duration: float = 600.0, noise: float = 5e-4,
                              step: float = 0.01):
    """slow_tumble's body (rates drawn with seed 100 + seed) sampled at 10 Hz
    for `duration` s, its gyro (noise 5e-4 rad/s: runs of 5-18 equal samples) read in steps of
    0.01 rad/s (0: in full) and no gyro_sigma given: the rounding error a function of the rate."""
    rec, _ = slow_tumble(effect, seed, 100 + seed, duration=duration, noise=noise)
    return dataclasses.replace(rec, w=np.round(rec.w / step) * step if step else rec.w)


#: The small satellite of satellite_record (kg·m²).
SATELLITE = np.array([[0.060, 0.002, -0.001], [0.002, 0.075, 0.003], [-0.001, 0.003, 0.040]])


def _euler(inertia, torque=None):
    inv = np.linalg.inv(inertia)

    def rate(t, w):
        tau = np.zeros(3) if torque is None else torque(t)
        return inv @ (tau - np.cross(w, inertia @ w))

    return rate


#: A toss's sample times (s): 1 s at 100 Hz.
TOSS_TIMES = np.arange(101) * 0.01


def flat_moments(shape, delta: float) -> np.ndarray:
    """A near-flat body's moments (3,) kg·m²: I3 = (1 - delta)(I1 + I2), (I1, I2) = shape, at the
    scale of a phone."""
    i1, i2 = shape
    return np.array([i1, i2, (1 - delta) * (i1 + i2)]) * 3e-4


def _toss_truth(moments, rate: float, rng) -> tuple[np.ndarray, np.ndarray]:
    """A toss's body of principal moments (3,), its axes turned at random, and its spin of `rate`
    rad/s about a random direction, drawn from rng: (inertia (3, 3) kg·m², w0 (3,) rad/s)."""
    turn = Rotation.random(random_state=rng).as_matrix()
    inertia = turn @ np.diag(np.asarray(moments, float)) @ turn.T
    direction = rng.normal(size=3)
    return inertia, rate * direction / np.linalg.norm(direction)


def _toss_rates(inertia, w0) -> np.ndarray:
    """The torque-free rates (101, 3) at TOSS_TIMES."""
    sol = solve_ivp(_euler(inertia), (0, TOSS_TIMES[-1]), w0, t_eval=TOSS_TIMES, rtol=1e-11, atol=1e-12,
                    method="DOP853")
    return sol.y.T


def toss_record(moments, rate: float, sigma: float, seed: int,
                name: str = "toss") -> tuple[Recording, np.ndarray]:
    """A 1-s, 100-Hz torque-free toss of a body of principal moments (3,) kg·m² spun at `rate`
    rad/s, gyro noise sigma rad/s: (record, true inertia (3, 3))."""
    rng = np.random.default_rng(seed)
    inertia, w0 = _toss_truth(moments, rate, rng)
    w = _toss_rates(inertia, w0) + sigma * rng.normal(size=(TOSS_TIMES.size, 3))
    return Recording(TOSS_TIMES, w, meta={"gyro_sigma": sigma}, name=f"{name}-{seed}"), inertia


def flat_record(shape, delta: float, rate: float, sigma: float,
                seed: int) -> tuple[Recording, np.ndarray]:
    """A 1-s, 100-Hz torque-free toss of a near-flat body (flat_moments): (record, true inertia)."""
    return toss_record(flat_moments(shape, delta), rate, sigma, seed, "flat")


def _matrix(theta) -> np.ndarray:
    """The inertia (3, 3) of theta (6,) = (Jxx, Jxy, Jxz, Jyy, Jyz, Jzz)."""
    return np.array([[theta[0], theta[1], theta[2]], [theta[1], theta[3], theta[4]],
                     [theta[2], theta[4], theta[5]]])


def _principal_ratios(theta) -> np.ndarray:
    """(I2/I1, I3/I1) of theta (6,), I1 the largest moment."""
    moments = np.sort(np.linalg.eigvalsh(_matrix(theta)))[::-1]
    return moments[1:] / moments[0]


def toss_ratio_bound(moments, rate: float, sigma: float, seed: int) -> np.ndarray:
    """The Cramér-Rao bound (2, 2) on the principal ratios (I2/I1, I3/I1) of toss_record's toss,
    at its truth: sigma^2 (G^T G)^-1 over the inertia's five directions at a fixed trace (a
    torque-free record has no scale) and the initial rate, G the rates' derivatives by central
    differences of scipy's DOP853 solutions, carried to the ratios by their gradient. No
    unbiased estimator's covariance lies below it.
    """
    inertia, w0 = _toss_truth(moments, rate, np.random.default_rng(seed))
    theta = inertia[np.triu_indices(3)]
    basis = np.linalg.svd(np.array([[1.0, 0.0, 0.0, 1.0, 0.0, 1.0]]))[2][1:].T  # (6, 5): trace kept
    steps = np.r_[np.full(5, 1e-4 * np.abs(theta).max()), np.full(3, 1e-4 * np.linalg.norm(w0))]

    def rates(p):
        return _toss_rates(_matrix(theta + basis @ p[:5]), w0 + p[5:]).ravel()

    unit = np.eye(8) * steps
    g = np.column_stack([(rates(e) - rates(-e)) / (2 * s) for e, s in zip(unit, steps)])
    cov = sigma ** 2 * np.linalg.inv(g.T @ g)[:5, :5]
    grad = np.column_stack([(_principal_ratios(theta + basis[:, k] * steps[k])
                             - _principal_ratios(theta - basis[:, k] * steps[k])) / (2 * steps[k])
                            for k in range(5)])  # (2, 5)
    return grad @ cov @ grad.T


def flat_ratio_bound(shape, delta: float, rate: float, sigma: float, seed: int) -> np.ndarray:
    """toss_ratio_bound of flat_record's toss."""
    return toss_ratio_bound(flat_moments(shape, delta), rate, sigma, seed)


def efficient_pass_probability(cov) -> float:
    """The probability that a Gaussian, unbiased error of covariance cov (2, 2) passes
    score_ratios' rule (each ratio within 3 of its standard deviations and within 0.5 %): what an
    efficient estimator reaches on a record whose bound is cov.
    """
    cov = np.asarray(cov, float)
    half = np.minimum(3 * np.sqrt(np.diag(cov)), 0.005)
    law = stats.multivariate_normal(np.zeros(2), cov, seed=0)
    return float(law.cdf(half, lower_limit=-half))


def satellite_record(seed: int) -> tuple[Recording, np.ndarray]:
    """60 s at 10 Hz of a small satellite with five 2-s torque pulses, logged: (record, inertia)."""
    rng = np.random.default_rng(seed)
    t = np.arange(601) * 0.1
    starts = np.array([5.0, 16.0, 27.0, 38.0, 49.0])
    amplitudes = rng.uniform(-1e-3, 1e-3, size=(5, 3))

    def torque(time_s):
        k = np.flatnonzero((time_s >= starts) & (time_s < starts + 2.0))
        return amplitudes[k[0]] if k.size else np.zeros(3)

    w0 = rng.normal(0.0, 0.05, 3)
    sol = solve_ivp(_euler(SATELLITE, torque), (0, t[-1]), w0, t_eval=t, rtol=1e-11, atol=1e-13,
                    method="DOP853", max_step=0.05)
    tau = np.array([torque(x) for x in t])
    w = sol.y.T + 1e-4 * rng.normal(size=(t.size, 3))
    return Recording(t, w, tau=tau, meta={"gyro_sigma": 1e-4}, name=f"satellite-{seed}"), SATELLITE


def score_ratios(result, inertia) -> tuple[bool, np.ndarray]:
    """(within 3 sigma and 0.5 % on both ratios, covered (2,) by the reported 95 % intervals)."""
    summary = result.summary()
    ratios = np.array(summary["principal_ratios"])[1:]
    sd = np.sqrt(np.diag(np.array(summary["principal_ratios_cov"])))[1:]
    ci = np.array(summary["principal_ratios_ci95"])[1:]
    truth = np.sort(np.linalg.eigvalsh(inertia))[::-1]
    truth = (truth / truth[0])[1:]
    err = np.abs(ratios - truth)
    return bool(np.all(err <= 3 * sd) and np.all(err <= 0.005)), (ci[:, 0] <= truth) & (truth <= ci[:, 1])


def score_entries(result, inertia) -> tuple[bool, np.ndarray]:
    """(within 3 sigma and 0.5 % of the largest moment on all six entries, covered (6,))."""
    est = result.estimate
    truth = inertia[np.triu_indices(3)]
    err = np.abs(est.theta - truth)
    scale = np.linalg.eigvalsh(inertia).max()
    return bool(np.all(err <= 3 * est.sigma) and np.all(err <= 0.005 * scale)), err <= 1.96 * est.sigma
