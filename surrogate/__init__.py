"""Surrogate stage: physics-informed f = d∘m and black-box baselines trained on the FEM's datasets.

Modules, one idea each: :mod:`~surrogate.data` (datasets → transitions),
:mod:`~surrogate.models` (f with the paper's law, the tip-contact f-coulomb, NN, LSTM),
:mod:`~surrogate.train` (Algorithm 1), :mod:`~surrogate.store` (model folders),
:mod:`~surrogate.rollout` and :mod:`~surrogate.native` (recursive rollouts),
:mod:`~surrogate.evaluate` (errors against the FEM), :mod:`~surrogate.experiments`
(the paper's six sets) and :mod:`~surrogate.cli` (``deapull train|evaluate|experiments``).
"""
