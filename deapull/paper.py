"""The paper's figures: every number the project compares with Lahariya et al., "Learning
physics-informed simulation models for soft robotic manipulation: a case study with
dielectric elastomer actuators", IROS 2022 (``../shared/seed/lahariya2022_dea_paper.tex``).

Each figure is typed here once, with the section, table or figure it comes from; the report,
the benches, the experiments and the control study import it (``tests/deapull/test_paper.py``
fails when another module types one of them). Section numbers follow the paper: §IV FEM of
DEA pulling (§IV-A its settings), §V parameter settings, §VI-A simulation, §VI-B control,
§VI-C inference; Table II is the mean absolute errors (``tab:openloopsimulation``); Fig. 6
the closed-loop control on C2.

Where the paper is ambiguous, the comment beside the figure says so and how it is read here.
"""
from __future__ import annotations

# --- the FEM (ABAQUS) -----------------------------------------------------------------------

#: §VI-A: "For 1 second of simulation with 700 points, the FEM model takes 130 seconds (average
#: for all test coins)". Per setup, ABAQUS, the paper's machine (not stated).
ABAQUS_S = 130.0
#: §VI-A: points of that 1 s run. Ambiguous: §V says "Each dataset contains 1000-2000 data
#: points" (:data:`DATASET_POINTS`); the timing is read as for 700 points.
ABAQUS_POINTS = 700
#: §V: points per FEM dataset (the range the paper gives)
DATASET_POINTS = (1000, 2000)
#: §IV-A: elements per DE membrane (C3D8E) and elements of the coin
ABAQUS_ELEMENTS_PER_MEMBRANE = 10
ABAQUS_COIN_ELEMENTS = 20
#: §IV-A: Young's modulus (Pa) and Poisson's ratio of both DE layers
YOUNGS_MODULUS_PA = 0.56e6
POISSON_RATIO = 0.5

# --- the data (§V) --------------------------------------------------------------------------

#: §V: the threshold voltage V^T is the voltage at which the coin reaches x = -1e-5 m
THRESHOLD_M = -1e-5
#: §V: "We assume the coin loses contact with the DEA for V_t >= 300 V"
CONTACT_LOST_V = 300.0

# --- the surrogates (§VI-A, Table II) -------------------------------------------------------

#: Table II: mean absolute errors of 1 s recursive rollouts over the six test setups, in SI units
#: (the table prints them in units of 1e-4 m and 1e-4 N); LSTM and NN have no force rows ("−")
TABLE2_MAE = {"mae_x_m": {"f": 0.34e-4, "lstm": 3.86e-4, "nn": 9.86e-4},
              "mae_Fx_N": {"f": 3.68e-4}, "mae_Fy_N": {"f": 12.01e-4}}
#: §VI-A: wall time of a 1 s rollout (ms): f "≤ 0.7 seconds" (an upper bound, read as 700 ms),
#: NN 0.3 s and LSTM 1.2 s
ROLLOUT_MS = {"f": 700.0, "nn": 300.0, "lstm": 1200.0}
#: Table II and the rollout times in one mapping (quantity → model → value), the shape
#: ``experiments.json`` stores under "paper"
TABLE2 = {**TABLE2_MAE, "rollout_ms": ROLLOUT_MS}
#: abstract and §VI-A: f's x error relative to the motion, "≤ 5 %" (the mean |x error| is less
#: than 0.05 times the magnitude of x)
SIM_ERROR_PCT = 5.0

# --- control (§V, §VI-B, Fig. 6) ------------------------------------------------------------

#: §V: the MPC of Amos et al. (mpc.pytorch): horizon 20 steps, 20 LQR iterations
MPC_HORIZON = 20
MPC_LQR_ITERATIONS = 20
#: §VI-B: MPC computation time per iteration (s), "average 1.2 s". Ambiguous: an "iteration" is
#: one control step (one observation of the loop) there, each solving the whole MPC problem
#: (20 LQR iterations); the benches read it so.
MPC_S_PER_ITERATION = 1.2
#: §VI-B, Fig. 6: iterations to the target on C2 per policy, as the paper words them, and time
#: per iteration (ms): SAC 0.005 s, PD 0.001 s; the heuristic's 0.002 s is only in a commented-out
#: sentence of the source, so it is None here
CONTROL = {"mpc": ("≤ 200", MPC_S_PER_ITERATION * 1e3), "sac": ("~10,000", 5.0), "pd": ("~1,500", 1.0),
           "heur": ("~500", None)}
#: §V: std of the Gaussian noise on the observed x (m); Fig. 6 shows runs with it
CONTROL_NOISE_M = 1e-3

# --- inference (§VI-C) ----------------------------------------------------------------------

#: §VI-C: inferred m_c within 10 % of the true value after 2,000 iterations; μ_b within 300
INFER_ERROR_PCT = 10.0
INFER_MASS_ITERATIONS = 2000
INFER_MU_B_ITERATIONS = 300
