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
  online inference of φ.

The experiment harness and the ``deapull control`` command are in
:mod:`deapull.workflows.control` (see README, "Control").
"""
