"""The base of the effect catalogue: EffectModel (every hook an effect may set, each defaulting
to "no such term"), Body (what a random draw is sized to), the registry and its decorator, the
helpers the effects share, and the catalogue's entry points (effect_model, Effect, random_params).
Each effect is one subclass of EffectModel in a module of its own, named for the effect.

Fit-side hooks receive ``d``, a fit.Data (the recording prepared for fitting).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import ClassVar

import numpy as np
from scipy import interpolate

from inertia_gym.dynamics import skew
from inertia_gym.errors import ConfigError

#: A function t (k,) s -> (k, 3): the running integral of a torque (N·m·s) from the recording's
#: start; the applied torque over an interval is its increment over the interval's length.
Cumulative = Callable[[np.ndarray], np.ndarray]


def rotvec_matrix(rotvec) -> np.ndarray:
    """Rotation matrix (3, 3) of a rotation vector (rad), Rodrigues' formula."""
    rv = np.asarray(rotvec, float)
    angle = np.linalg.norm(rv)
    k = skew(rv / angle) if angle > 0 else np.zeros((3, 3))
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def _unit(rng) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def _signed(rng, lo, hi, size=None):
    return rng.uniform(lo, hi, size) * rng.choice([-1.0, 1.0], size)


def jsonable(params: dict) -> dict:
    """Parameters with numpy values turned into floats / lists."""
    return {k: (np.asarray(v).tolist() if np.ndim(v) else float(v)) for k, v in params.items()}


def inertia6(j) -> np.ndarray:
    """(xx, xy, xz, yy, yz, zz) of a symmetric 3x3 matrix."""
    j = np.asarray(j, float)
    return np.array([j[0, 0], j[0, 1], j[0, 2], j[1, 1], j[1, 2], j[2, 2]])


def matrix6(v) -> np.ndarray:
    """The symmetric 3x3 matrix of (xx, xy, xz, yy, yz, zz)."""
    v = np.asarray(v, float)
    return np.array([[v[0], v[1], v[2]], [v[1], v[3], v[4]], [v[2], v[4], v[5]]])


@dataclasses.dataclass(frozen=True)
class Body:
    """What a random draw is sized to: inertia (3, 3) kg·m², omega_ref rad/s (typical rate),
    tau_ref N·m (actuator level), gyro_sigma rad/s, duration s of the recording.
    """

    inertia: np.ndarray
    omega_ref: float
    tau_ref: float
    gyro_sigma: float
    duration: float

    @property
    def j(self) -> float:
        """Mean principal moment trace(J) / 3, kg·m²."""
        return float(np.trace(self.inertia)) / 3.0


class EffectModel:
    """Base class of a catalogue effect; every hook defaults to "this effect has no such term".

    Class attributes: ``name`` (fixed by the contract), ``params`` (named parameters), ``size``
    (length of the fitted vector p of the default form), ``needs_torque``, ``needs_attitude``,
    ``needs_momentum`` (what the recording must hold), ``ambiguities`` ((other effect or
    "inertia", reason) pairs that the data may not separate), ``sets_inertia`` (the effect's
    parameters are the inertia itself: the base inertia is then not fitted), ``family`` (the
    physical cause, shared by effects that model it at different fidelity, e.g. linear and
    quadratic drag), ``restarts_on_base`` (the forms in which the forward selection also tries
    the effect's own starts found on top of the fit it is added to, and refits it jointly
    wherever structure is left: a mode's frequency screen, which a larger effect beside it
    leads astray when run on the nominal fit alone; a momentum's equation-error estimate, which
    a screen from its single fit's parameters, biased by the effect beside it, does not reach; a
    gyro bias, whose screen holds the rates it shifts),
    ``optional`` (parameters a truth Effect may leave out, with the value they then take),
    ``keeps_invariants`` (the effect acts on the body only as a torque, or as dissipation inside
    it: |J w + h| and w.J w / 2 of the measured rates stay the body's momentum and energy, so
    the invariants may be read with its fit's inertia alone; not so for a gyro error, a fitted
    momentum or mode, an inertia that changes).
    """

    name: ClassVar[str]
    params: ClassVar[tuple[str, ...]]
    size: ClassVar[int]
    family: ClassVar[str] = ""
    needs_torque: ClassVar[bool] = False
    needs_attitude: ClassVar[bool] = False
    needs_momentum: ClassVar[bool] = False
    ambiguities: ClassVar[tuple[tuple[str, str], ...]] = ()
    sets_inertia: ClassVar[bool] = False
    #: A varying form's time profile: one knot per this many residual rows (0: no varying
    #: form), within these bounds; and the ambiguities that form adds.
    ROWS_PER_KNOT: ClassVar[int] = 0
    KNOTS: ClassVar[tuple[int, int]] = (0, 0)
    varying_ambiguities: ClassVar[tuple[tuple[str, str], ...]] = ()
    restarts_on_base: ClassVar[tuple[str, ...]] = ()
    optional: ClassVar[dict] = {}
    keeps_invariants: ClassVar[bool] = False
    #: Each parameter's unit, as reports print it ("" where it has none).
    units: ClassVar[dict] = {}
    #: The parts (recordings.BODY_PARTS) of which the body must carry one for the effect to be
    #: the named physics (empty: any body), the words for those parts, and what the fitted terms
    #: are where the body carries none of them, per form ("" the default).
    hardware: ClassVar[tuple[str, ...]] = ()
    hardware_words: ClassVar[str] = ""
    as_fitted: ClassVar[dict] = {}

    def carried_words(self) -> str:
        """The condition under which the effect is its named physics, in words."""
        return f"the body carries a {self.hardware_words}"

    def lacked_words(self) -> str:
        """What a sidecar that rules the effect's physics out says, in words."""
        return f"the body carries no {self.hardware_words}"

    def implausible(self, params: dict, meta: dict, d) -> str | None:
        """Why the fitted `params` are beyond what such a body or sensor plausibly has (the
        range, in words), given the sidecar `meta` and the record's data d (its noise level);
        None where they are plausible or the effect has no such range.
        """
        return None

    # --- parameters -------------------------------------------------------------------------
    def draw(self, rng: np.random.Generator, body: Body) -> dict:
        """Random magnitudes, sized to the body so the effect is visible but not dominant."""
        raise NotImplementedError

    def unpack(self, p: np.ndarray) -> dict:
        """Fitted vector p -> named parameters (the single parameter by default)."""
        return {self.params[0]: p[0] if self.size == 1 else np.array(p[:self.size])}

    def pack(self, params: dict) -> np.ndarray:
        """Named parameters -> the fitted vector, the inverse of unpack."""
        value = np.ravel(np.asarray(params[self.params[0]], float))
        return np.broadcast_to(value, (self.size,)).copy() if value.size == 1 else value

    def confounded(self, form: str) -> tuple[tuple[str, str], ...]:
        """The known ambiguities of the effect fitted in that form: ``ambiguities``, and in the
        varying form also ``varying_ambiguities``.
        """
        return self.ambiguities + (self.varying_ambiguities if form == "varying" else ())

    def knots(self, d) -> int:
        """Knots of the varying form's time profile on d: as many as knot_room allows, within
        KNOTS (0: too few for it, or the effect has no varying form).
        """
        if not self.ROWS_PER_KNOT:
            return 0
        k = self.knot_room(d)
        return 0 if k < self.KNOTS[0] else min(k, self.KNOTS[1])

    def knot_room(self, d) -> int:
        """Knots d has room for: one per ROWS_PER_KNOT residual rows."""
        return d.n_rows // self.ROWS_PER_KNOT

    # --- fit set-up -------------------------------------------------------------------------
    def forms(self, d) -> tuple[str, ...]:
        """The forms this effect is fitted in on d: its simplest, "", and where it has knots on d
        (knots), also "varying", its time-varying form.
        """
        return ("", "varying") if self.knots(d) else ("",)

    def form_size(self, form: str, d) -> int:
        """Length of p in that form."""
        return self.size

    def skip_reason(self, d) -> str | None:
        """Why the data cannot test this effect, or None."""
        if self.needs_torque and not d.has_torque:
            return "no commanded torque in the recording"
        if self.needs_attitude and d.q is None:
            return "needs attitude (qw..qz) columns"
        if self.needs_momentum and not d.has_momentum:
            return "no changing internal momentum logged (h_x..h_z columns)"
        return None

    def bounds(self, form: str, d) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds of p."""
        size = self.form_size(form, d)
        return np.full(size, -np.inf), np.full(size, np.inf)

    def held(self, form: str, d) -> np.ndarray:
        """Bool mask of parameters held at their start (set by a scan, or bookkeeping)."""
        return np.zeros(self.form_size(form, d), bool)

    def typical(self, form: str, d) -> np.ndarray:
        """Typical magnitude of each parameter (finite-difference steps and solver scaling)."""
        return np.ones(self.form_size(form, d))

    def starts(self, form: str, d, probe) -> list[np.ndarray]:
        """Starts of the fit (several where the cost is not convex): vectors p of this effect
        (the rest of the model as in the fit it is added to), or whole joint vectors x where the
        start moves more (probe.x(p, inertia)); probe (fit.Probe) scores candidates.
        """
        return [np.zeros(self.form_size(form, d))]

    def nested(self, form: str, d, p) -> np.ndarray | None:
        """The vector of this form that equals p, the fit of the first form (forms(d)[0]), where
        this form nests that one (its fit then starts there alone); None where it does not.
        """
        return None

    def neutral(self, form: str, d, base) -> np.ndarray:
        """A vector p at which the effect changes nothing of the fit `base` it is added to (zero
        within the bounds: a zero coupling, momentum, scale or rotation).
        """
        return np.clip(np.zeros(self.form_size(form, d)), *self.bounds(form, d))

    def penalty(self, p, d) -> list[float]:
        """Constraint rows (relative units: 0 where the constraint holds) appended to the
        whitened residual, heavily weighted: what the parameters must obey.
        """
        return []

    def feasible(self, p, inertia) -> np.ndarray:
        """The nearest vector to p that the physics allows with the model's inertia (3, 3)
        kg·m² (the solver projects every step onto it): p itself by default.
        """
        return p

    def face(self, p) -> np.ndarray:
        """(m, len(p)) rows A: steps dp with A dp = 0 stay on the face of the physical limit
        where p sits (the solver also tries such a step, so it does not creep along the limit
        by projections); none by default.
        """
        return np.zeros((0, p.size))

    # --- physics (truth and model) ----------------------------------------------------------
    def disturbance(self, params: dict) -> dict:
        """Fields of dynamics.Disturbance that carry this effect in the compiled right-hand side."""
        return {}

    def applied(self, params: dict, cumulative: Cumulative) -> Cumulative:
        """The running integral of the torque the body receives, from that of the command."""
        return cumulative

    def momentum(self, params: dict, t: np.ndarray):
        """Internal momentum (k, 3) kg·m²/s at times t (k,) s that changes in time, or None."""
        return None

    def known_momentum(self, params: dict, h: np.ndarray) -> np.ndarray:
        """The internal momentum (k, 3) kg·m²/s the body carries, from h (k, 3), the one the
        recording logs (its h columns).
        """
        return h

    def motion_torque(self, params: dict, motion):
        """The torque (m+1, 3) N·m at the grid points of motion (model.Motion: the recording's own
        attitude and rates on the grid) that the body's motion sets (air on a body in flight),
        or None.
        """
        return None

    def damping_factor(self, params: dict, t: np.ndarray):
        """The factor (k,) of the viscous damping matrix at times t (k,) s where the drag
        coefficient changes in time, or None.
        """
        return None

    def gyro(self, params: dict, w: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Gyro output (..., n, 3) from true rates w (..., n, 3) at the sample times t (n,) s (a
        batch of trajectories of one model at once: leading axes broadcast).
        """
        return w

    def true_inertia(self, params: dict):
        """The body's inertia (3, 3) when this effect sets it (not the nominal), or None; only an
        effect with sets_inertia sets it.
        """
        return None

    def inertia_change(self, params: dict):
        """(t_change s, delta_J (3, 3) kg·m²) when the inertia changes during the recording."""
        return None


#: Effect name -> its model; the catalogue in the contract's order.
REGISTRY: dict[str, EffectModel] = {}


def register(cls):
    """Class decorator: add one instance of an EffectModel subclass to REGISTRY."""
    REGISTRY[cls.name] = cls()
    return cls


@functools.lru_cache(maxsize=16)
def _spline_basis(knots: bytes, t: bytes) -> np.ndarray:
    """(n, K) values at the times t (n,) s of the cubic splines (not-a-knot) through the knots
    (K,) s, one a knot at 1 and the others 0, held at their end values beyond the knots: a
    profile's spline at t is this times its K values. Cached (read-only): the knots are held in
    a fit and t is the model's grid, and building a spline costs ten times the product.
    """
    k, times = np.frombuffer(knots), np.frombuffer(t)
    out = interpolate.CubicSpline(k, np.eye(k.size))(np.clip(times, k[0], k[-1]))
    out.flags.writeable = False
    return out


def effect_model(name: str) -> EffectModel:
    """The registered model of an effect name (ConfigError naming the choices otherwise)."""
    try:
        return REGISTRY[name]
    except KeyError:
        raise ConfigError(f"unknown effect {name!r}; choose from {sorted(REGISTRY)}") from None


@dataclasses.dataclass(frozen=True)
class Effect:
    """One catalogue effect with its parameters (a dict of floats / lists): a truth instance."""

    name: str
    params: dict

    def __post_init__(self) -> None:
        model = effect_model(self.name)
        unknown = set(self.params) - set(model.params) - {"axis", "profile_t", "profile"}
        if unknown or not set(model.params) - set(model.optional) <= set(self.params):
            raise ConfigError(f"effect {self.name}: parameters {sorted(self.params)}; expected "
                              f"{model.params}")

    @property
    def model(self) -> EffectModel:
        """The effect's registered class instance."""
        return REGISTRY[self.name]


def random_params(name: str, rng: np.random.Generator, inertia, omega_ref: float, tau_ref: float,
                  gyro_sigma: float, duration: float) -> dict:
    """Random magnitudes of an effect sized to the body (see Body and each class's draw).

    inertia (3, 3) kg·m², omega_ref rad/s (typical rate), tau_ref N·m (actuator level),
    gyro_sigma rad/s, duration s.
    """
    body = Body(np.asarray(inertia, float), omega_ref, tau_ref, gyro_sigma, duration)
    return effect_model(name).draw(rng, body)
