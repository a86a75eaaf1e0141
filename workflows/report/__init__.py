"""One reproduction report (``deapull report``): every result of the pipeline on one page,
beside the paper's numbers, with pictures of the deforming DEA.

The report is built from whatever outputs exist; it runs no FEM and trains nothing. Each
section reads the files of one study (paths in :class:`Inputs`, the defaults being the
folders the make targets write) and, when they are absent, says what is missing and the
command that makes it. Written to ``--out``:

* ``index.html`` — self-contained: inline CSS, no script, no network; images beside it in
  ``img/``;
* ``report.md`` — the same content as Markdown (same images);
* ``img/`` — the figures drawn here (sweep, DEA pictures, animation) and copies of the
  studies' own figures;
* ``report.json`` — the paper-against-ours rows, the missing steps and the sources.

Every file is written atomically. :func:`missing_steps` names the make targets whose
outputs are absent (``make report FULL=1`` runs them first, then builds the page).

The modules, one job each:

* :mod:`.inputs` — where each study's outputs are read, the make steps, what is missing;
* :mod:`.document` — sections, tables, claims and the registry of source files (:class:`Report`);
* :mod:`.assemble` — the sections in page order (:data:`assemble.SECTIONS`, the one place a section
  is registered) and the build;
* ``sections_*`` — the sections, one function ``f(rep) -> Section`` each (FEM, surrogates,
  control, error against run time, and the page's summary and provenance);
* :mod:`.render` — HTML and Markdown; :mod:`.plots`, :mod:`.pictures` — the figures drawn here;
* :mod:`.tabular` — reading CSV and Markdown tables, formatting numbers; :mod:`.versions` —
  package versions and the machine; :mod:`.check` — the page in a real browser.
"""
from deapull.workflows.report.assemble import SECTIONS, build
from deapull.workflows.report.inputs import SETUPS, STEP, STEPS, Inputs, missing_steps

__all__ = ["SECTIONS", "SETUPS", "STEP", "STEPS", "Inputs", "build", "missing_steps"]
