"""One online-inference update on an f-memory f_a, compiled against torch in the same run
(issue 24, item 4): ms per Levenberg–Marquardt update and per observed step, and how far the
two estimates are apart.

The inference (:class:`~deapull.control.inference.OnlineInference`, ``--infer-optimizer lm``,
``--phi-prior coins``) watches the f_a itself as the plant, with the coin of C3 (m_c 1.36 g,
μ_b 0.2, μ_t 0.55) under ``make control PRESET=fem``'s push (0.4 V per step, a pause of 40 steps every
200) and observation noise ``--noise`` (default 1e-4 m, the FEM goals' noise). For each buffer
length in ``--rows`` both engines observe the same record; then each takes ``--updates`` updates
(a batch of 256 and, for f-memory, the memory re-derived along the whole buffer every update:
``InferenceConfig.memory_refresh`` = 1). ``engine="torch"`` is autograd through the model and
the Python scan (what the f-memory f_a ran on before); ``engine="native"`` is
``native_mpc_memory.c`` (``deapull_memory_predict``, ``deapull_memory_scan``).

    python bench/bench_inference.py --model out/models/fa_mem        # make bench BENCH=inference
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from deapull.control.inference import COIN_PRIOR, InferenceConfig, OnlineInference
from deapull.surrogate import store
from deapull.surrogate.phi import Phi

F64 = torch.float64
DT = 1e-3
TRUTH = Phi(mass_kg=1.36069e-3, mu_b=0.2, mu_t=0.55)


def record(model, steps: int, noise: float, seed: int) -> list:
    """(x̃, V) of the plant (``model`` with the coin TRUTH) under the push, noisy."""
    m = model.double()
    rng = np.random.default_rng(seed)
    out, V = [(0.0, 0.0)], 0.0
    with torch.no_grad():
        s, memory = torch.zeros(1, 2, dtype=F64), None
        for k in range(steps):
            if k % 200 < 160:
                V = min(V + 0.4, 400.0)
            s, _, memory = m.step(s, torch.tensor([[V, DT]], dtype=F64), memory, TRUTH.to(dtype=F64))
            out.append((float(s[0, 0]) + noise * float(rng.standard_normal()), V))
    model.float()
    return out


def bench(model, rows: int, updates: int, noise: float, seed: int) -> dict:
    observed = record(model, rows, noise, seed)
    result = {"rows": rows}
    estimates = {}
    for engine in ("torch", "native"):
        config = InferenceConfig(optimizer="lm", engine=engine, prior=COIN_PRIOR,
                                 observation_std_m=max(noise, 1e-9), motion_threshold_m=3 * noise, seed=seed)
        inf = OnlineInference(model, config, DT)
        start = time.perf_counter()
        for x, V in observed:
            inf.observe(x, V)
        result[f"{engine}_observe_ms"] = 1e3 * (time.perf_counter() - start) / len(observed)
        inf.moved = True                   # time the updates themselves, whatever the record shows
        start = time.perf_counter()
        inf.update(updates)
        result[f"{engine}_update_ms"] = 1e3 * (time.perf_counter() - start) / updates
        estimates[engine] = inf.estimate()
    result["max_rel_diff"] = max(abs(estimates["native"][f] / estimates["torch"][f] - 1) for f in estimates["torch"])
    result["estimate"] = estimates["native"]
    return result


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", required=True, help="an f_a model folder (f-memory, or f-coulomb for comparison)")
    p.add_argument("--rows", default="250,1000,3000", help="buffer lengths, comma-separated (default 250,1000,3000)")
    p.add_argument("--updates", type=int, default=10, help="updates timed per engine (default 10)")
    p.add_argument("--noise", type=float, default=1e-4, help="observation noise std (m; default 1e-4)")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args()
    torch.set_num_threads(1)
    model, _ = store.load(args.model)
    print(f"{model.kind} f_a {args.model}: LM updates (batch 256, prior coins), noise {args.noise:g} m, one thread")
    print(f"{'rows':>6} {'torch ms/update':>16} {'native ms/update':>17} {'ratio':>7} "
          f"{'torch ms/obs':>13} {'native ms/obs':>14} {'ratio':>7} {'estimates apart':>16}")
    for rows in (int(r) for r in args.rows.split(",")):
        r = bench(model, rows, args.updates, args.noise, args.seed)
        print(f"{rows:>6} {r['torch_update_ms']:>16.2f} {r['native_update_ms']:>17.3f} "
              f"{r['torch_update_ms'] / r['native_update_ms']:>6.0f}x {r['torch_observe_ms']:>13.3f} "
              f"{r['native_observe_ms']:>14.4f} {r['torch_observe_ms'] / r['native_observe_ms']:>6.0f}x "
              f"{r['max_rel_diff']:>16.1e}")
    print("paper: Algorithm 2's inference update in torch, no figure given; before this, an f-memory f_a's "
          "update ran the torch engine")


if __name__ == "__main__":
    main()
