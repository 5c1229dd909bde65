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


def install_hint(extra: str) -> str:
    """How to install the optional extra `extra` from the repository's folder; torch pinned first
    for the extras that need it (an unpinned torch pulls a several-GB CUDA build).
    """
    torch = ("pip install torch==2.13.0 --index-url https://download.pytorch.org/whl/cpu (a CPU build), then "
             if extra in ("optimize", "rl") else "")
    return f"{torch}pip install -e '.[{extra}]' in the repository's folder"
