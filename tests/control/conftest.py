"""Plants for the control tests: a surrogate trained on the committed FEM fixture (C1, test
mesh: the coin travels at most 0.65 mm, so these tests aim at −0.4 mm) and two analytic
plants with answers known in closed form. Nothing here needs dolfinx; the FEM-plant tests
import it inside themselves and are marked ``fem``."""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from deapull.surrogate.phi import Phi
from tests.conftest import MODELS

#: a target the fixture's surrogate reaches (its coin travels 0.65 mm at 400 V)
FIXTURE_TARGET_M = -0.4e-3


class RatchetPlant:
    """The quasi-static push without rate effects: x = −gain (max(V̂, V_on) − V_on), V̂ the
    highest voltage so far. The coin moves only while the voltage rises past its previous
    high and never comes back."""

    dt = 1e-3
    truth = Phi(mass_kg=1.36e-3, mu_b=0.2, mu_t=0.5)

    def __init__(self, gain_m_per_V: float = 5e-6, onset_V: float = 150.0, name: str = "ratchet"):
        self.gain, self.onset, self.name = gain_m_per_V, onset_V, name
        self.reset()

    def reset(self, seed=None):
        self.t, self.V, self.high, self.x = 0.0, 0.0, 0.0, 0.0
        return np.zeros(2)

    def step(self, V: float):
        self.high = max(self.high, V)
        x = -self.gain * (max(self.high, self.onset) - self.onset)
        u, self.x = (x - self.x) / self.dt, x
        self.t, self.V = self.t + self.dt, V
        return np.array([x, u])


class ParkedPlant:
    """A coin that stays at ``x_m`` whatever the voltage."""

    dt = 1e-3
    truth = Phi(mass_kg=1.36e-3, mu_b=0.2, mu_t=0.5)
    name = "parked"

    def __init__(self, x_m: float):
        self.x_m, self.t, self.V = x_m, 0.0, 0.0

    def reset(self, seed=None):
        self.t, self.V = 0.0, 0.0
        return np.array([self.x_m, 0.0])

    def step(self, V: float):
        self.t, self.V = self.t + self.dt, V
        return np.array([self.x_m, 0.0])


@pytest.fixture(scope="session")
def fs1_model(committed):
    """f-coulomb trained on the fixture's C1 (validated on C2; committed), as the plant f_s,1."""
    return committed("f-coulomb")


@pytest.fixture(scope="session")
def fs1_dir(tmp_path_factory):
    """That model's folder as `deapull train` saved it (a --plant-model folder), copied."""
    return Path(shutil.copytree(MODELS / "f-coulomb", tmp_path_factory.mktemp("models") / "fs1"))


@pytest.fixture
def surrogate_plant(fs1_model, sweep):
    """f_s,1 simulating the fixture's C1 coin."""
    from deapull.control.plants import SurrogatePlant
    return SurrogatePlant(fs1_model, fs1_model.phi_of(sweep["C1"]), name="surrogate:C1")
