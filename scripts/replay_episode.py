"""Replay a recorded FEM control episode offline and log what the MPC policy estimated.

A diagnostic for ``deapull control`` on FEM plants (docs/control.md, seventh session): an
FEM episode takes 20-40 minutes, but the policy sees only the noisy position and the voltage,
and the episode is deterministic given its seed. So a stand-in plant that returns the
recorded true position at every step (``traces.npz`` of the run) reproduces the episode in
about a minute, as long as the policy asks for the recorded voltages. The plant checks that
at every step and stops at the first step where the policy would act otherwise (a changed
policy: the step where the two part ways). Every step's estimate, its std, the hold and
stand-off state and the action are written to a JSON file.

::

    .venv/bin/python scripts/replay_episode.py out/s7/fix_C1_s0/traces.npz --episode 0 \\
        --log replay.json -- control --policy mpc --plant fem:C1 --episodes 1 --seed 0 ...

Everything after ``--`` is the original ``deapull control`` command line (same plant, seed
and MPC flags; ``--out`` to a scratch folder). Not part of any make target.
"""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np


class ReplayDiverged(AssertionError):
    """The policy asked for another voltage than the recorded episode's."""


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    split = argv.index("--") if "--" in argv else len(argv)
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("traces", help="traces.npz of the recorded run")
    p.add_argument("--episode", type=int, default=0, help="the episode's index in that run")
    p.add_argument("--log", default="replay.json", help="where the per-step log goes")
    args = p.parse_args(argv[:split])
    control_args = argv[split + 1:]

    from deapull.control import mpc_policy, plants
    from deapull.surrogate.phi import Phi
    traces = np.load(args.traces)
    prefix = [k[:-len("x_m")] for k in traces.files if k.endswith(f"|{args.episode}|x_m")]
    if not prefix:
        raise SystemExit(f"{args.traces}: no episode {args.episode} (keys: {', '.join(traces.files[:4])}, ...)")
    X, V_rec = traces[prefix[0] + "x_m"], traces[prefix[0] + "V_V"]

    def init(self, scene, work_dir=None, name="fem", dt=plants.DT_S):
        self.scene, self.name, self.dt = scene, name, float(dt)
        self.truth = Phi(mass_kg=float("nan"), mu_b=scene.coin.mu_b, mu_t=scene.coin.mu_t)
        self.mass_kg, self.mesh_summary, self.records, self.i, self.t, self.V = float("nan"), {}, [], 0, 0.0, 0.0

    def reset(self, seed=None):
        self.i, self.t = 0, 0.0
        return np.array([X[0], 0.0])

    def step(self, V):
        self.i += 1
        if self.i >= len(X) or abs(V - V_rec[self.i]) > 1e-6:
            recorded = V_rec[self.i] if self.i < len(X) else "none"
            raise ReplayDiverged(f"step {self.i}: the policy asks for {V!r} V, the recording has {recorded}")
        self.t = self.i * self.dt
        return np.array([X[self.i], (X[self.i] - X[self.i - 1]) / self.dt])

    plants.FEMPlant.__init__, plants.FEMPlant.reset, plants.FEMPlant.step = init, reset, step
    plants.FEMPlant.save = lambda self, path, name: path
    log = []
    act = mpc_policy.MPCPolicy.act

    def logged_act(self, obs, info):
        dV = act(self, obs, info)
        x, _, V = self.previous
        xi0 = self.dynamics.state(*self.previous, self.memory)
        log.append({"step": len(log), "x_true_m": float(X[len(log)]), "x_estimate_m": x,
                    "estimate_std_m": self.estimate_std_m, "holding": self.holding, "waited": self.waited,
                    "aim_m": self._aim(xi0, x, V), "dV_V": float(dV)})
        return dV

    mpc_policy.MPCPolicy.act = logged_act
    from deapull.workflows.cli import main as deapull_main
    try:
        rc = deapull_main(control_args)
    finally:
        with open(args.log, "w") as f:
            json.dump(log, f)
        print(f"{len(log)} steps logged to {args.log}")
    return rc


if __name__ == "__main__":
    raise SystemExit(main())
