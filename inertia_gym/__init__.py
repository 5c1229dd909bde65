"""inertia-gym: informative torque excitation for identifying a tumbling rigid body's inertia.

The package holds pure physics and estimation (dynamics, sensors, estimation, information,
excitation, simulation), thin shells over them (envs, cli) and the sim-vs-real diagnosis tool
(discrepancy). Importing it registers the Gymnasium environment "InertiaGym/Excitation-v0".
"""

from inertia_gym.kernel_cache import use_fork_safe_threading, use_source_keyed_cache

use_source_keyed_cache()  # before any kernel module is imported (see kernel_cache.py)
use_fork_safe_threading()  # before the first parallel kernel runs (see kernel_cache.py)

import inertia_gym.envs  # noqa: E402,F401  (registers "InertiaGym/Excitation-v0")
from inertia_gym.errors import (  # noqa: E402
    ConfigError,
    EstimatorDivergedError,
    InertiaGymError,
    RecordingError,
)
from inertia_gym.identification import identify  # noqa: E402
from inertia_gym.joint_identification import identify_joint  # noqa: E402
from inertia_gym.recordings import Recording, read_recordings  # noqa: E402
from inertia_gym.scenario import Scenario  # noqa: E402

__all__ = [
    "ConfigError",
    "EstimatorDivergedError",
    "InertiaGymError",
    "Recording",
    "RecordingError",
    "Scenario",
    "identify",
    "identify_joint",
    "read_recordings",
]
__version__ = "0.1.0"
