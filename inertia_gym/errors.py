"""The project's exception tree: every bad input ends in one of these, naming the culprit."""


class InertiaGymError(Exception):
    """Base class of every error inertia-gym raises on purpose."""


class ConfigError(InertiaGymError, ValueError):
    """A scenario, option or argument is invalid; the message names the field and value."""


class RecordingError(InertiaGymError, ValueError):
    """A recording cannot be read; the message names the file, row and column."""


class EstimatorDivergedError(InertiaGymError, RuntimeError):
    """The estimator left its domain of validity (non-finite state, exploding innovations)."""


class InputWarning(UserWarning):
    """Something in the user's input that the run goes on without (the CLI prints it in one line)."""


class SidecarKeyWarning(InputWarning):
    """A sidecar key that looks like a mistyped key the tool reads; the run goes on without it."""
