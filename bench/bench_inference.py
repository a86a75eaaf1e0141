"""One online-inference update on an f-memory f_a, compiled against torch in the same run: ms per
Levenberg–Marquardt update and per observed step, and how far the
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

    python bench/bench_inference.py --model control/models/fa_mem        # make bench BENCH=inference

``--calibration N`` measures instead what the inference can tell (goal G6): over N seeds of the
noise, each seed's plant f_a with a coin of ``--truths`` (the design's C1..C8 in turn,
:func:`design_coins`, or coins drawn from the family prior, :func:`family_draws`), the same push for
``--steps`` steps (default 2,500) with one Levenberg–Marquardt update every 10 steps (the MPC's
``inference.every``), under each of ``--priors`` and ``--losses``; then, per field, the median
relative error of the estimate and how often the posterior's 68 % interval
(:func:`~deapull.control.inference.posterior`: the profile likelihood for the rollout loss, Laplace
for the one-step loss; Laplace beside it) covers the truth, and the relative error of the onset
voltage (where the estimate's f_a first moves the coin 1 µm under the push, against the truth's).
The design's coins sit at ±1 std of the family prior, so where the data leave a field to the prior
(m_c) its interval's edge falls on them and their coverage is a coin toss; drawn from the prior,
the truths test the interval as a Bayesian one.

    python bench/bench_inference.py --model control/models/fa_push --calibration 20 --noise 1e-6
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np
import torch

from deapull.control.inference import (COIN_PRIOR, InferenceConfig, OnlineInference, design_coins, named_prior,
                                      posterior)
from deapull.control.rollout_inference import RolloutInference
from deapull.io import write_json
from deapull.surrogate import store
from deapull.surrogate.phi import Phi

F64 = torch.float64
DT = 1e-3
TRUTH = Phi(mass_kg=1.36069e-3, mu_b=0.2, mu_t=0.55)


def record(model, steps: int, noise: float, seed: int, phi: Phi = TRUTH) -> list:
    """(x̃, V) of the plant (``model`` with the coin ``phi``, default TRUTH) under the push, noisy."""
    m = model.double()
    rng = np.random.default_rng(seed)
    out, V = [(0.0, 0.0)], 0.0
    with torch.no_grad():
        s, memory = torch.zeros(1, 2, dtype=F64), None
        for k in range(steps):
            if k % 200 < 160:
                V = min(V + 0.4, 400.0)
            s, _, memory = m.step(s, torch.tensor([[V, DT]], dtype=F64), memory, phi.to(dtype=F64))
            out.append((float(s[0, 0]) + noise * float(rng.standard_normal()), V))
    model.float()
    return out


def onset_V(model, phi: Phi, steps: int, moved_m: float = 1e-6) -> float:
    """The push's voltage when ``model`` with the coin ``phi`` has first moved it ``moved_m``."""
    for x, V in record(model, steps, 0.0, 0, phi):
        if abs(x) > moved_m:
            return V
    return float("nan")


def family_draws(prior: dict, seeds: int) -> list[Phi]:
    """``seeds`` coins drawn from the log-normal ``prior`` (seed k from default_rng(1000 + k)): the truths
    of a simulation-based calibration, where a Bayesian interval's coverage is its stated level."""
    draws = []
    for seed in range(seeds):
        rng = np.random.default_rng(1000 + seed)
        draws.append(Phi(**{f: median * float(np.exp(std * rng.standard_normal())) for f, (median, std) in prior.items()}))
    return draws


def calibration(model, seeds: int, steps: int, noise: float, prior_name: str, loss: str = "rollout",
                truths: str = "design") -> dict:
    """Estimates, 68 % intervals and onset voltages over ``seeds`` noise seeds (module docstring). The
    truths are the design's coins C1..C8 in turn (``design``), or coins drawn from the family prior
    (``family``, :func:`family_draws`), whichever prior the inference states."""
    prior = named_prior(prior_name)
    if truths == "family":
        coins = family_draws(named_prior("family"), seeds)
    else:
        coins = [list(design_coins().values())[seed % 8] for seed in range(seeds)]
    rows = []
    for seed in range(seeds):
        coin = coins[seed]
        truth_onset = onset_V(model, coin, steps)
        config = InferenceConfig(optimizer="lm", prior=prior, observation_std_m=max(noise, 1e-9),
                                 motion_threshold_m=3 * noise, seed=seed)
        if loss == "rollout":
            inf = RolloutInference(model, config, DT, dv_max_V=5.0, v_max_V=400.0, every=10)
        else:
            inf = OnlineInference(model, config, DT)
        for k, (x, V) in enumerate(record(model, steps, noise, seed, coin)):
            inf.observe(x, V)
            if k % 10 == 0:
                inf.update(1)
        laplace, post = posterior(inf, noise, profile=False), posterior(inf, noise)
        row = {"seed": seed, "onset_error": onset_V(model, inf.phi, steps) / truth_onset - 1}
        for f, p in post.items():
            truth = coin.value(f)
            row[f] = {"error": p["estimate"] / truth - 1, "covered": p["lo"] <= truth <= p["hi"],
                      "covered_laplace": laplace[f]["lo"] <= truth <= laplace[f]["hi"], "std_log": p["std_log"],
                      "method": p["method"]}
        rows.append(row)
    fields = list(post)
    return {"prior": prior_name, "loss": loss, "truths": truths, "noise_m": noise, "steps": steps, "seeds": seeds,
            "interval": rows[0][fields[0]]["method"],
            "onset_abs_error_median": float(np.median([abs(r["onset_error"]) for r in rows])),
            "onset_abs_error_max": float(np.max([abs(r["onset_error"]) for r in rows])),
            **{f: {"abs_error_median": float(np.median([abs(r[f]["error"]) for r in rows])),
                   "coverage_68": float(np.mean([r[f]["covered"] for r in rows])),
                   "coverage_68_laplace": float(np.mean([r[f]["covered_laplace"] for r in rows])),
                   "std_log_median": float(np.median([r[f]["std_log"] for r in rows]))} for f in fields}}


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
    p.add_argument("--calibration", type=int, default=0, help="seeds of the calibration study (0: time instead)")
    p.add_argument("--steps", type=int, default=2500, help="steps of the calibration's push (2500)")
    p.add_argument("--priors", default="family,coins", help="priors of the calibration (family,coins)")
    p.add_argument("--out", default="", help="with --calibration: also write the results as JSON to this file "
                   "(make bench BENCH=inference: bench/reference/inference_calibration.json)")
    p.add_argument("--truths", default="design,family",
                   help="the calibration's true coins: design (C1..C8 in turn), family (drawn from the family prior)")
    p.add_argument("--losses", default="rollout,step",
                   help="the inference's losses in the calibration: rollout (output error), step (the paper's)")
    args = p.parse_args()
    torch.set_num_threads(1)
    model, _ = store.load(args.model)
    if args.calibration:
        unknown = [t for t in args.truths.split(",") if t not in ("design", "family")]
        if unknown:
            p.error(f"--truths {','.join(unknown)}: choose from design, family")
        print(f"{model.kind} f_a {args.model} as the plant, the coins of --truths {args.truths}, push of {args.steps} steps, "
              f"noise {args.noise:g} m, {args.calibration} seeds; goal (G6): 68 % intervals cover the truth 58-78 % of the seeds, "
              f"mu_b and the onset within 10 %")
        results = []
        for loss, name, truths in ((loss, name, truths) for loss in args.losses.split(",")
                                   for name in args.priors.split(",") for truths in args.truths.split(",")):
            r = calibration(model, args.calibration, args.steps, args.noise, name, loss, truths)
            results.append(r)
            print(f"loss {loss}, prior {name}, truths {truths} ({r['interval']} intervals): onset |error| median "
                  f"{100 * r['onset_abs_error_median']:.2f} %, "
                  f"max {100 * r['onset_abs_error_max']:.2f} %")
            for f in ("mass_kg", "mu_b", "mu_t"):
                if f in r:
                    print(f"  {f:8s} |error| median {100 * r[f]['abs_error_median']:6.2f} %, 68 % interval covers "
                          f"{100 * r[f]['coverage_68']:5.1f} % of seeds (Laplace {100 * r[f]['coverage_68_laplace']:5.1f} %), "
                          f"posterior std of log "
                          f"{r[f]['std_log_median']:.3g}")
        if args.out:
            write_json(args.out, {"schema": 1, "model": args.model, "kind": model.kind, "noise_m": args.noise,
                                  "steps": args.steps, "seeds": args.calibration, "runs": results,
                                  "command": "python bench/bench_inference.py " + " ".join(sys.argv[1:])}, indent=2)
        return
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
