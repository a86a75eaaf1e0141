"""The paper's figures (Lahariya et al., IROS 2022), each with where it comes from.

Every number the project compares with the paper is typed here and only here; the report,
the benches and the experiments import it.
"""
from __future__ import annotations

#: ABAQUS wall time of one 1 s, 700-point run (§VI-A)
PAPER_FEM_S = 130.0
#: Table II (MAE over the six test setups; m and N) and the 1 s rollout times (ms, §VI-A)
PAPER_TABLE2 = {"mae_x_m": {"f": 0.34e-4, "lstm": 3.86e-4, "nn": 9.86e-4},
                "mae_Fx_N": {"f": 3.68e-4}, "mae_Fy_N": {"f": 12.01e-4},
                "rollout_ms": {"f": 700.0, "nn": 300.0, "lstm": 1200.0}}
#: §VI-B: iterations to the target and time per iteration (ms) per policy (Fig. 6, C2)
PAPER_CONTROL = {"mpc": ("≤ 200", 1200.0), "sac": ("~10,000", 5.0), "pd": ("~1,500", 1.0), "heur": ("~500", None)}
#: the threshold displacement of V^T (§V)
THRESHOLD_M = -1e-5
