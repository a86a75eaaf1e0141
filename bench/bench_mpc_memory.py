"""One MPC plan on an f-memory f_a beside one on f-coulomb: wall time
of the compiled plan (``native_mpc_memory.c`` / ``native_mpc.c``) and of the torch plan
(:func:`deapull.control.mpc.solve` on :class:`~deapull.control.dynamics.CoinDynamics`), and how
far the two plans are apart.

The problem, for both kinds: the MPC's own solve (3 warm starts: half ramp, ramp, reverse
ramp; horizon 20, 20 iterations), from the state the compiled model reaches after 880 steps of
the 0.4 V per step ramp (the coin sliding at ~352 V), aiming 0.02 mm further; φ of C3
(m_c 1.36 g, μ_b 0.2, μ_t 0.55), Δt 1 ms, ΔV_max 0.4 V.

    python bench/bench_mpc_memory.py --fmem control/models/fa_mem --fcoulomb out/models/fa
"""
from __future__ import annotations

import argparse
import time

import torch

from deapull.control import mpc, native
from deapull.control.dynamics import CoinDynamics, coin_cost
from deapull.surrogate import store
from deapull.surrogate.phi import Phi

F64 = torch.float64


def bench(folder: str, repeat: int) -> dict:
    model, _ = store.load(folder)
    phi = Phi(mass_kg=1.36069e-3, mu_b=0.2, mu_t=0.55).to(dtype=F64)
    slow = CoinDynamics(model, phi, 1e-3, 0.4, 400.0)
    fast = native.native_dynamics(model, phi, 1e-3, 0.4, 400.0)
    with torch.no_grad():
        path = fast.rollout(fast.state(0.0, 0.0, 0.0), torch.ones(1, 900, 1, dtype=F64))[0]
    x0 = path[880:881].repeat(3, 1)
    cost = coin_cost(float(path[880, 0]) * 1e-3 - 0.02e-3, memory=slow.n - 3)
    ramp = torch.ones(1, 20, 1, dtype=F64)
    u0 = torch.cat([0.5 * ramp, ramp, -ramp])
    start = time.perf_counter()
    for _ in range(repeat):
        got = fast.solve(cost, x0, u0, -1.0, 1.0, iterations=20)
    native_ms = 1e3 * (time.perf_counter() - start) / repeat
    start = time.perf_counter()
    ref = mpc.solve(slow, cost, x0, u0, -1.0, 1.0, iterations=20)
    torch_ms = 1e3 * (time.perf_counter() - start)
    return {"kind": model.kind, "native_ms": native_ms, "torch_ms": torch_ms,
            "max_du": float((got.u - ref.u).abs().max()), "max_dx": float((got.x - ref.x).abs().max()),
            "max_dJ": float((got.history - ref.history).abs().max())}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--fmem", required=True, help="an f-memory model folder")
    p.add_argument("--fcoulomb", required=True, help="an f-coulomb model folder")
    p.add_argument("--repeat", type=int, default=50, help="compiled plans timed (default 50)")
    args = p.parse_args()
    torch.set_num_threads(1)
    for folder in (args.fmem, args.fcoulomb):
        r = bench(folder, args.repeat)
        print(f"{r['kind']}: one plan (3 rows, T = 20, 20 iterations) native {r['native_ms']:.2f} ms, torch "
              f"{r['torch_ms']:.0f} ms ({r['torch_ms'] / r['native_ms']:.0f}x); native - torch: max |ν| "
              f"{r['max_du']:.1e}, max |ξ| {r['max_dx']:.1e}, max |J| {r['max_dJ']:.1e}")


if __name__ == "__main__":
    main()
