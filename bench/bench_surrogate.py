"""Surrogate benchmark (``make bench BENCH=surrogate``): wall time of a 1 s rollout of each model,
beside the FEM's wall time and the paper's figures.

A 1 s rollout is 1000 steps of Δt = 1 ms under V = 400·t (the control stage's step),
simulating the test coin C3. Each model is timed at batch 1 on the CPU with both rollout
engines (native C and torch, one thread), and batched (``--batch`` rollouts at once) on
CUDA when a GPU is present (and on the CPU with ``--cpu-batch``). Timings are medians of
``--repeats`` runs after warm-up. Models come from ``--models`` (a folder with one
sub-folder per kind, e.g. an experiments set: ``out/experiments/set1``) or are trained
here briefly on C1/C2 (``--epochs``; the rollout cost does not depend on the weights).
The kinds with a TorchScript export (:mod:`deapull.surrogate.export`) are also timed as the
exported file, loaded back. Nothing is asserted: it prints a table and, with ``--out``, writes JSON.
"""
from __future__ import annotations

import argparse
import json
import logging
import platform
import statistics
import sys
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402
import torch  # noqa: E402

from deapull.surrogate import export, native, store  # noqa: E402
from deapull.surrogate.data import load_sweep  # noqa: E402
from deapull.paper import ABAQUS_S as PAPER_FEM_S, TABLE2 as PAPER  # noqa: E402
from deapull.surrogate.models import KINDS  # noqa: E402
from deapull.surrogate.rollout import OutOfRangeWarning, rollout  # noqa: E402
from deapull.surrogate.train import TrainConfig, train  # noqa: E402

TARGET_MS = 7.0  # the goal: a 1 s rollout of f in <= 7 ms on a CPU
STEPS = 1000


def one_second_actions(steps: int = STEPS) -> np.ndarray:
    """(steps, 2): V = 400·t at the end of each 1 ms step, and Δt."""
    dt = 1.0 / steps
    return np.stack([400.0 * dt * np.arange(1, steps + 1), np.full(steps, dt)], axis=1)


def median_ms(fn, repeats: int, sync=lambda: None) -> tuple[float, float]:
    """Median and minimum wall time of ``fn()`` in ms, after three warm-up calls."""
    for _ in range(3):
        fn()
    sync()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        sync()
        times.append(1e3 * (time.perf_counter() - start))
    return statistics.median(times), min(times)


def get_models(args, data) -> dict:
    if args.models:
        return {kind: store.load(Path(args.models) / kind)[0] for kind in args.kinds
                if (Path(args.models) / kind / store.META).is_file()}
    logging.info("training each model for %d epochs on C1/C2 (timing only)", args.epochs)
    return {kind: train(TrainConfig(kind=kind, epochs=args.epochs), [data["C1"]], data["C2"]).model
            for kind in args.kinds}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True, help="folder with C1.nc, C2.nc, C3.nc (and the rest of the sweep)")
    ap.add_argument("--models", default=None, help="folder with <kind>/model.json sub-folders (default: train)")
    ap.add_argument("--kinds", default=",".join(KINDS), help="model kinds to time")
    ap.add_argument("--epochs", type=int, default=20, help="training epochs when --models is not given")
    ap.add_argument("--repeats", type=int, default=30, help="timed runs per figure")
    ap.add_argument("--batch", type=int, default=10000, help="rollouts per batched CUDA run")
    ap.add_argument("--cpu-batch", type=int, default=0, help="also time this many rollouts at once on the CPU")
    ap.add_argument("--out", default=None, help="JSON file for the results")
    ap.add_argument("--scratch", default="out/bench_surrogate", help="folder for the exported TorchScript files")
    args = ap.parse_args(argv)
    args.kinds = [k for k in args.kinds.split(",") if k]
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    torch.set_num_threads(1)
    warnings.simplefilter("ignore", OutOfRangeWarning)

    sweep = sorted(Path(args.data).glob("C*.nc"))
    data = load_sweep(args.data, sorted({"C1", "C2", "C3"} | {p.stem for p in sweep}))
    fem_s = [d.wall_time_s for d in data.values() if np.isfinite(d.wall_time_s)]
    models = get_models(args, data)
    actions = one_second_actions()
    s0 = np.zeros(2)
    cuda = torch.cuda.is_available()
    rows = []
    for kind, model in models.items():
        phi = model.phi_of(data["C3"])      # the test coin
        row = {"model": kind}
        with torch.inference_mode():
            engines = ["native", "torch"] if native.supports(model) else ["torch"]
            for engine in engines:
                row[f"cpu_b1_{engine}_ms"], row[f"cpu_b1_{engine}_min_ms"] = median_ms(
                    lambda: rollout(model, phi, s0, actions, engine=engine), args.repeats)
            if export.supports(model):
                path = export.export(model, Path(args.scratch) / f"{kind}.ts")
                module, _ = export.load(path)
                st, at = torch.as_tensor(s0), torch.as_tensor(actions)
                pt = torch.tensor([phi.value("mass_kg"), phi.value("mu_b"), phi.value("mu_t")], dtype=torch.float64)
                row["cpu_b1_torchscript_ms"], row["cpu_b1_torchscript_min_ms"] = median_ms(
                    lambda: module(st, at, pt), args.repeats)
            if args.cpu_batch:
                s0b, ab = np.zeros((args.cpu_batch, 2)), np.tile(actions, (args.cpu_batch, 1, 1))
                total, _ = median_ms(lambda: rollout(model, phi, s0b, ab, engine="torch"), 3)
                row["cpu_batch"], row["cpu_batch_total_ms"] = args.cpu_batch, total
                row["cpu_batch_per_rollout_ms"] = total / args.cpu_batch
            if cuda:
                gpu = model.to("cuda")
                s0g = torch.zeros(args.batch, 2, device="cuda")
                ag = torch.as_tensor(actions, dtype=torch.float32, device="cuda").expand(args.batch, -1, -1)
                total, _ = median_ms(lambda: rollout(gpu, phi, s0g, ag, engine="torch"), 3, torch.cuda.synchronize)
                row["cuda_batch"], row["cuda_batch_total_ms"] = args.batch, total
                row["cuda_batch_per_rollout_ms"] = total / args.batch
                model.cpu()
        rows.append(row)

    cpu = next((line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                if line.startswith("model name")), platform.processor()) if Path("/proc/cpuinfo").exists() else ""
    print(f"1 s rollout ({STEPS} steps of 1 ms), test coin C3, CPU: {cpu}, torch {torch.__version__}, "
          f"1 thread{', CUDA: ' + torch.cuda.get_device_name() if cuda else ', no CUDA device'}")
    head = ["model", "CPU b=1 native [ms]", "CPU b=1 torch [ms]", "CPU b=1 TorchScript [ms]"]
    if args.cpu_batch:
        head.append(f"CPU b={args.cpu_batch} [ms/rollout]")
    if cuda:
        head.append(f"CUDA b={args.batch} [ms/rollout]")
    head += ["paper [ms]", "target [ms]"]
    lines = [head]
    for row in rows:
        cells = [row["model"], f"{row.get('cpu_b1_native_ms', float('nan')):.2f}", f"{row['cpu_b1_torch_ms']:.1f}",
                 f"{row['cpu_b1_torchscript_ms']:.1f}" if "cpu_b1_torchscript_ms" in row else "-"]
        if args.cpu_batch:
            cells.append(f"{row['cpu_batch_per_rollout_ms']:.3f}")
        if cuda:
            cells.append(f"{row['cuda_batch_per_rollout_ms']:.4f}")
        physics = KINDS[row["model"]].physics
        paper = PAPER["rollout_ms"].get("f" if physics else row["model"])
        cells += [f"{paper:.0f}" if paper else "-", f"{TARGET_MS:.0f}" if physics else "-"]
        lines.append(cells)
    widths = [max(len(line[i]) for line in lines) for i in range(len(head))]
    print("\n".join("  ".join(c.rjust(w) for c, w in zip(line, widths)) for line in lines))
    fem = statistics.mean(fem_s) if fem_s else float("nan")
    print(f"FEM (this project, {len(fem_s)} setups of {args.data}): {fem:.1f} s per 1 s run on average; "
          f"paper: ABAQUS {PAPER_FEM_S:.0f} s, "
          + ", ".join(f"{k if k == 'f' else k.upper()} {v:.0f} ms" for k, v in PAPER["rollout_ms"].items()))
    for row in rows:
        best = row.get("cpu_b1_native_ms", row["cpu_b1_torch_ms"])
        print(f"  {row['model']:9s} {fem * 1e3 / best:10.0f}x faster than the FEM at batch 1")
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps({"rows": rows, "fem_wall_time_s": fem, "cpu": cpu, "steps": STEPS,
                                              "torch": torch.__version__, "cuda": cuda,
                                              "paper_rollout_ms": PAPER["rollout_ms"], "paper_fem_s": PAPER_FEM_S,
                                              "target_ms": TARGET_MS}, indent=2) + "\n")
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
