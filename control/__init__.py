"""Control stage (the layer above the surrogates): plants, the task env, policies and online inference.

Installed as ``deapull.control`` so that it never shadows python-control's ``control``.

* :mod:`~deapull.control.plants` — one plant protocol (``reset``, ``step(V)``, ``dt``, ``t``,
  ``V``, ``truth``): a trained surrogate (the paper's f_s,1, f_s,2) or the FEM stepped online;
* :mod:`~deapull.control.env` — the coin-push task as a gymnasium ``Env`` (x^T = −1 mm,
  success on the true state, one ΔV limit for every policy, seeded observation noise);
* :mod:`~deapull.control.policies` — the policy interface and the PD, heuristic and SAC
  baselines;
* :mod:`~deapull.control.mpc`, :mod:`~deapull.control.dynamics`, :mod:`~deapull.control.mpc_policy`, :mod:`~deapull.control.inference`
  — the box-constrained iLQR, f_a in scaled units with its cost, the MPC policy on f_a and the
  online inference of φ;
* :mod:`~deapull.control.harness` — the closed-loop bench: the task every episode asks, the
  plants and policies built from resolved models and settings, and one episode's run.

The ``deapull control`` command (its configuration, checks and outputs) is in
:mod:`deapull.workflows.control` (see README, "Control").
"""
from deapull.control import mpc
from deapull.control.dynamics import CoinDynamics, coin_cost
from deapull.control.env import CoinPushEnv
from deapull.control.inference import InferenceConfig, OnlineInference
from deapull.control.mpc_policy import MPCConfig, MPCPolicy, make_dynamics
from deapull.control.plants import FEMPlant, Plant, PlantFailed, SurrogatePlant
from deapull.control.policies import HeuristicPolicy, PDPolicy, Policy, SACPolicy

__all__ = ["CoinDynamics", "CoinPushEnv", "FEMPlant", "HeuristicPolicy", "InferenceConfig", "MPCConfig", "MPCPolicy",
           "OnlineInference", "PDPolicy", "Plant", "PlantFailed", "Policy", "SACPolicy", "SurrogatePlant", "coin_cost",
           "make_dynamics", "mpc"]   # mpc: the module (the box-iLQR solver, mpc.solve)
