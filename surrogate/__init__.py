"""Surrogate stage: physics-informed f = d∘m and black-box baselines trained on the FEM's datasets.

Modules, one idea each: :mod:`~surrogate.data` (datasets → transitions, through the
dataset contract :mod:`deapull.dataset`), :mod:`~surrogate.phi` (φ, the coin a physics
model simulates, as a value), :mod:`~surrogate.models` (one module per kind behind a
registry: f with the paper's law, the tip-contact f-coulomb, NN, LSTM),
:mod:`~surrogate.train` (Algorithm 1), :mod:`~surrogate.store` (model folders),
:mod:`~surrogate.rollout` and :mod:`~surrogate.native` (recursive rollouts),
:mod:`~surrogate.evaluate` (errors against the FEM) and :mod:`~surrogate.experiments`
(the paper's six sets). The commands (``deapull train|evaluate|experiments``) live in
:mod:`deapull.workflows.cli_surrogate`.
"""
from deapull.surrogate import models, store
from deapull.surrogate.data import SetupData, Transitions, load_setup, load_sweep, transitions
from deapull.surrogate.evaluate import Evaluation, evaluate
from deapull.surrogate.models import KINDS, Surrogate, build, register
from deapull.surrogate.phi import Phi
from deapull.surrogate.rollout import Rollout, rollout
from deapull.surrogate.train import TrainConfig, TrainResult, train

__all__ = ["Evaluation", "KINDS", "Phi", "Rollout", "SetupData", "Surrogate", "TrainConfig", "TrainResult",
           "Transitions", "build", "evaluate", "load_setup", "load_sweep", "models", "register", "rollout", "store",
           "train", "transitions"]   # models, store: the modules (store.load / store.save)
