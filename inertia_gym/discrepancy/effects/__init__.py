"""The physics catalogue (docs/contracts.md) as a registry of effect classes, one per module.

Units: rad/s, N·m, kg·m², s. The body obeys
    J(t) w_dot + K eta_dot w + h_dot + d eta_ddot + w x (J(t) w + h + d eta_dot) = tau_applied + tau_ext,
    eta_ddot + 2 zeta Omega eta_dot + Omega^2 eta = w^T K w / 2 - d . w_dot   (flexible mode,
    J(t) carrying its K eta)
and the gyro reads (1 + s) * w + b. Every effect sets one group of these terms, and one class
owns everything about it: its parameters and their fitted vector, a random draw sized to the
body, bounds, typical sizes and starts of the fit, its known ambiguities, and its physics hooks:
    disturbance  torques the compiled right-hand side carries (dynamics.Disturbance fields),
    applied      what the body receives of the commanded torque (its running integral),
    momentum     an internal momentum changing in time,
    gyro         what the gyro reads of the true rates,
    true_inertia / inertia_change   the body's inertia when it is not the nominal one.
The same hooks drive the truth simulator (synthetic.simulate_truth) and the model that diagnose
fits (fit.py): the recording is explained by simulating the catalogue, never by a second copy
of its equations.

Each effect is one class in one module of this package, named for the effect (gyro_bias.py holds
GyroBias); the base class, the registry and the shared helpers are in base.py, and a form two
effects share in its own module (gyro_error.py, drag.py). Adding an effect is one file here, a
subclass of EffectModel with ``@register``, and its import below: importing a module registers
its effect, so the imports' order is the catalogue's (REGISTRY's, which orders the reports and
breaks ties between equal BICs).

Fit-side hooks receive ``d``, a fit.Data (the recording prepared for fitting).
"""

from inertia_gym.discrepancy.effects.base import (
    REGISTRY,
    Body,
    Cumulative,
    Effect,
    EffectModel,
    effect_model,
    inertia6,
    jsonable,
    matrix6,
    random_params,
    register,
    rotvec_matrix,
)

# isort: off
# the catalogue's order (docs/contracts.md)
from inertia_gym.discrepancy.effects.gyro_error import BIAS_KNOT_SPACING_S
from inertia_gym.discrepancy.effects.gyro_bias import GYRO_BIAS_OVER_NOISE, GYRO_BIAS_PLAUSIBLE, GyroBias
from inertia_gym.discrepancy.effects.gyro_scale import GYRO_SCALE_BOUND, GyroScale
from inertia_gym.discrepancy.effects.constant_body_torque import ConstantBodyTorque
from inertia_gym.discrepancy.effects.internal_momentum import InternalMomentum
from inertia_gym.discrepancy.effects.viscous_damping import ViscousDamping
from inertia_gym.discrepancy.effects.aero_drag import (
    FLIGHT_MAX_S,
    GRAVITY,
    AeroDrag,
    direction,
    direction_angles,
    plane_basis,
)
from inertia_gym.discrepancy.effects.internal_dissipation import InternalDissipation
from inertia_gym.discrepancy.effects.actuator_scale import ActuatorScale
from inertia_gym.discrepancy.effects.actuator_misalignment import ActuatorMisalignment
from inertia_gym.discrepancy.effects.actuator_delay import ActuatorDelay
from inertia_gym.discrepancy.effects.momentum_misalignment import MomentumMisalignment
from inertia_gym.discrepancy.effects.gravity_gradient import GravityGradient
from inertia_gym.discrepancy.effects.flexible_mode import (
    FLEX_BAND,
    MODE_MASS_LIMIT,
    MODE_MIN_CYCLES,
    FlexibleMode,
    flex_floor_hz,
)
from inertia_gym.discrepancy.effects.inertia_change import AFTER_MOMENT_FLOOR, InertiaChange
from inertia_gym.discrepancy.effects.inertia_offset import InertiaOffset
# isort: on

#: Effect name -> ordered parameter names (vector parameters are given as 3-lists).
EFFECTS: dict[str, tuple[str, ...]] = {name: m.params for name, m in REGISTRY.items()}

__all__ = [
    # the base, the registry and the catalogue's entry points
    "Body", "Cumulative", "EFFECTS", "Effect", "EffectModel", "REGISTRY", "effect_model",
    "random_params", "register",
    # shared helpers
    "inertia6", "jsonable", "matrix6", "rotvec_matrix",
    # the effects, in the catalogue's order, with their constants and helpers
    "BIAS_KNOT_SPACING_S", "GYRO_BIAS_OVER_NOISE", "GYRO_BIAS_PLAUSIBLE", "GyroBias",
    "GYRO_SCALE_BOUND", "GyroScale", "ConstantBodyTorque", "InternalMomentum", "ViscousDamping",
    "FLIGHT_MAX_S", "GRAVITY", "AeroDrag", "direction", "direction_angles", "plane_basis",
    "InternalDissipation", "ActuatorScale", "ActuatorMisalignment", "ActuatorDelay",
    "MomentumMisalignment", "GravityGradient", "FLEX_BAND", "MODE_MASS_LIMIT", "MODE_MIN_CYCLES",
    "FlexibleMode", "flex_floor_hz", "AFTER_MOMENT_FLOOR", "InertiaChange", "InertiaOffset",
]
