"""BLAS benchmark (``make bench BENCH=blas``): what the BLAS under PETSc's direct solvers costs the FEM.

MUMPS and UMFPACK spend their factorisations in dense BLAS kernels, and Debian links PETSc
against whatever ``libblas.so.3`` the alternatives system points at: the reference (netlib)
BLAS of ``libblas3`` unless an optimised one is installed. ``scripts/setup.sh`` installs
OpenBLAS (``libopenblas0-serial``: one thread, so ``mpirun`` ranks do not oversubscribe).

Measured in this run, each in a child process:

* **system** — the BLAS the dynamic linker finds (after ``make setup``: OpenBLAS);
* **reference** — the same, with ``LD_LIBRARY_PATH`` set to the reference BLAS and LAPACK
  folders of ``libblas3`` / ``liblapack3``, which take precedence over the alternative.

Each child meshes coin_pull C3 at ``--fidelity`` (default: the scene file as written, the datasets'),
assembles the Newton Jacobian at rest and times its numeric factorisation (the median of
``--repeats``, after a first factorisation that also does the symbolic analysis) with MUMPS
and UMFPACK, and one back-solve. The child reports which BLAS library it loaded (from
``/proc/self/maps``), so a row never claims a library it did not use. ``--solve`` also runs the
whole 1 s ramp of C3 under both (one after the other, minutes each at the data fidelity): the wall times,
and the Newton iterations and travel, which must agree. Nothing is asserted: it prints and
writes ``bench_blas.json``.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from deapull.io import write_json
from deapull.paper import ABAQUS_S

#: Debian's folders of the reference BLAS and LAPACK (packages libblas3, liblapack3), which
#: the alternatives system falls back to when no optimised BLAS is installed
REFERENCE_DIRS = tuple(f"/usr/lib/{arch}/{lib}" for arch in ("x86_64-linux-gnu", "aarch64-linux-gnu")
                       for lib in ("blas", "lapack"))
PACKAGES = ("mumps", "umfpack")


def loaded_blas() -> list[str]:
    """The BLAS and LAPACK shared objects mapped into this process."""
    names = set()
    for line in Path("/proc/self/maps").read_text().splitlines():
        fields = line.split()
        path = fields[-1] if len(fields) >= 6 else ""
        # the system's (PETSc's, numpy's); a wheel's bundled copy (site-packages) is not PETSc's
        if Path(path).name.startswith(("libblas", "liblapack", "libopenblas")) and "-packages" not in path:
            names.add(os.path.realpath(path))
    return sorted(names)


def child(fidelity: str, repeats: int, mesh_dir: str) -> dict:
    """Factorisation times of the C3 Jacobian in this process (its BLAS)."""
    from petsc4py import PETSc

    from deapull import scene as scenes
    from deapull.fem_solver import compat
    from deapull.fem_solver.simulation import Simulation

    overrides = scenes.fidelity_overrides("coin_pull", fidelity) if fidelity else ()
    sim = Simulation.from_scene(scenes.load("coin_pull", setup="C3", overrides=overrides), mesh_dir=mesh_dir)
    p = sim.problem()
    A = p.A
    start = time.perf_counter()
    compat.assemble_jacobian(A, p.J_form, p.bcs)
    out = {"dofs": p.num_dofs(), "nonzeros": int(A.getInfo()["nz_used"]),
           "jacobian_assembly_s": time.perf_counter() - start, "blas": loaded_blas()}
    b = A.createVecLeft()
    b.set(1.0)
    x = b.duplicate()
    for package in PACKAGES:
        ksp = PETSc.KSP().create()
        ksp.setType("preonly")
        pc = ksp.getPC()
        pc.setType("lu")
        pc.setFactorSolverType(package)
        ksp.setOperators(A)
        start = time.perf_counter()
        ksp.setUp()                                   # symbolic + numeric
        first = time.perf_counter() - start
        times = []
        for _ in range(repeats):
            compat.assemble_jacobian(A, p.J_form, p.bcs)   # new values, as in a Newton iteration
            ksp.setOperators(A)                            # the next setUp refactorises (numeric only)
            start = time.perf_counter()
            ksp.setUp()
            times.append(time.perf_counter() - start)
        start = time.perf_counter()
        ksp.solve(b, x)
        out[package] = {"first_factorisation_s": first, "factorisation_s": float(np.median(times)),
                        "back_solve_s": time.perf_counter() - start}
        ksp.destroy()
    return out


def reference_env() -> dict | None:
    dirs = [d for d in REFERENCE_DIRS if Path(d, "libblas.so.3").exists() or Path(d, "liblapack.so.3").exists()]
    if not dirs:
        return None
    env = dict(os.environ)
    env["LD_LIBRARY_PATH"] = ":".join(dirs + [p for p in env.get("LD_LIBRARY_PATH", "").split(":") if p])
    return env


def run_child(env, fidelity: str, repeats: int, mesh_dir: Path) -> dict:
    cmd = [sys.executable, __file__, "--child", "--fidelity", fidelity, "--repeats", str(repeats),
           "--mesh-dir", str(mesh_dir)]
    proc = subprocess.run(cmd, env=env, check=True, capture_output=True, text=True)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def run_solve(env, fidelity: str, out: Path) -> dict:
    from deapull import dataset
    cmd = [sys.executable, "-m", "deapull.workflows", "solve", "--scene", "coin_pull", "--setup", "C3",
           "--out", str(out)] + (["--fidelity", fidelity] if fidelity else [])
    subprocess.run(cmd, env=env, check=True)
    r = dataset.read(out / "C3.nc", ("x", "newton_iterations"))
    return {"wall_s": r.number("wall_time_total_s"), "newton_its": int(np.sum(r.columns["newton_iterations"])),
            "travel_mm": 1e3 * float(np.max(np.abs(r.columns["x"])))}


def short(paths: list[str]) -> str:
    """The folders of the loaded libraries: ``openblas-serial``, or ``blas, lapack`` (the reference)."""
    return ", ".join(sorted({Path(p).parent.name for p in paths})) or "none found"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/bench_blas")
    ap.add_argument("--fidelity", default="",
                    help="a [fidelities.NAME] of coin_pull (default '': the file as written, the datasets')")
    ap.add_argument("--repeats", type=int, default=5, help="numeric factorisations timed per package")
    ap.add_argument("--solve", action="store_true", help="also the whole C3 ramp under both BLAS")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--mesh-dir", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    out = Path(args.out)
    if args.child:
        print(json.dumps(child(args.fidelity, args.repeats, args.mesh_dir)))
        return 0
    if args.repeats < 1:
        ap.error(f"--repeats = {args.repeats}: must be >= 1")
    ref_env = reference_env()
    res = {"fidelity": args.fidelity or "the scene file", "system": run_child(None, args.fidelity, args.repeats,
                                                                               out / "mesh")}
    if ref_env is None:
        print("no reference BLAS folder found (" + ", ".join(REFERENCE_DIRS) + "): timing the system BLAS only")
    else:
        res["reference"] = run_child(ref_env, args.fidelity, args.repeats, out / "mesh")
    if args.solve:
        res["system"]["solve"] = run_solve(None, args.fidelity, out / "solve_system")
        if ref_env is not None:
            res["reference"]["solve"] = run_solve(ref_env, args.fidelity, out / "solve_reference")
    write_json(out / "bench_blas.json", res, indent=2)

    sysr = res["system"]
    print(f"\nBLAS benchmark: coin_pull C3 at {res['fidelity']}, {sysr['dofs']} dofs, "
          f"{sysr['nonzeros']:,} nonzeros in the Jacobian; one core; median of {args.repeats} numeric factorisations")
    rows = [("system", sysr)] + ([("reference", res["reference"])] if "reference" in res else [])
    print(f"{'':10s} {'BLAS loaded (folder)':28s} " + " ".join(f"{p + ' factor s':>15s}" for p in PACKAGES)
          + f" {'J assembly s':>13s}")
    for label, r in rows:
        print(f"{label:10s} {short(r['blas'])[:28]:28s} "
              + " ".join(f"{r[p]['factorisation_s']:15.4f}" for p in PACKAGES) + f" {r['jacobian_assembly_s']:13.4f}")
    if "reference" in res:
        ref = res["reference"]
        print("factorisation, reference / system BLAS, same run: "
              + ", ".join(f"{p} {ref[p]['factorisation_s'] / sysr[p]['factorisation_s']:.2f}x" for p in PACKAGES))
        if sysr["blas"] == ref["blas"]:
            print("both children loaded the same BLAS: install an optimised one (make setup installs "
                  "libopenblas0-serial)")
    if args.solve:
        for label, r in rows:
            s = r["solve"]
            print(f"C3 ramp, {label:9s}: {s['wall_s']:7.1f} s ({ABAQUS_S / s['wall_s']:.2f}x the paper's ABAQUS "
                  f"{ABAQUS_S:g} s), {s['newton_its']} Newton iterations, travel {s['travel_mm']:.5f} mm")
        if "reference" in res:
            print(f"whole ramp, reference / system BLAS, same run: "
                  f"{res['reference']['solve']['wall_s'] / sysr['solve']['wall_s']:.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
