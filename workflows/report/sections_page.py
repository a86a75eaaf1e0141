"""The sections about the page itself: the summary (paper against ours, first) and the
provenance of every number (last)."""
from __future__ import annotations

import datetime as _dt

from deapull import provenance
from deapull.workflows.report.document import OUTCOMES, Report, Section, Table
from deapull.workflows.report.inputs import STEP
from deapull.workflows.report.versions import machine, versions


def section_provenance(rep: Report) -> Section:
    sec = Section("provenance", "Provenance of every number")
    commit = provenance.git_commit()
    sec.p(f"Page built {_dt.datetime.now(_dt.timezone.utc).strftime('%Y-%m-%d %H:%M UTC')} by `deapull report` at "
          f"commit `{commit[:12]}` on {machine()}. Each study's files say which commit made them (last column); "
          "a section's Sources line links here.")
    v = versions()
    sec.table(Table(["package", "version"], [[k, val] for k, val in v.items()],
                    caption="Package versions (this build)"))
    rows, anchors = [], []
    for info in rep.sources.values():
        rows.append([f"`{info['path']}`", ", ".join(f"[{s}](#{s})" for s in info["sections"]), str(info["bytes"]),
                     info["modified_utc"], info["sha256"], info["commit"] or "–"])
        anchors.append(info["anchor"])
    if rows:
        sec.table(Table(["file", "used in", "bytes", "modified (UTC)", "sha256", "commit recorded in it"], rows,
                        anchors, caption="Every file a number on this page came from"))
    return sec


def outcome_counts(claims) -> dict[str, int]:
    """How many claims say each outcome (``""``: not judged)."""
    counts = {o: 0 for o in (*OUTCOMES, "")}
    for c in claims:
        counts[c.outcome] += 1
    return counts


def section_summary(rep: Report) -> Section:
    sec = Section("summary", "Does this reproduce the paper? Paper against ours")
    rep.claims.sort(key=lambda c: c.verdict == "caveat")          # stable: the caveats last
    if rep.claims:
        counts = outcome_counts(rep.claims)
        sec.p("**" + " · ".join(f"{counts[o]} {o}" for o in OUTCOMES) + f"** ({counts['']} rows not judged), "
              "counted from the rows below: *reproduced* = the paper's result holds with our FEM, *not reproduced* "
              "= it does not (the row says why), *beyond the paper* = a model or measurement the paper does not "
              "have.")
        sec.table(Table(["result", "paper", "ours", "where", "verdict", "outcome"],
                        [[c.what, c.paper, c.ours, f"[row]({c.anchor})", c.verdict or "–", c.outcome or "–"]
                         for c in rep.claims],
                        [f"claim-{i}" for i in range(len(rep.claims))],
                        caption="Each paper number beside ours; 'row' links to the row it comes from", wrap=True))
    missing = [m for s in rep.sections for m in s.missing]
    if missing:
        steps = list(dict.fromkeys(step for _, step in missing))
        sec.p("Not on this page yet (each section says what and how): " + "; ".join(
            f"{STEP[s].what} — `{STEP[s].hint(rep.inputs)[0]}`" for s in steps) + ". `make report FULL=1` runs the missing steps "
            "(they resume) and rebuilds the page.")
    sec.p("Where we differ by design: the FEM is dolfinx (mixed u–p hexahedra, penalty contact with regularised "
          "Coulomb friction), not ABAQUS; the flat-top contact pushes the coin away from the clamp (−x) rather than "
          "pulling it (`docs/physics.md`); the surrogate adds a tip-contact law beside the paper's; control limits "
          "|ΔV| per step equally for every policy (`docs/control.md`).")
    return sec
