"""The surrogate models, one kind per module behind a small registry.

* ``f`` — :class:`~deapull.surrogate.models.paper.PhysicsModel`, the paper's f = d∘m
  (forces from a material network, the paper's friction law; φ = (m_c, μ_b, V^T));
* ``f-coulomb`` — :class:`~deapull.surrogate.models.tip_contact.TipContactModel`, f = d∘m
  grounded in the FEM's contact mechanics (the tip's stroke and pressing force from m, two
  Coulomb contacts in d; φ = (m_c, μ_b, μ_t));
* ``f-patch`` — :class:`~deapull.surrogate.models.tip_contact.TipPatchModel`, f-coulomb whose
  tip patch spreads with V (the coin lags the tip more at a larger friction margin); needs
  coins of two or more friction pairs;
* ``f-patch-lag`` — :class:`~deapull.surrogate.models.tip_contact.TipPatchLagModel`, f-patch
  whose patch also depends on the coin's lag behind the tip (the held-out pair model);
* ``f-memory`` — :class:`~deapull.surrogate.models.memory.TipMemoryModel`, the tip-contact f
  with the tip's memory (its compliance carries the friction between steps, so the friction
  reverses when the voltage turns; Fy depends on it);
* ``nn``, ``lstm`` — :mod:`~deapull.surrogate.models.black_box`, the black-box baselines.

Every model takes and returns physical quantities (SI); the normalisation of the training
data lives in the model as buffers, so a model is one self-contained ``nn.Module``. All
share one step interface for rollouts, ``step(s, a, memory, phi) -> (s', z, memory)``
(``z`` None for the black boxes, ``memory`` None for memoryless models, ``phi`` a
:class:`~deapull.surrogate.phi.Phi`, ignored by the black boxes), and one training
interface, ``training_loss(batch)`` (φ of each row in ``batch.phi``).

A new kind is a :class:`Surrogate` subclass in its own module, decorated with
:func:`register` and imported below (the import order is the order the CLI lists kinds).
"""
from deapull.surrogate.models.base import (INPUT_UNITS, INPUTS, InputRange, NativeKernel, Normalisation, Surrogate,
                                           mlp)
from deapull.surrogate.models.registry import KINDS, build, kind_class, register
# the kinds (each registers itself on import)
from deapull.surrogate.models.paper import PhysicsModel, paper_dynamics
from deapull.surrogate.models.tip_contact import TipContactModel, regularised_slip, tip_coin_step
from deapull.surrogate.models.memory import TipMemoryModel, tip_memory_step
from deapull.surrogate.models.black_box import LSTMBaseline, NNBaseline

__all__ = ["INPUTS", "INPUT_UNITS", "InputRange", "KINDS", "LSTMBaseline", "NNBaseline", "NativeKernel",
           "Normalisation", "PhysicsModel", "Surrogate", "TipContactModel", "TipMemoryModel", "build", "kind_class", "mlp",
           "paper_dynamics", "register", "regularised_slip", "tip_coin_step", "tip_memory_step"]
