"""Fuzz of scenario files: random fields, scales over 8 decades, wrong units and types.

Every outcome is a valid Scenario on which a short validation gives finite numbers (or a clean
project error), or a one-line ConfigError naming a field; through the CLI, exit code 0 with
finite numbers, or exit code 2 with one line on stderr: never a traceback, NaN or RuntimeWarning.
"""

import json
import math
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from inertia_gym.cli import main
from inertia_gym.errors import ConfigError, InertiaGymError
from inertia_gym.scenario import Scenario, ScenarioWarning
from inertia_gym.validation import validate

FIELDS = [f for f in Scenario.__dataclass_fields__.values() if f.init]
NAMES = [f.name for f in FIELDS]
MATRIX_FIELDS = ("inertia_true", "inertia_guess")
VECTOR3_FIELDS = ("omega0", "attitude0_euler_deg", "gravity_inertial", "mag_inertial")
INTERVAL_FIELDS = ("meas_interval", "dwell", "t_on", "validation_coast", "a_bounds", "b_bounds")

decades = st.floats(-4.0, 4.0).map(lambda e: 10.0 ** e)  # 8 decades
wrong_type = st.sampled_from(["5 N*m", "", True, None, {"value": 1.0}, [], [[1.0, 2.0], [3.0]],
                              float("nan"), float("inf"), -1.0, 0.0, 1e308, [1.0, "x", 3.0]])


@st.composite
def inertia(draw):
    """A body over 8 decades: random principal moments (sometimes breaking the triangle
    inequality or positivity), randomly rotated, sometimes made asymmetric.
    """
    scale = draw(decades)
    moments = np.array(draw(st.lists(st.floats(0.05, 1.0), min_size=3, max_size=3))) * scale
    if draw(st.booleans()):
        moments[draw(st.integers(0, 2))] *= draw(st.sampled_from([-1.0, 0.0, 3.0]))
    q, _ = np.linalg.qr(np.random.default_rng(draw(st.integers(0, 2**16))).standard_normal((3, 3)))
    matrix = q @ np.diag(moments) @ q.T
    if draw(st.integers(0, 9)) == 0:
        matrix[0, 1] += scale
    return matrix.tolist()


def value_for(name: str):
    """A plausible value of one field (its scale drawn over 8 decades), in the file's types."""
    if name in MATRIX_FIELDS:
        good = inertia()
    elif name in VECTOR3_FIELDS:
        good = st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3).flatmap(
            lambda v: decades.map(lambda s: [x * s for x in v]))
    elif name in INTERVAL_FIELDS:
        good = st.tuples(decades, st.floats(1.0, 3.0)).map(lambda p: [p[0] * 1e-2, p[0] * p[1] * 1e-2])
    elif name == "P0_theta":
        good = decades.map(lambda s: s * s)
    elif name == "bursts_per_episode":
        good = st.integers(-1, 6)
    elif name == "estimator":
        good = st.sampled_from(["ekf", "ukf", "pf"])
    elif name == "window_set":
        good = st.sampled_from(["burst", "episode", "all"])
    elif name == "use_vector_sensors":
        good = st.booleans()
    elif name in ("alpha_gamma", "nis_gate", "inertia_step_limit"):
        good = st.floats(0.0, 1.5)
    else:
        good = decades.map(lambda s: s * 1e-2)
    return good


@st.composite
def scenario_files(draw):
    """A mapping of 1-8 random fields as a scenario file holds; in about half of the files one
    field has a wrong type or unit, or a misspelt name.
    """
    names = draw(st.lists(st.sampled_from(NAMES), min_size=1, max_size=8, unique=True))
    data = {name: draw(value_for(name)) for name in names}
    spoil = draw(st.sampled_from(["none"] * 10 + ["value"] * 9 + ["name"]))
    if spoil == "name":
        data["tau_mx"] = 1.0
    elif spoil == "value":
        data[draw(st.sampled_from(names))] = draw(wrong_type)
    return {k: v for k, v in data.items() if v is not None}  # TOML/JSON have no null field


def build(data):
    """Scenario.from_mapping(data) or its ConfigError; warnings other than ScenarioWarning fail."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warnings.simplefilter("ignore", ScenarioWarning)
        try:
            return Scenario.from_mapping(data), None
        except ConfigError as exc:
            return None, str(exc)


def short_validation(sc: Scenario) -> dict:
    """A validation whose burst comes after a coast of 20 steps (the scenario's times may span
    8 decades): finite numbers or a project error.
    """
    with warnings.catch_warnings():  # (replace checks the scenario again: it may warn too)
        warnings.simplefilter("error")
        warnings.simplefilter("ignore", ScenarioWarning)
        quick = sc.replace(validation_coast=(20 * sc.dt, 20 * sc.dt))
        lo, hi = quick.xi_bounds
        xi = 0.5 * (lo + hi)
        xi[2] = quick.t_on[0]
        duration = (60 + 2 * math.ceil(xi[2] / sc.dt)) * sc.dt
        return validate(quick, xi, duration, [0]).summary()


def finite(obj) -> bool:
    """No NaN or infinity anywhere in a JSON-like object (None stands for 'no value')."""
    if isinstance(obj, dict):
        return all(finite(v) for v in obj.values())
    if isinstance(obj, (list, tuple)):
        return all(finite(v) for v in obj)
    return not isinstance(obj, float) or math.isfinite(obj)


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scenario_files())
def test_every_scenario_file_is_valid_or_one_line_error(data):
    sc, error = build(data)
    if sc is None:
        assert "\n" not in error and len(error) < 600
        assert any(name in error for name in data) or "unknown scenario field" in error, error
    else:
        assert finite(sc.to_dict()) and np.all(np.isfinite(sc.xi_bounds))
        assert build(sc.to_dict())[0] == sc


@pytest.mark.slow
@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scenario_files())
def test_a_valid_fuzzed_scenario_validates_to_finite_numbers(data):
    sc, _ = build(data)
    assume(sc is not None and sc.t_on[0] <= 1000 * sc.dt)
    try:
        summary = short_validation(sc)
    except InertiaGymError as exc:
        assert "\n" not in str(exc)
        return
    assert finite(summary), summary


@pytest.mark.slow
@settings(max_examples=6, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(data=scenario_files(), as_json=st.booleans())
def test_cli_on_fuzzed_scenario_files(data, as_json, tmp_path, capsys):
    path = tmp_path / ("s.json" if as_json else "s.toml")
    if as_json:
        path.write_text(json.dumps(data))
    else:
        path.write_text("\n".join(f"{k} = {_toml(v)}" for k, v in data.items()))
    out = tmp_path / "out"
    code = main(["validate", "--scenario", str(path), "--xi", "none", "--duration", "0.5", "--seeds", "1",
                 "--out", str(out)])
    captured = capsys.readouterr()
    errors = [line for line in captured.err.splitlines() if "warning:" not in line]
    assert "Traceback" not in captured.err and "nan" not in captured.out.lower()
    if code == 0:
        assert errors == [] and finite(json.loads((out / "result.json").read_text()))
    else:
        assert code == 2 and len(errors) == 1 and errors[0].startswith("inertia-gym validate: error:")


def _toml(value) -> str:
    """A TOML literal of a fuzzed value (non-finite floats as TOML's nan/inf, booleans lower-case)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return "nan" if math.isnan(value) else ("inf" if value == math.inf else repr(value))
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {_toml(v)}" for k, v in value.items()) + "}"
    return json.dumps(value)
