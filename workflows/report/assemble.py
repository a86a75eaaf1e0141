"""The page assembled: the sections in page order, registered in one place (:data:`SECTIONS`),
run over the outputs found and written as ``index.html``, ``report.md`` and ``report.json``."""
from __future__ import annotations

import logging
import shutil
from pathlib import Path

from tqdm import tqdm

from deapull import provenance
from deapull.errors import InputError
from deapull.io import write_json, write_text
from deapull.workflows.report import (sections_control, sections_error_time, sections_fem, sections_page,
                                     sections_surrogates)
from deapull.workflows.report.document import Report
from deapull.workflows.report.inputs import STEPS, Inputs
from deapull.workflows.report.render import render_html, render_markdown, table_csv, table_files

log = logging.getLogger(__name__)

#: The page's body in order: (name in the log, function of the Report returning its Section).
#: A new section is one function ``f(rep) -> Section`` added here; :data:`FIRST` and :data:`LAST`
#: run after the body (the summary reads the body's claims, the provenance its sources).
SECTIONS = (("model", sections_fem.section_model),
            ("pictures", sections_fem.section_pictures),
            ("sweep", sections_fem.section_sweep),
            ("fem-accuracy", sections_fem.section_fem_accuracy),
            ("fidelity", sections_fem.section_fidelity),
            ("stability", sections_fem.section_stability),
            ("surrogates", sections_surrogates.section_surrogates),
            ("protocols", sections_surrogates.section_protocols),
            ("control", sections_control.section_control),
            ("control-fem", sections_control.section_control_fem),
            ("error-time", sections_error_time.section_error_time))
FIRST = sections_page.section_summary
LAST = sections_page.section_provenance
TITLE = "deapull: reproduction report of Lahariya et al., IROS 2022"
LEAD = ["The whole pipeline on one page — FEM (dolfinx) of a dielectric-elastomer actuator pushing a coin, "
        "physics-informed surrogates (torch), closed-loop control — beside the paper's numbers "
        "(“Learning physics-informed simulation models for soft robotic manipulation: a case study with "
        "dielectric elastomer actuators”). Built by `deapull report` from the outputs found; nothing is "
        "recomputed here. The [summary](#summary) links each paper number to its row."]


def build(out, inputs: Inputs, frames: int = 30, progress: bool = True) -> dict:
    """Build the report into ``out`` from the outputs in ``inputs``; returns its summary
    (``index``, ``markdown``, ``missing`` steps, ``claims``, ``images``)."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {str(out)!r}: exists and is not a folder")
    if frames < 2:
        raise InputError(f"--frames {frames}: need at least 2 frames for the animation")
    if inputs.data.exists() and not inputs.data.is_dir():
        raise InputError(f"--data {str(inputs.data)!r}: not a folder")
    rep = Report(out, inputs, frames, progress)
    rep.img.mkdir(parents=True, exist_ok=True)
    for name, make in tqdm(SECTIONS, desc="report", unit="section", disable=not progress or None):
        log.debug("report: section %s", name)
        rep.sections.append(make(rep))
    rep.sections.insert(0, FIRST(rep))
    rep.sections.append(LAST(rep))
    _drop_stale_images(rep)
    tables = out / "tables"
    if tables.is_dir():
        shutil.rmtree(tables)
    tables.mkdir()
    names = table_files(rep)
    for s in rep.sections:
        for block in s.blocks:
            if block[0] == "table":
                write_text(tables / names[id(block[1])], table_csv(block[1]))
            elif block[0] == "data":                 # the numbers behind a figure
                write_text(tables / block[1], block[2])
    index = write_text(out / "index.html", render_html(rep, TITLE, LEAD))
    standalone = write_text(out / "report_standalone.html", render_html(rep, TITLE, LEAD, standalone=True))
    md = write_text(out / "report.md", render_markdown(rep, TITLE, LEAD))
    found = {step for s in rep.sections for _, step in s.missing}
    missing = [s.name for s in STEPS if s.name in found]          # in pipeline order
    summary = {"index": str(index), "standalone": str(standalone), "markdown": str(md), "missing": missing,
               "claims": [vars(c) for c in rep.claims], "images": sorted(p.name for p in rep.img.iterdir()),
               "sources": list(rep.sources.values()), "git_commit": provenance.git_commit()}
    write_json(out / "report.json", summary, indent=1)
    return summary


def _drop_stale_images(rep: Report) -> None:
    """Remove images of an earlier build that this page no longer shows."""
    used = {Path(b[1]).name for s in rep.sections for b in s.blocks if b[0] == "img"}
    for p in rep.img.iterdir():
        if p.is_file() and p.name not in used and not p.name.startswith("."):
            p.unlink()
        elif p.is_dir():
            shutil.rmtree(p)
