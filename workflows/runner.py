"""The one resumable MPI case runner of the studies: sweep, fidelity ladder, stability suite.

A study is a list of :class:`Case` s (a scene, a setup and the ``--set`` overrides that make
the case). ``mpirun -n N deapull <study>`` splits the ranks into N / K groups of K ranks
(``ranks_per_case``, default 1: at these mesh sizes one rank per case is fastest); each group,
when it is free, takes the next case that no group has taken (:class:`Claims`: a file created
exclusively per case), so one long case does not hold back the cases dealt behind it. Each
finished case leaves one JSON result
``<out>/cases/<name>.json``, written atomically, so an interrupted study resumes where it
stopped and a file that exists is whole. A case whose scene fails validation becomes a
``rejected`` row without solving; a solve that fails after its cut-backs becomes a
``failed`` row with PETSc's reason (and its accepted steps as ``partial.nc``); a crash is
an ``error`` row — never the end of the study — and is solved again when the study resumes.

Two MPI details are handled here once: PETSc is initialised on every rank before the
groups split (its initialisation is collective on COMM_WORLD, and a rank with no case
left would otherwise leave the solving ranks waiting forever), and a rank whose share is
done waits in a sleeping barrier (Open MPI's blocking one polls a core at full speed).
Only rank 0 shows progress.
"""
from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import shutil
import socket
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

import numpy as np
from tqdm import tqdm

from deapull import dataset, scene as scenes
from deapull.errors import InputError
from deapull.io import write_json

log = logging.getLogger(__name__)

#: seconds between checks of a pending barrier
POLL_S = 0.05


# --- MPI -------------------------------------------------------------------------------

def idle_barrier(comm, poll_s: float = POLL_S) -> None:
    """A barrier that sleeps while it waits.

    Open MPI's blocking ``Barrier`` polls at full speed: a rank whose share of the cases is
    done would keep a core busy until the slowest group finishes, stealing it from the
    solves still running when the ranks outnumber the free cores. This one posts a
    non-blocking barrier and tests it every ``poll_s`` seconds.
    """
    request = comm.Ibarrier()
    while not request.Test():
        time.sleep(poll_s)


def initialise_petsc(comm) -> None:
    """Import dolfinx (and so initialise PETSc) on every rank before the groups split."""
    import dolfinx.fem.petsc  # noqa: F401  # lazy: the point of the call; importing the runner loads no dolfinx
    comm.Barrier()


class Claims:
    """Which group takes which case: a dynamic schedule over a study's rank groups.

    Each case is taken by the first group whose root creates ``<out>/.claims-<run>/<name>``
    (``O_CREAT | O_EXCL``: exactly one creator wins, on one machine or on a shared file
    system, which the results in ``<out>/cases`` already need). ``<run>`` is drawn on rank 0
    for this call of the runner, so a claim left by a run that was killed never blocks a
    later one, and two studies run into one folder do not see each other's claims (each
    solves what was missing when it started, as before). Rank 0 removes the folder when the
    study ends. Each folder names its owner (``OWNER``: the host and the process id of rank 0);
    a new run removes the folders of this host whose owner is no longer running (a run killed
    with -9 leaves its folder behind).
    """

    OWNER = ".owner"

    def __init__(self, out_dir: Path, comm):
        token = comm.bcast(uuid.uuid4().hex[:12] if comm.rank == 0 else None, root=0)
        self.folder = Path(out_dir) / f".claims-{token}"
        if comm.rank == 0:
            remove_dead_claims(Path(out_dir))
            self.folder.mkdir(parents=True, exist_ok=True)
            (self.folder / self.OWNER).write_text(f"{socket.gethostname()} {os.getpid()}\n")
        comm.Barrier()

    def take(self, name: str) -> bool:
        """Claim case ``name`` for the caller's group; False when another group has it."""
        try:
            os.close(os.open(self.folder / name, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
        except FileExistsError:
            return False
        return True

    def cases(self, todo: list, group) -> Iterator:
        """Yield, on every rank of ``group``, the cases its root claims, in ``todo``'s order,
        until none is left (the root claims; the group follows by broadcast)."""
        i = 0
        while True:
            if group.rank == 0:
                while i < len(todo) and not self.take(todo[i].name):
                    i += 1
            i = group.bcast(i, root=0)
            if i >= len(todo):
                return
            yield todo[i]
            i += 1

    def remove(self) -> None:
        shutil.rmtree(self.folder, ignore_errors=True)


def _running(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:     # someone else's process: running
        return True
    return True


def remove_dead_claims(out_dir: Path) -> list[Path]:
    """Remove the ``.claims-*`` folders under ``out_dir`` whose owner ran on this host and has
    stopped (or that name no owner, from a run killed before it wrote one); return them."""
    host, gone = socket.gethostname(), []
    for folder in Path(out_dir).glob(".claims-*"):
        try:
            owner_host, pid = (folder / Claims.OWNER).read_text().split()
            dead = owner_host == host and not _running(int(pid))
        except (OSError, ValueError):
            dead = time.time() - folder.stat().st_mtime > 60     # no owner yet: not a starting run's
        if dead:
            shutil.rmtree(folder, ignore_errors=True)
            gone.append(folder)
    if gone:
        log.info("removed the claims of stopped runs: %s", ", ".join(g.name for g in gone))
    return gone


# --- cases and their results -------------------------------------------------------------

@dataclass(frozen=True)
class Case:
    """One run of a study: a scene, a setup and the overrides that make it this case."""
    name: str
    scene: str
    setup: str | None
    overrides: tuple[str, ...]
    description: str
    meta: dict = field(default_factory=dict, compare=False)   # copied into the case's row


def case_dir(out_dir: Path, name: str) -> Path:
    return Path(out_dir) / "cases" / name


def result_path(out_dir: Path, name: str) -> Path:
    return Path(out_dir) / "cases" / f"{name}.json"


def scene_digest(scene) -> str:
    """A short digest of a resolved scene (its TOML): a stored result is reused only for the
    same scene, so a changed scene file or default re-solves the case instead of resuming."""
    return hashlib.sha256(scene.to_toml().encode()).hexdigest()[:16]


def load_result(out_dir: Path, case: Case, scene=None) -> dict | None:
    """The stored result of ``case``, or None when absent, unreadable or made for other inputs
    (other scene, setup or overrides; given the resolved ``scene``, another resolved scene)."""
    path = result_path(out_dir, case.name)
    try:
        result = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    same = (result.get("scene") == case.scene and result.get("setup") == (case.setup or "")
            and result.get("overrides") == list(case.overrides)
            and (scene is None or result.get("scene_digest") == scene_digest(scene)))
    return result if same else None


def base_result(case: Case, scene=None) -> dict:
    digest = {} if scene is None else {"scene_digest": scene_digest(scene)}
    return {"case": case.name, "description": case.description, "scene": case.scene, "setup": case.setup or "",
            "overrides": list(case.overrides), **digest, **case.meta}


# --- what a solved case reports ------------------------------------------------------------

def run_stats(cols: dict) -> dict:
    """Solver diagnostics of one run from its step columns (a dataset or partial records)."""
    n = len(cols["t"])
    if n == 0:
        return {"steps": 0}
    newton = np.asarray(cols["newton_iterations"])
    dt = np.asarray(cols["dt"])[1:]
    tip = np.asarray(cols["tip_uy"]) - cols["tip_uy"][0]
    touching = np.asarray(cols["n_contact"])
    touching = touching[touching > 0]
    return {
        "steps": n,
        "newton_iterations": int(newton.sum()),
        "max_newton_per_step": int(newton.max()),
        "cutbacks": int(np.sum(cols["cutbacks"])),
        "min_dt_s": float(dt.min()) if dt.size else math.nan,
        "max_dt_s": float(dt.max()) if dt.size else math.nan,
        "max_penetration_mm": float(np.max(cols["penetration_m"])) * 1e3,
        # the fewest DEA-obstacle contact points of a step that touches (NaN: it never touches)
        "min_contact_points": float(touching.min()) if touching.size else math.nan,
        "max_table_penetration_um": float(np.max(cols["table_penetration_m"])) * 1e6,
        "max_force_residual_N": float(np.max(cols["force_balance_residual_N"])),
        "travel_mm": float(np.max(np.abs(cols["x"]))) * 1e3,
        "solve_s": float(np.sum(cols["wall_time_s"])),
        "max_Fy_mN": float(np.max(cols["Fy"])) * 1e3,
        "max_tip_deflection_mm": float(np.max(np.abs(tip))) * 1e3,
        "last_t_s": float(cols["t"][-1]),
        "last_V": float(cols["V"][-1]),
        **instability_indicators(cols),
    }


def instability_indicators(cols: dict, from_fraction: float = 0.1) -> dict:
    """Signs of an approaching limit point (pull-in) in the accepted steps.

    ``tip_log_slope_max``: the largest d ln|Δtip| / d ln V between consecutive accepted
    steps with V ≥ ``from_fraction`` × the last voltage (Δtip: the free-end displacement
    since t = 0, as a vector): 2 for the small-strain V² law, larger as the actuator
    softens toward pull-in. ``dV_collapse``: the median accepted voltage increment over the
    last one — of order 1 for a smooth ramp, ≫ 1 when the cut-backs can no longer advance
    the voltage (the step size collapses at the limit point).
    """
    V = np.asarray(cols["V"], dtype=float)
    tip = np.stack([np.asarray(cols[k], dtype=float) for k in ("tip_ux", "tip_uy", "tip_uz")])
    d = np.linalg.norm(tip - tip[:, :1], axis=0)
    use = np.flatnonzero((V >= from_fraction * V[-1]) & (V > 0) & (d > 0))
    slope = math.nan
    if use.size >= 2:
        dv, dd = np.diff(np.log(V[use])), np.diff(np.log(d[use]))
        ok = dv > 0
        slope = float(np.max(dd[ok] / dv[ok])) if ok.any() else math.nan
    dV = np.diff(V)
    dV = dV[dV > 0]
    collapse = float(np.median(dV) / dV[-1]) if dV.size else math.nan
    return {"tip_log_slope_max": slope, "dV_collapse": collapse}


def _write_partial(records, scene, path: Path) -> None:
    """The accepted steps of a failed run, as a dataset marked incomplete (for diagnosis)."""
    from deapull.fem_solver.stepping import as_arrays  # lazy: dolfinx loads only when a solve runs
    ds = dataset.build(as_arrays(records), {"scene": scene.scene.name, "setup": scene.setup,
                                            "scene_toml": scene.to_toml()})
    ds.attrs["complete"] = 0
    dataset.write(ds, path)


def solve_case(case: Case, scene, out_dir: Path, comm, progress: bool, run_dir: Path | None = None,
               name: str | None = None) -> dict:
    """Solve one case into ``run_dir`` (default ``<out>/cases/<name>/``) as ``<name>.nc`` (default
    the setup's or scene's name); a failed or crashed solve becomes a result that says so (its
    accepted steps in ``<out>/cases/<name>/partial.nc``)."""
    # lazy (dolfinx): setting up a study and reading its results need no FEniCSx
    from deapull.fem_solver.run import solve_scene  # lazy: dolfinx
    from deapull.fem_solver.stepping import SolveFailed, as_arrays  # lazy: dolfinx
    run_dir = case_dir(out_dir, case.name) if run_dir is None else Path(run_dir)
    start = time.perf_counter()
    try:
        path = solve_scene(scene, run_dir, comm, progress=progress, name=name)
    except SolveFailed as err:
        wall = time.perf_counter() - start
        log.info("%s: %s", case.name, err)
        # the accepted steps, then the sub-steps of the failed step that were solved before
        # it was given up (they show how the solve approached the failure)
        steps = list(err.records) + list(getattr(err, "substeps", ()))
        if steps and comm.rank == 0:
            _write_partial(steps, scene, case_dir(out_dir, case.name) / "partial.nc")
        stats = run_stats(as_arrays(steps)) if steps else {"steps": 0}
        return {"status": "failed", "reason": err.reason, "fail_t_s": err.t, "fail_V": err.voltage,
                "last_good_step": err.last_good_step, "wall_s": wall, "ranks": comm.size, **stats}
    except Exception as err:   # a crash of one case is that case's row, not the study's end
        log.exception("%s: crashed", case.name)
        return {"status": "error", "reason": f"{type(err).__name__}: {err}", "steps": 0,
                "wall_s": time.perf_counter() - start, "ranks": comm.size}
    wall = time.perf_counter() - start
    run = dataset.read(path, variables=tuple(dataset.VARIABLES))
    # ranks: those that shared the mesh (times on different counts are not on one scale)
    return {"status": "ok", "reason": "", "wall_s": wall, "dofs": int(run.attrs["mesh_dofs"]), "ranks": comm.size,
            "dataset": str(path.relative_to(out_dir)), **run_stats(run.columns)}


def resolve_cases(cases) -> tuple[dict, dict]:
    """Validate every case's scene before any work: ({name: Scene}, {name: rejection message})."""
    resolved, rejected = {}, {}
    for case in cases:
        try:
            resolved[case.name] = scenes.load(case.scene, setup=case.setup, overrides=case.overrides)
        except scenes.SceneError as err:
            rejected[case.name] = str(err)
    return resolved, rejected


# --- the runner ------------------------------------------------------------------------------

Solver = Callable[[Case, object, Path, object, bool], dict]


def run_cases(cases, out_dir, comm, ranks_per_case: int = 1, desc: str = "cases",
              solve: Solver = solve_case, is_done: Callable[[Case, object], bool] | None = None) -> list[dict]:
    """Run a study's cases over rank groups; every rank returns the results in case order.

    Parameters
    ----------
    cases : list of Case
        Names must be unique.
    out_dir : path-like
    comm : mpi4py communicator (the study's ranks)
    ranks_per_case : int
        K: ranks that share one case's mesh; must divide ``comm.size``.
    desc : str
        Name of the progress bar and the log lines.
    solve : callable
        ``solve(case, scene, out_dir, group_comm, progress) -> dict`` (default
        :func:`solve_case`: the dataset under ``<out>/cases/<name>/``).
    is_done : callable, optional
        ``is_done(case, scene) -> bool``: whether the case's own output is there (the sweep:
        a complete dataset made with the resolved ``scene``). Given it, a stored "ok" result
        counts only with its output (a deleted dataset is solved again); a failed or
        rejected result still counts. An ``error`` result (a crash) never counts: it is solved
        again on resume. The stored result of a done case, if any, is returned.
    """
    out_dir = Path(out_dir)
    names = [c.name for c in cases]
    if len(set(names)) != len(names):
        raise InputError(f"case names must be unique: {names}")
    if ranks_per_case < 1 or comm.size % ranks_per_case:
        raise InputError(f"--ranks-per-case {ranks_per_case}: must divide the number of ranks ({comm.size})")
    resolved, rejected = resolve_cases(cases)

    def done(case):
        scene = resolved.get(case.name)
        stored = load_result(out_dir, case, scene)
        if stored is not None and stored.get("status") == "error":
            return False        # a crash is the code's, not the case's: solved again on resume
        if is_done is None:
            return stored is not None
        # a study with outputs of its own (the sweep's datasets): an "ok" result whose output
        # is gone is not done; a failed or rejected row stays a row
        return is_done(case, scene) or (stored is not None and stored.get("status") != "ok")

    if comm.rank == 0:
        for case in cases:
            if case.name in rejected and load_result(out_dir, case) is None:
                write_json(result_path(out_dir, case.name), {**base_result(case), "status": "rejected",
                                                             "reason": rejected[case.name], "steps": 0})
    todo = comm.bcast([c for c in cases if c.name in resolved and not done(c)] if comm.rank == 0 else None, root=0)
    n_groups, color = comm.size // ranks_per_case, comm.rank // ranks_per_case
    initialise_petsc(comm)
    group = comm.Split(color, comm.rank)
    if comm.rank == 0:
        log.info("%s: %d cases, %d already done, %d to run on %d group(s) of %d rank(s) -> %s", desc, len(cases),
                 len(cases) - len(todo), len(todo), n_groups, ranks_per_case, out_dir)
        stored = {c.name: load_result(out_dir, c, resolved[c.name]) for c in todo}
        stale = [c.name for c in todo if result_path(out_dir, c.name).is_file() and stored[c.name] is None]
        crashed = [name for name, result in stored.items() if result is not None and result.get("status") == "error"]
        if stale:
            log.info("%s: solving again %s: stored for another resolved scene (a changed scene file or default)",
                     desc, ", ".join(stale))
        if crashed:
            log.info("%s: solving again %s: its stored run crashed (%s)", desc, ", ".join(crashed),
                     "; ".join((stored[name].get("reason") or "?").splitlines()[0] for name in crashed))
    claims = Claims(out_dir, comm)
    bar = tqdm(total=len(cases), initial=len(cases) - len(todo), desc=desc, unit="case", disable=comm.rank != 0)
    for case in claims.cases(todo, group):
        result = solve(case, resolved[case.name], out_dir, group, comm.rank == 0)
        if group.rank == 0:
            write_json(result_path(out_dir, case.name), {**base_result(case, resolved[case.name]), **result})
        if comm.rank == 0:
            bar.n = sum(done(c) for c in cases)
            bar.refresh()
    idle_barrier(comm)
    if comm.rank == 0:
        claims.remove()
    bar.n = len(cases)
    bar.close()
    group.Free()
    return [load_result(out_dir, c) for c in cases]
