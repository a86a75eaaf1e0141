"""Control stage (the layer above the surrogates): plants, policies and online inference.

Installed as ``deapull.control`` so that it never shadows python-control's ``control``.
The controllers of the paper (MPC, SAC, PD, heuristic) are the open control issue; this
layer holds only what has landed (see README, "Pipeline").
"""
