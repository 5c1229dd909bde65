"""flexible_mode: one lightly damped mode (a panel, a propellant) coupled to the body."""

from __future__ import annotations

import numpy as np
from typing_extensions import override

from inertia_gym.discrepancy.effects.base import EffectModel, _unit, register

#: Modal frequencies (Hz) screened for flexible_mode: lowest (lower on a long record of a slow
#: body: flex_floor_hz), and highest as a share of Nyquist.
FLEX_BAND = (0.05, 0.25)
#: Cycles a mode must complete within the record for flex_floor_hz to screen it.
MODE_MIN_CYCLES = 2.0


def flex_floor_hz(d) -> float:
    """The lowest modal frequency (Hz) screened for flexible_mode on the data d: two cycles in
    the record's length, and no lower than FLEX_BAND[0] or the body's own rotation rate,
    whichever is lower (a slower mode follows the rotation quasi-statically, as an inertia
    would). A 1e4 kg·m² stage tumbling at 0.02 rad/s for 20 min with its propellant sloshing at
    0.02 Hz has the slosh out of reach of a fixed 0.05 Hz floor (which leaves 6x the noise). On a
    record shorter than MODE_MIN_CYCLES / FLEX_BAND[0] (40 s) the floor is two cycles in the
    record: on a 1-s toss a 0.05 Hz floor would screen a "mode" that is a drift of a twentieth
    of a cycle (the fit's bounds keep half the floor: at least one cycle).
    """
    return max(MODE_MIN_CYCLES / max(d.duration, 1e-9), min(FLEX_BAND[0], d.omega_ref / (2 * np.pi)))


#: Damping ratios the modal frequency is screened at: light (a panel's or a free liquid's: a
#: ringing) and heavy (a liquid in a baffled tank, a mass on a damper: overdamped, a lag whose two
#: poles lie 34x apart); each draws a response of its own shape, which a start at the other ratio
#: does not reach. A fit moves a start's ratio anywhere within its bounds, critical damping included.
MODE_ZETAS = (0.03, 3.0)


def pole_spread(zeta: float) -> float:
    """The factor r = zeta + sqrt(zeta^2 - 1) by which an overdamped mode's poles lie either side
    of omega_n (omega_n r and omega_n / r); 1 up to critical damping, where both sit at omega_n.
    """
    return float(zeta + np.sqrt(zeta ** 2 - 1.0)) if zeta > 1.0 else 1.0


def mode_band(d) -> tuple[float, float]:
    """The modal frequencies a fit may take (rad/s): half the screened floor (at least one cycle in
    the record) up to FLEX_BAND[1] of the sampling rate.
    """
    return 2 * np.pi * 0.5 * flex_floor_hz(d), 2 * np.pi * FLEX_BAND[1] / d.dt


def zeta_max(d) -> float:
    """The largest damping ratio a fit may take: an overdamped mode's poles lie about 4 zeta^2
    apart, so beyond 0.5 sqrt(band) they cannot both lie in the band of mode_band; one is then
    unseen and only omega_n / (2 zeta), the other, is fitted, along a ridge of (omega_n, zeta)
    that the bound cuts off. At least 1: a critically damped mode is always allowed.
    """
    lo, hi = mode_band(d)
    return max(1.0, 0.5 * np.sqrt(hi / lo))


#: The largest modal mass fraction delta^T J^-1 delta a fitted flexible_mode may take (1 makes
#: the body and mode's joint mass matrix singular; drawn modes take up to about 0.1).
MODE_MASS_LIMIT = 0.9
#: Length of the loaded form's p: the mode's seven and its inertia rate K (6).
LOADED_SIZE = 13


@register
class FlexibleMode(EffectModel):
    """One lightly damped mode (omega_n rad/s, zeta, coupling d (3,) sqrt(kg)·m) coupled to w_dot,
    with its state where the recording starts (eta0 sqrt(kg)·m, eta_dot0 sqrt(kg)·m/s): a
    panel or a propellant already swinging when the log begins, as on any real record. The mode
    moves mass, so the body's inertia is J + K eta and the rotation loads the mode by
    w^T K w / 2 (inertia_rate K = dJ/d eta, (xx, xy, xz, yy, yz, zz) sqrt(kg)·m;
    dynamics.Disturbance): a propellant mass on a spring at r along p has d = sqrt(m) r x p and
    K = sqrt(m) (2 (r . p) I - r p^T - p r^T), whose Frobenius norm is at least sqrt(2) |d|, and the
    rotation holds it out by about |w|^2 |r| / omega_n^2: a centimetre for a mass 0.4 m out on a
    0.3-Hz spring in a body turning at 0.3 rad/s.
    """

    name, params, size, family = ("flexible_mode", ("omega_n", "zeta", "coupling", "eta0", "eta_dot0",
                                                    "inertia_rate"), 7, "internal motion")
    units = {"omega_n": "rad/s", "zeta": "", "coupling": "√kg·m", "eta0": "√kg·m", "eta_dot0": "√kg·m/s",
             "inertia_rate": "√kg·m"}
    hardware, hardware_words = ("appendages", "propellant"), "flexible appendage or liquid"
    as_fitted = {"": "an oscillating unmodelled torque, fitted as a damped mode"}  # either form
    restarts_on_base = ("", "loaded")
    # d eta_dot enters the body's equation as a momentum along d does: an undamped mode of about
    # one cycle in the record beside a constant momentum along d is exactly a momentum that rises
    # and falls along d (a simulated rotor's spin-up and brake, 0.5 (1 - cos 2 pi t / T), reads
    # so, its ten parameters against the varying momentum's twenty-four)
    ambiguities = (("internal_momentum", (
        "the mode's own motion acts on the rates as a momentum along its coupling that rises and "
        "falls as it swings: a slow mode (about one cycle in the record) beside a momentum along "
        "the same axis draws a rotor spinning up and down; where the body has a rotor along that "
        "axis, read the two together as its momentum")),)
    optional = {"eta0": 0.0, "eta_dot0": 0.0, "inertia_rate": np.zeros(6)}

    @override
    def draw(self, rng, body):  # the mode at rest at the start: the bursts excite it
        return {"omega_n": 2 * np.pi * rng.uniform(0.5, 2.0), "zeta": rng.uniform(0.01, 0.05),
                "coupling": _unit(rng) * np.sqrt(rng.uniform(0.02, 0.06) * body.j),
                "eta0": 0.0, "eta_dot0": 0.0}

    @override
    def forms(self, d):  # "": the mode alone; "loaded": also moving the body's mass (K)
        return ("", "loaded")

    @override
    def form_size(self, form, d):
        return LOADED_SIZE if form == "loaded" else self.size

    @override
    def nested(self, form, d, p):  # K = 0 is the mode of the first form
        return np.r_[p, np.zeros(LOADED_SIZE - self.size)] if form == "loaded" else None

    @override
    def unpack(self, p):  # the model depends on delta delta^T, delta eta and K eta: report delta's sign
        sign = 1.0 if p[2 + int(np.argmax(np.abs(p[2:5])))] >= 0 else -1.0  # canonically
        out = {"omega_n": abs(p[0]), "zeta": abs(p[1]), "coupling": np.array(p[2:5] * sign),
               "eta0": float(p[5] * sign), "eta_dot0": float(p[6] * sign)}
        if p.size == LOADED_SIZE:
            out["inertia_rate"] = np.array(p[7:] * sign)
        return out

    @override
    def pack(self, params):  # the loaded form's vector where params give an inertia rate
        full = {**self.optional, **params}
        p = np.r_[float(full["omega_n"]), float(full["zeta"]), np.asarray(full["coupling"], float),
                  float(full["eta0"]), float(full["eta_dot0"])]
        return np.r_[p, np.asarray(params["inertia_rate"], float)] if "inertia_rate" in params else p

    @override
    def bounds(self, form, d):  # a mode inside the sampled band, damping in [0, zeta_max]
        lb, ub = np.full(self.form_size(form, d), -np.inf), np.full(self.form_size(form, d), np.inf)
        (lb[0], ub[0]), lb[1], ub[1] = mode_band(d), 0.0, zeta_max(d)
        return lb, ub

    @override
    def typical(self, form, d):
        lb, ub = self.bounds(form, d)
        eta = 0.01 * np.sqrt(d.j_ref)
        # the frequency's typical size is the band's floor, which no fitted frequency is below:
        # its finite-difference step is then always relative to the frequency itself
        return np.r_[lb[0], 0.01, np.full(3, 0.1 * np.sqrt(d.j_ref)), eta, eta * np.sqrt(lb[0] * ub[0]),
                     np.full(lb.size - self.size, 0.1 * np.sqrt(d.j_ref))]

    @override
    def starts(self, form, d, probe):
        return probe.mode_starts(zetas=tuple(min(z, zeta_max(d)) for z in MODE_ZETAS))

    @override
    def feasible(self, p, inertia):
        # the body and mode's joint mass matrix [[J, delta], [delta^T, 1]] is positive definite
        # only while delta^T J^-1 delta < 1 (the modal mass fraction): the coupling is scaled
        # back to MODE_MASS_LIMIT, beyond which the model is singular or indefinite; the modal
        # state scaled up alike keeps delta eta (what the rates see of it), and K scaled down
        # alike keeps K eta
        c = p[2:5]
        fraction = float(c @ np.linalg.solve(inertia, c))
        if not fraction > MODE_MASS_LIMIT:
            return p
        shrink = np.sqrt(MODE_MASS_LIMIT / fraction)
        return np.r_[p[:2], c * shrink, p[5:7] / shrink, p[7:] * shrink]

    @override
    def disturbance(self, params):
        params = {**self.optional, **params}
        return {"flex_omega": float(params["omega_n"]), "flex_zeta": float(params["zeta"]),
                "flex_coupling": np.asarray(params["coupling"], float),
                "flex_eta0": float(params["eta0"]), "flex_eta_dot0": float(params["eta_dot0"]),
                "flex_inertia_rate": np.asarray(params["inertia_rate"], float)}
