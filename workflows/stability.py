"""Numerical stability of the FEM: stiff and extreme cases (``deapull stability``).

The cases are data, ``studies/stability.toml`` (:mod:`deapull.workflows.study_file`): the
coin_pull scene (setup C3) — or free_bending for the free pull-in — with one thing pushed to an
extreme: near- and fully-incompressible material in both formulations, contact penalty from 1e-2
to 1e4 × the scene's, voltage far beyond pull-in, friction coefficients at 0 and 1, coin mass × 0.1
and × 10, a Gent material near locking, tiny and huge time steps and a first step forced too large.
Every case is a row: converged or not, Newton iterations, cut-backs, the smallest step, the largest
penetration, the largest coin force-balance residual, wall time, and for a failure PETSc's reason
with the time and voltage where it happened. A scene that validation rejects (pure displacement at
ν = 0.5) is a row ``rejected: <message>``.

Protocol: ``quick`` (default) keeps the 1 s, 0 → V_max ramp on the scene's mesh with a base step of
0.01 s (~100 points, :func:`deapull.workflows.fidelity.protocol_overrides`); ``full`` keeps the
scene's steps.

Pull-in is *detected*, not crashed into: the step that cannot be solved after the
cut-backs ends the run with :class:`fem_solver.stepping.SolveFailed`, and the row records
its voltage as ``instability_V``, beside the growth of the tip deflection before it
(``tip_log_slope_max``: 2 for the small-strain V² law, larger as the actuator softens) and
the collapse of the accepted voltage increments (``dV_collapse``) as the cut-backs pile up.
"""
from __future__ import annotations

import math
from pathlib import Path

from deapull import provenance, scene as scenes
from deapull.errors import InputError
from deapull.io import cell as fmt, markdown_of, table_record, write_csv, write_json, write_text
from deapull.workflows import study_file
from deapull.workflows.fidelity import PROTOCOLS, protocol_overrides
from deapull.workflows.runner import Case, run_cases

CONVERGED, INSTABILITY, REJECTED = "converged", "instability", "rejected"
#: the keys of a stability case besides ``set`` and ``description``
CASE_KEYS = {"scene": None, "expected": (CONVERGED, INSTABILITY, REJECTED)}


def fidelity_of_case(scene: str, base_scene: str, fidelity: str | None) -> tuple[str, ...]:
    """``fidelity``'s overrides for a case of ``scene``: the base scene must define it (else
    SceneError naming what it defines); a case of another scene (free_bending's pull-in) takes it
    only where that scene defines it too, and is run as its file is written otherwise."""
    if not fidelity or (scene != base_scene and fidelity not in scenes.fidelities_of(scene)):
        return ()
    return scenes.fidelity_overrides(scene, fidelity)


def stability_cases(protocol: str = "quick", overrides=(), names=None, fidelity: str | None = None,
                    study: str | Path = "stability") -> list[Case]:
    """The cases of the ``study`` file; ``names`` picks cases (default: all). ``fidelity`` names one of
    the base scene's fidelities (:func:`fidelity_of_case`), applied before ``overrides``. Bad names,
    an unknown fidelity, a bad study file or a bad --set raise InputError."""
    if protocol not in PROTOCOLS:
        raise InputError(f"--protocol {protocol!r}: expected one of {', '.join(PROTOCOLS)}")
    head, entries = study_file.load(study, CASE_KEYS)
    base_scene, base_setup = head["scene"], head.get("setup")
    fidelity_of_case(base_scene, base_scene, fidelity)      # an unknown fidelity: before any case
    bases, cases = {}, []
    for entry in study_file.pick(entries, names, "--cases"):
        scene = entry.keys.get("scene", base_scene)
        setup = base_setup if scene == base_scene else None
        if scene not in bases:
            fid = fidelity_of_case(scene, base_scene, fidelity)
            shipped = scenes.load(scene, setup=setup, overrides=(*fid, *overrides))
            proto = protocol_overrides(shipped, protocol)
            bases[scene] = fid, proto, scenes.load(scene, setup=setup, overrides=(*fid, *overrides, *proto))
        fid, proto, base = bases[scene]
        sets = study_file.resolve(entry.set, base, f"cases.{entry.name}")
        expected = entry.keys.get("expected", CONVERGED)
        try:
            voltage = scenes.load(scene, setup=setup, overrides=(*fid, *overrides, *proto, *sets)).load.voltage_max_V
        except scenes.SceneError:
            voltage = base.load.voltage_max_V       # a case validation rejects: a row, solved never
        described = entry.description
        if fidelity and not fid:
            described += f" ({scene} as written: it defines no fidelity {fidelity!r})"
        cases.append(Case(entry.name, scene, setup, (*fid, *overrides, *proto, *sets), described,
                          {"expected": expected, "protocol": protocol, "voltage_max_V": voltage}))
    return cases


# --- the table -------------------------------------------------------------------------

def outcome(row: dict) -> str:
    """One phrase: converged, or why not and where."""
    status = row["status"]
    if status == "ok":
        return CONVERGED
    if status == "failed":
        return (f"failed: {row['reason']} at t = {row['fail_t_s']:.4g} s, V = {row['fail_V']:.4g} V "
                f"(last good step {row['last_good_step']})")
    return f"{status}: {row['reason']}"


def finish_row(row: dict) -> dict:
    """Add the derived columns: converged, outcome, instability voltage, as expected."""
    row = dict(row)
    row["converged"] = row["status"] == "ok"
    row["outcome"] = outcome(row)
    detected = row["status"] == "failed" and row.get("fail_V", math.inf) < row["voltage_max_V"]
    row["instability_V"] = row["fail_V"] if row["expected"] == INSTABILITY and detected else math.nan
    row["as_expected"] = {CONVERGED: row["converged"], INSTABILITY: detected,
                          REJECTED: row["status"] == "rejected"}[row["expected"]]
    return row


CSV_COLUMNS = ("case", "description", "scene", "expected", "status", "converged", "as_expected", "steps",
               "newton_iterations", "max_newton_per_step", "cutbacks", "min_dt_s", "max_dt_s", "max_penetration_mm",
               "min_contact_points", "max_table_penetration_um", "max_force_residual_N", "travel_mm", "max_Fy_mN",
               "max_tip_deflection_mm", "last_V", "solve_s", "wall_s", "ranks",
               "reason", "fail_t_s", "fail_V", "instability_V", "tip_log_slope_max", "dV_collapse", "dofs",
               "outcome", "protocol", "overrides")
MD_COLUMNS = (("case", "case", ""), ("converged", "converged", ""), ("as expected", "as_expected", ""),
              ("steps", "steps", "d"), ("Newton its", "newton_iterations", "d"),
              ("max its/step", "max_newton_per_step", "d"), ("cut-backs", "cutbacks", "d"),
              ("min dt s", "min_dt_s", ".2g"), ("max pen. mm", "max_penetration_mm", ".3g"),
              ("fewest contact pts", "min_contact_points", ".0f"), ("max table pen. µm", "max_table_penetration_um", ".2f"),
              ("max coin residual N", "max_force_residual_N", ".2g"), ("travel mm", "travel_mm", ".3f"),
              ("wall s", "wall_s", ".1f"), ("outcome", "outcome", ""))


def stability_results(rows, header: str) -> dict:
    """The suite's results (stability.json): the header, the table (:func:`deapull.io.table_record`),
    the pull-in notes and the cases not as expected."""
    notes = []
    for r in (r for r in rows if r["expected"] == INSTABILITY):
        notes.append(f"`{r['case']}`: {'detected at V = ' + format(r['instability_V'], '.4g') + ' V' if math.isfinite(r['instability_V']) else 'not detected'}; "
                     f"largest tip log-slope d ln|tip| / d ln V {fmt(r.get('tip_log_slope_max'), '.3g')} "
                     f"(2 = small-strain V^2 law), voltage-increment collapse {fmt(r.get('dV_collapse'), '.3g')}x, "
                     f"max tip deflection {fmt(r.get('max_tip_deflection_mm'), '.3g')} mm.")
    return {"schema": 1, "git_commit": provenance.git_commit(), "header": header,
            "table": table_record(rows, MD_COLUMNS), "pull_in": notes,
            "not_as_expected": [r["case"] for r in rows if not r["as_expected"]]}


def write_markdown(result: dict, path: Path) -> None:
    lines = ["# FEM stability: stiff and extreme cases", "", result["header"], "", markdown_of(result["table"]), ""]
    if result["pull_in"]:
        lines += ["Pull-in (electromechanical instability) detection:", ""]
        lines += [f"* {note}" for note in result["pull_in"]]
        lines.append("")
    unexpected = result["not_as_expected"]
    lines.append(f"Cases not as expected: {', '.join(unexpected) if unexpected else 'none'}.")
    write_text(path, "\n".join(lines) + "\n")


def run_stability(out_dir, comm, protocol: str = "quick", names=None, overrides=(),
                  ranks_per_case: int = 1, fidelity: str | None = None,
                  study: str | Path = "stability") -> list[dict] | None:
    """Run (or resume) the stability cases; rank 0 writes stability.csv/.md and returns the rows."""
    out_dir = Path(out_dir)
    cases = stability_cases(protocol, overrides, names, fidelity, study)
    results = run_cases(cases, out_dir, comm, ranks_per_case, desc="stability")
    if comm.rank != 0:
        return None
    rows = [finish_row(r) for r in results]
    head = study_file.load(study, CASE_KEYS)[0]
    header = (f"Study `{study}`: base `{head['scene']}` setup `{head.get('setup')}`, fidelity "
              f"`{fidelity or 'as written'}`, protocol `{protocol}`"
              f"{' (1 s ramp, base step 0.01 s)' if protocol == 'quick' else ''}, {comm.size} MPI rank(s), "
              f"{ranks_per_case} per case; extra --set: {' '.join(overrides) or 'none'}. {provenance.summary()}.")
    write_csv(out_dir / "stability.csv", rows, CSV_COLUMNS)
    result = stability_results(rows, header)
    write_json(out_dir / "stability.json", result, indent=2)
    write_markdown(result, out_dir / "stability.md")
    return rows


def summary_table(rows) -> str:
    lines = [f"{'case':24s} {'steps':>6s} {'newton':>7s} {'cuts':>5s} {'wall s':>7s}  outcome", "-" * 90]
    for r in rows:
        lines.append(f"{r['case']:24s} {fmt(r.get('steps'), 'd'):>6s} {fmt(r.get('newton_iterations'), 'd'):>7s} "
                     f"{fmt(r.get('cutbacks'), 'd'):>5s} {fmt(r.get('wall_s'), '.1f'):>7s}  "
                     f"{'' if r['as_expected'] else '[unexpected] '}{r['outcome']}")
    return "\n".join(lines)
