"""MPC benchmark (``make bench BENCH=control``): wall time of one MPC step (one plan: horizon 20,
20 iterations) of our batched box-iLQR (deapull.control.mpc) and of mpc.pytorch on the same
problem, in one run, beside the paper's time per iteration (``deapull.paper``).

The same problem for every solver: f_a (kind f-coulomb, ``--model`` or trained here on
C3..C7, validated on C8, ``--epochs``) in the task's scaled units
(:class:`deapull.control.dynamics.CoinDynamics`, the true φ of C1), the scaled cost without a
final term (mpc.pytorch has none: the last state is not costed), the box |ΔV| ≤ ΔV_max
(ν ∈ [−1, 1]), the same warm start (the full ramp) and the same number of iterations
(mpc.pytorch is made to run all of them: ``eps = 0`` and no early stop). The plans start
from ``--solves`` states of the coin sliding toward the target (a ramp of ΔV_max per step
on the model, after the onset), where the MPC really solves (before the onset the policy
applies the ramp without solving).

Ours runs twice: compiled (:mod:`deapull.control.native`, the MPC's default; timed over
``--repeat`` passes of the states) and in eager torch (:func:`deapull.control.mpc.solve` on
:class:`~deapull.control.dynamics.CoinDynamics`, one pass).

mpc.pytorch (PyPI ``mpc``) pins numpy < 2 and torch: it is installed apart from the project
(``pip install --no-deps --target DIR mpc``, as ``make bench BENCH=control`` does) and imported
from ``--mpc-path``; without it the bench says so and times ours only. It runs in
AUTO_DIFF mode (what the paper ran: per-step autograd Jacobians through the torch model)
and in ANALYTIC mode given the fastest model we have: the compiled step and its analytic
Jacobians (through :func:`deapull.control.mpc.linearize`), so that what remains of its
time is its own.

Prints median and p95 ms per solve and the cost each reached (evaluated by the same
function on the model's rollout of each plan); writes JSON with ``--out``.
"""
from __future__ import annotations

import argparse
import logging
import math
import platform
import sys
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402
import torch  # noqa: E402

from deapull.control import mpc, native  # noqa: E402
from deapull.control.dynamics import X_UNIT_M, CoinDynamics, coin_cost  # noqa: E402
from deapull.io import write_json  # noqa: E402
from deapull.paper import MPC_HORIZON, MPC_LQR_ITERATIONS, MPC_S_PER_ITERATION  # noqa: E402
from deapull.surrogate import store  # noqa: E402
from deapull.surrogate.data import load_sweep  # noqa: E402
from deapull.surrogate.phi import Phi  # noqa: E402
from deapull.surrogate.rollout import OutOfRangeWarning  # noqa: E402
from deapull.surrogate.train import TrainConfig, train  # noqa: E402

PAPER_S = MPC_S_PER_ITERATION          # the paper's MPC: s per iteration (mpc.pytorch)
GOAL_MS = 5.0          # the goal: <= 5 ms per MPC iteration
GOAL_RATIO = 100.0     # the goal: >= 100x mpc.pytorch
DT, DV_MAX_V, V_MAX_V = 1e-3, 5.0, 400.0
TRAIN, VAL, PLANT = ("C3", "C4", "C5", "C6", "C7"), "C8", "C1"


def f_a(args):
    if args.model:
        model, _ = store.load(args.model)
        return model, f"loaded from {args.model}"
    data = Path(args.data)
    if not all((data / f"{s}.nc").is_file() for s in (*TRAIN, VAL, PLANT)):
        fallback = Path(__file__).resolve().parents[1] / "tests" / "data" / "sweep"
        print(f"note: {data} lacks C1..C8; training on the test-size sweep {fallback} instead")
        data = fallback
    sets = load_sweep(data, [*TRAIN, VAL, PLANT])
    start = time.perf_counter()
    result = train(TrainConfig(kind="f-coulomb", epochs=args.epochs), [sets[s] for s in TRAIN], sets[VAL])
    phi = result.model.phi_of(sets[PLANT])
    return result.model, (f"f-coulomb trained here on {','.join(TRAIN)} (val {VAL}) of {data}, {args.epochs} epochs, "
                          f"{time.perf_counter() - start:.0f} s; plant coin φ of {PLANT}: {phi.as_dict()}")


def start_states(dyn: CoinDynamics, count: int, target_m: float):
    """States ξ of the coin sliding under the full ramp, between its onset and the target
    (or 90 % of its reach at V_max when the target is beyond it)."""
    steps = int(math.ceil(V_MAX_V / DV_MAX_V))
    with torch.no_grad():
        xs = mpc.rollout(dyn, dyn.state(0.0, 0.0, 0.0), torch.ones(1, steps, 1, dtype=torch.float64))[0]
    x = xs[:, 0] * X_UNIT_M
    end = max(float(x.min()) * 0.9, target_m)
    sliding = torch.nonzero((x < -1e-6) & (x > end)).flatten()
    if len(sliding) < count:
        raise SystemExit(f"the model's coin slides for only {len(sliding)} ramp steps; cannot pick {count} states")
    pick = sliding[torch.linspace(0, len(sliding) - 1, count).round().long()]
    return xs[pick], end


def timed(fn, states):
    times, plans = [], []
    fn(states[0])       # warm-up
    for xi in states:
        start = time.perf_counter()
        plans.append(fn(xi))
        times.append(1e3 * (time.perf_counter() - start))
    return times, plans


def summary(name, times, costs, iterations):
    t = np.array(times)
    return {"solver": name, "median_ms": float(np.median(t)), "p95_ms": float(np.percentile(t, 95)),
            "median_ms_per_iteration": float(np.median(t)) / iterations, "mean_cost": float(np.mean(costs)),
            "costs": [float(c) for c in costs], "times_ms": t.tolist()}


def load_mpc_pytorch(path: str | None):
    """mpc.pytorch's module, or (None, reason)."""
    if path:
        sys.path.insert(0, str(Path(path).resolve()))
    try:
        from mpc import mpc as mpt
        return mpt, None
    except ImportError as err:
        return None, (f"mpc.pytorch is not importable ({err}); install it apart from the project with "
                      f"`.venv/bin/pip install --no-deps --target out/mpc_pytorch mpc` and pass --mpc-path "
                      f"out/mpc_pytorch (make bench BENCH=control does)")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", default="data", help="folder with C1..C8.nc (default data/; test sweep otherwise)")
    p.add_argument("--model", help="a trained f_a folder (skips training)")
    p.add_argument("--epochs", type=int, default=300, help="training epochs of f_a when trained here (300)")
    p.add_argument("--solves", type=int, default=5, help="MPC steps timed per solver (5)")
    p.add_argument("--horizon", type=int, default=MPC_HORIZON)
    p.add_argument("--iterations", type=int, default=MPC_LQR_ITERATIONS)
    p.add_argument("--repeat", type=int, default=20, help="times the C solver goes over the states (20)")
    p.add_argument("--target-mm", type=float, default=1.0, help="distance to the target (1 mm)")
    p.add_argument("--mpc-path", help="folder where mpc.pytorch is installed (pip --target)")
    p.add_argument("--skip-mpc-pytorch", action="store_true")
    p.add_argument("--out", help="folder for bench_control.json")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    warnings.simplefilter("ignore", OutOfRangeWarning)
    torch.set_num_threads(1)

    model, origin = f_a(args)
    phi = Phi(1.36e-3, 0.2, 0.5)    # C1's coin
    dyn = CoinDynamics(model, phi.to(dtype=torch.float64), DT, DV_MAX_V, V_MAX_V)
    states, reach_m = start_states(dyn, args.solves, -args.target_mm * 1e-3)
    target_m = -args.target_mm * 1e-3
    if reach_m > target_m:
        print(f"--target-mm {args.target_mm:g}: unreachable: the model's coin (C1's) gets to {reach_m * 1e3:.3f} mm "
              f"at most at {V_MAX_V:.0f} V; pass --target-mm {abs(reach_m) * 1e3 * 0.95:.3f} (or less) to time the "
              f"solvers on a target within reach (make bench BENCH=control BENCH_TARGET_MM=...)", file=sys.stderr)
        return 2
    full = coin_cost(target_m)
    cost = mpc.QuadCost(full.C, full.c)             # no final term, as mpc.pytorch
    T, iters = args.horizon, args.iterations
    ramp = torch.ones(1, T, 1, dtype=torch.float64)

    def evaluate(xi, u):
        with torch.no_grad():
            return float(mpc.total_cost(cost, mpc.rollout(dyn, xi.reshape(1, 3), u.reshape(1, T, 1)),
                                        u.reshape(1, T, 1)))

    rows = []
    fast = None
    if native.available(model):
        fast = native.NativeCoinDynamics(model, phi.to(dtype=torch.float64), DT, DV_MAX_V, V_MAX_V)

        def ours_native(xi):
            return fast.solve(cost, xi.reshape(1, 3), ramp, -1.0, 1.0, iterations=iters).u
        times, plans = timed(ours_native, list(states) * args.repeat)
        rows.append(summary("deapull box-iLQR (C)", times, [evaluate(x, u) for x, u in zip(states, plans)], iters))
    else:
        print("note: the native MPC is not available (no C compiler?); timing the torch path only")

    def ours(xi):
        return mpc.solve(dyn, cost, xi.reshape(1, 3), ramp, -1.0, 1.0, iterations=iters).u

    times, plans = timed(ours, states)
    rows.append(summary("deapull box-iLQR (eager torch)", times, [evaluate(x, u) for x, u in zip(states, plans)],
                        iters))
    skipped = None
    if not args.skip_mpc_pytorch:
        mpt, skipped = load_mpc_pytorch(args.mpc_path)
        if mpt is not None:
            class Dx(torch.nn.Module):
                def __init__(self, step):
                    super().__init__()
                    self.step = step

                def forward(self, x, u):
                    return self.step(x, u)

                def grad_input(self, x, u):
                    return mpc.linearize(self.step, x, u)
            C = cost.C.expand(T, 1, 4, 4).contiguous()
            c = cost.c.expand(T, 1, 4).contiguous()
            # AUTO_DIFF: autograd through the torch model, as the paper ran it; ANALYTIC: our
            # batched Jacobians, and the C step when it is available (the fastest model for them)
            modes = [("AUTO_DIFF", Dx(dyn), "")]
            modes.append(("ANALYTIC", Dx(fast), ", C step + Jacobians") if fast is not None else
                         ("ANALYTIC", Dx(dyn), ", torch step, batched autograd Jacobians"))
            for mode, dx, note in modes:
                def theirs(xi, mode=mode, dx=dx):
                    solver = mpt.MPC(3, 1, T, u_lower=-1.0, u_upper=1.0, u_init=ramp.transpose(0, 1).clone(),
                                     lqr_iter=iters, grad_method=getattr(mpt.GradMethods, mode), eps=0.0,
                                     not_improved_lim=iters + 1, exit_unconverged=False, detach_unconverged=False,
                                     backprop=False, verbose=-1, n_batch=1)
                    _, u, _ = solver(xi.reshape(1, 3), mpt.QuadCost(C, c), dx)
                    return u.detach().transpose(0, 1)
                times, plans = timed(theirs, states)
                rows.append(summary(f"mpc.pytorch {mode}{note}", times, [evaluate(x, u) for x, u in zip(states, plans)],
                                    iters))

    ours_ms = rows[0]["median_ms"]
    print(f"\nMPC step: horizon {T}, {iters} iterations, |ΔV| <= {DV_MAX_V} V per step, ramp warm start, "
          f"{args.solves} states sliding toward x^T = {target_m * 1e3:.3f} mm; f_a {origin}")
    print(f"{'solver':58s} {'median ms':>10s} {'p95 ms':>9s} {'ms/iter':>8s} {'mean cost':>11s} "
          f"{f'vs paper {PAPER_S:g} s':>15s} {'ours faster':>12s}")
    for r in rows:
        print(f"{r['solver']:58s} {r['median_ms']:10.1f} {r['p95_ms']:9.1f} {r['median_ms_per_iteration']:8.2f} "
              f"{r['mean_cost']:11.5f} {PAPER_S * 1e3 / r['median_ms']:14.1f}x {r['median_ms'] / ours_ms:11.1f}x")
    print(f"paper (mpc.pytorch, their machine): {PAPER_S * 1e3:.0f} ms per iteration")
    if skipped:
        print(f"mpc.pytorch NOT run: {skipped}")
    print(f"goal: <= {GOAL_MS} ms per MPC step: {'met' if ours_ms <= GOAL_MS else 'NOT met'} ({ours_ms:.1f} ms); "
          f">= {GOAL_RATIO:.0f}x mpc.pytorch: "
          + (", ".join(f"{r['solver']}: {r['median_ms'] / ours_ms:.1f}x" for r in rows[1:]) or "not measured"))
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        write_json(out / "bench_control.json",
                   {"rows": rows, "horizon": T, "iterations": iters, "target_m": target_m, "f_a": origin,
                    "paper_s": PAPER_S, "mpc_pytorch_skipped": skipped, "machine": platform.platform(),
                    "torch": torch.__version__, "threads": torch.get_num_threads()}, indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
