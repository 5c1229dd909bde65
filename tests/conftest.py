import numpy as np
import pytest

from inertia_gym.scenario import Scenario


@pytest.fixture(scope="session")
def paper() -> Scenario:
    """The paper's scenario (defaults)."""
    return Scenario()


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)
