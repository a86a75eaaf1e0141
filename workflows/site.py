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
"""
from __future__ import annotations

import csv
import datetime as _dt
import hashlib
import html
import json
import logging
import math
import os
import platform
import re
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from deapull import dataset, provenance, scene as scenes
from deapull.errors import InputError
from deapull.io import atomic_write, write_json, write_text

log = logging.getLogger(__name__)

SCENE = "coin_pull"
SETUPS = tuple(f"C{i}" for i in range(1, 9))
#: the paper (Lahariya et al., IROS 2022): ABAQUS wall time of a 1 s, 700-point run (§VI-A)
PAPER_FEM_S = 130.0
#: the paper's Table II (MAE over the six test setups; m and N) and 1 s rollout times (ms, §VI-A)
#: — the same numbers as deapull.surrogate.experiments.PAPER, which experiments.json repeats
PAPER_TABLE2 = {"mae_x_m": {"f": 0.34e-4, "lstm": 3.86e-4, "nn": 9.86e-4},
                "mae_Fx_N": {"f": 3.68e-4}, "mae_Fy_N": {"f": 12.01e-4},
                "rollout_ms": {"f": 700.0, "nn": 300.0, "lstm": 1200.0}}
#: the paper's §VI-B: iterations to the target and time per iteration (ms) per policy (Fig. 6, C2)
PAPER_CONTROL = {"mpc": ("≤ 200", 1200.0), "sac": ("~10,000", 5.0), "pd": ("~1,500", 1.0), "heur": ("~500", None)}
#: the paper's threshold displacement of V^T (§V) — as deapull.surrogate.data.THRESHOLD_DISPLACEMENT_M
THRESHOLD_M = -1e-5
MODEL_LABELS = {"f": "f (paper's law)", "f-coulomb": "f (tip contact)", "nn": "NN", "lstm": "LSTM"}
#: packages whose versions the provenance section lists: distribution name (module name if different)
VERSIONS = (("fenics-dolfinx", "dolfinx"), ("gmsh", "gmsh"), ("petsc4py", "petsc4py"), ("mpi4py", "mpi4py"),
            ("numpy", "numpy"), ("xarray", "xarray"), ("h5netcdf", "h5netcdf"), ("h5py", "h5py"),
            ("torch", "torch"), ("gymnasium", "gymnasium"), ("stable-baselines3", "stable_baselines3"),
            ("matplotlib", "matplotlib"), ("pillow", "PIL"), ("playwright", "playwright"))


# --- inputs and the steps that make them --------------------------------------------------

@dataclass(frozen=True)
class Inputs:
    """Where each study's outputs are read from (defaults: the make targets' folders)."""
    data: Path = Path("data")
    fields: Path = Path("out/report_fields/C3_fields.xdmf")
    fidelity: Path = Path("out/fidelity")
    stability: Path = Path("out/stability")
    experiments: Path = Path("out/experiments")
    control: Path = Path("out/control")
    bench_control: Path = Path("out/bench_control")
    bench_fem: Path = Path("out/bench_fem")
    excitation: Path = Path("data/excitation")
    protocols: Path = Path("out/protocols")

    @classmethod
    def under(cls, out_root="out", data="data", **paths) -> "Inputs":
        """Every study folder under ``out_root`` unless given in ``paths`` (None: the default)."""
        root = Path(out_root)
        default = {"fields": root / "report_fields" / "C3_fields.xdmf", "fidelity": root / "fidelity",
                   "stability": root / "stability", "experiments": root / "experiments",
                   "control": root / "control", "bench_control": root / "bench_control",
                   "bench_fem": root / "bench_fem", "excitation": Path(data) / "excitation",
                   "protocols": root / "protocols"}
        default.update({k: Path(v) for k, v in paths.items() if v is not None})
        return cls(data=Path(data), **default)


@dataclass(frozen=True)
class Step:
    """A make target and the command behind it, and the files that show it has run."""
    name: str
    make: str
    command: str
    what: str


STEPS = (
    Step("sweep", "make sweep", "mpirun -n 2 deapull sweep --scene coin_pull --out data",
         "the 8 FEM datasets C1..C8 (the sweep, the surrogates and control read them)"),
    Step("report-fields", "make report-fields",
         "deapull solve --scene coin_pull --setup C3 --out out/report_fields --fields-every 10",
         "the displacement fields of one run (pictures and animation)"),
    Step("bench-fem", "make bench-fem", "python bench/bench_fem.py --out out/bench_fem --np 2",
         "the FEM's wall time, travel error and sweep time beside ABAQUS (docs/fem_accuracy.md)"),
    Step("fidelity", "make fidelity", "mpirun -n 2 deapull fidelity --scene coin_pull --setup C3 --out out/fidelity",
         "the error-against-run-time ladder"),
    Step("stability", "make stability", "mpirun -n 2 deapull stability --out out/stability",
         "the stiff and extreme cases"),
    Step("experiments", "make experiments", "deapull experiments --data data --out out/experiments",
         "the paper's six experiment sets (Table II, box plot, rollouts)"),
    Step("excitation", "make excitation", "mpirun -n 2 deapull sweep --scene coin_pull --setups C1,C3,C5,C7 "
         "--protocols excitation --out data/excitation", "the FEM under ramp-hold-ramp, triangle, release and "
         "random voltages"),
    Step("experiments-protocols", "make experiments-protocols", "deapull experiments-protocols --data data "
         "--excitation data/excitation --out out/protocols --ramp-results out/experiments",
         "the surrogates on held-out protocols and coins"),
    Step("control", "make control", "deapull control --policy mpc,sac,pd,heur --plant surrogate:C1,surrogate:C2 "
         "--episodes 10 --noise 0,1e-5,1e-4,1e-3 --out out/control", "the closed-loop episodes (Fig. 6)"),
    Step("bench-control", "make bench-control", "python bench/bench_control.py --out out/bench_control",
         "the MPC step beside mpc.pytorch"),
)
STEP = {s.name: s for s in STEPS}


def step_done(name: str, inputs: Inputs) -> bool:
    """True when the outputs of step ``name`` are there (complete datasets, the study's table)."""
    if name == "sweep":
        return all(dataset.is_complete(inputs.data / f"{s}.nc") for s in SETUPS)
    if name == "report-fields":
        return inputs.fields.is_file() and dataset.is_complete(_fields_run(inputs.fields))
    files = {"fidelity": inputs.fidelity / "fidelity.csv", "stability": inputs.stability / "stability.csv",
             "experiments": inputs.experiments / "experiments.csv", "control": inputs.control / "control.csv",
             "bench-control": inputs.bench_control / "bench_control.json",
             "bench-fem": inputs.bench_fem / "bench_fem.json",
             "experiments-protocols": inputs.protocols / "protocols.csv"}
    if name == "excitation":
        from deapull.workflows.sweep import PROTOCOL_SETS
        return all(dataset.is_complete(inputs.excitation / f"{s}_{p}.nc")
                   for s in EXCITATION_SETUPS for p in PROTOCOL_SETS["excitation"])
    return files[name].is_file()


#: the coins `make excitation` plays the excitation protocols on
EXCITATION_SETUPS = ("C1", "C3", "C5", "C7")


def missing_steps(inputs: Inputs) -> list[str]:
    """Names of the steps (make targets) whose outputs are absent, in pipeline order."""
    return [s.name for s in STEPS if not step_done(s.name, inputs)]


def _fields_run(xdmf: Path) -> Path:
    return xdmf.with_name(xdmf.name.replace("_fields.xdmf", ".nc"))


# --- the document: sections of blocks, rendered as HTML and Markdown -------------------------

@dataclass
class Table:
    headers: list
    rows: list                 # lists of cells (str)
    anchors: list | None = None   # an id per row (None: no id)
    caption: str = ""
    wrap: bool = False            # text cells: wrap and align left (HTML)


@dataclass
class Section:
    id: str
    title: str
    blocks: list = field(default_factory=list)
    sources: list = field(default_factory=list)     # paths the section's numbers come from
    missing: list = field(default_factory=list)     # (what, step name)

    def p(self, text: str) -> None:
        self.blocks.append(("p", text))

    def table(self, t: Table) -> None:
        self.blocks.append(("table", t))

    def img(self, rel: str, caption: str) -> None:
        self.blocks.append(("img", rel, caption))

    def bullets(self, items) -> None:
        self.blocks.append(("ul", list(items)))

    def lack(self, what: str, step: str) -> None:
        self.missing.append((what, step))
        s = STEP[step]
        self.blocks.append(("missing", what, s))


@dataclass
class Claim:
    """One number of the paper beside ours, linked to the row it comes from."""
    what: str
    paper: str
    ours: str
    anchor: str              # the section or table row with our number
    verdict: str = ""


class Report:
    """Collects the sections, the paper-against-ours claims and the image files."""

    def __init__(self, out: Path):
        self.out = out
        self.img = out / "img"
        self.sections: list[Section] = []
        self.claims: list[Claim] = []
        self.sources: dict[Path, dict] = {}

    def found(self, path: Path, section: Section, what: str, step: str) -> bool:
        """True and ``path`` registered as a source when it exists; otherwise the section
        says what is missing (``what``, `path` appended) and which make ``step`` makes it."""
        if not Path(path).is_file():
            section.lack(f"{what} `{path}`", step)
            return False
        self.source(path, section)
        return True

    def source(self, path: Path, section: Section) -> str:
        """Register a file a number came from; returns the anchor of its provenance row."""
        path = Path(path)
        key = path.resolve()
        if path.is_absolute() and key.is_relative_to(Path.cwd()):
            path = key.relative_to(Path.cwd())          # shown as the user would type it
        if key not in self.sources:
            self.sources[key] = {"path": str(path), "sections": [], "anchor": f"src-{len(self.sources) + 1}",
                                 **_file_facts(path)}
        if section.id not in self.sources[key]["sections"]:
            self.sources[key]["sections"].append(section.id)
        if path not in section.sources:
            section.sources.append(path)
        return self.sources[key]["anchor"]

    def copy_image(self, src: Path, name: str) -> str:
        """Copy a study's figure beside the page; returns its path relative to the page."""
        data = Path(src).read_bytes()
        atomic_write(self.img / name, lambda p: Path(p).write_bytes(data), suffix=Path(name).suffix)
        return f"img/{name}"


def _file_facts(path: Path) -> dict:
    st = path.stat()
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return {"bytes": st.st_size, "sha256": h.hexdigest()[:12],
            "modified_utc": _dt.datetime.fromtimestamp(st.st_mtime, _dt.timezone.utc).strftime("%Y-%m-%d %H:%M"),
            "commit": _recorded_commit(path)}


def _recorded_commit(path: Path) -> str:
    """The git commit the file says made it ('' when it says none)."""
    try:
        if path.suffix == ".nc":
            import xarray as xr
            with xr.open_dataset(path, engine=dataset.ENGINE) as ds:
                return str(ds.attrs.get("git_commit", ""))[:12]
        if path.suffix == ".json":
            return str(json.loads(path.read_text()).get("git_commit", ""))[:12]
        if path.suffix == ".md":
            m = re.search(r"\bgit ([0-9a-f]{7,40})\b", path.read_text())
            return m.group(1)[:12] if m else ""
    except (OSError, ValueError, AttributeError):
        return ""
    return ""


_INLINE = re.compile(r"`([^`]+)`|\[([^\]]+)\]\(([^)\s]+)\)|\*\*([^*]+)\*\*")


def inline_html(text: str) -> str:
    """Escape ``text`` and turn its `code`, [link](href) and **bold** into HTML."""
    out, pos = [], 0
    for m in _INLINE.finditer(text):
        out.append(html.escape(text[pos:m.start()]))
        if m.group(1) is not None:
            out.append(f"<code>{html.escape(m.group(1))}</code>")
        elif m.group(2) is not None:
            out.append(f'<a href="{html.escape(m.group(3), quote=True)}">{inline_html(m.group(2))}</a>')
        else:
            out.append(f"<strong>{html.escape(m.group(4))}</strong>")
        pos = m.end()
    out.append(html.escape(text[pos:]))
    return "".join(out)


def _md_cell(text: str) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;max-width:1200px;margin:0 auto;
padding:0 1.2em 3em;
color:#1d1d1f;line-height:1.45}
h1{margin-top:.6em}h2{border-bottom:2px solid #ddd;padding-bottom:.2em;margin-top:2em}
table{border-collapse:collapse;margin:.6em 0 1.2em;font-size:.86em;display:block;overflow-x:auto}
th,td{border:1px solid #ccc;padding:.25em .5em;text-align:right;white-space:nowrap}
th{background:#f2f2f5}td:first-child,th:first-child{text-align:left}
tr:target{background:#fff3b0}caption{caption-side:top;text-align:left;font-weight:600;padding:.3em 0}
figure{margin:1em 0}figure img{max-width:100%;border:1px solid #eee}figcaption{font-size:.88em;color:#444}
.missing{background:#fff4f0;border-left:4px solid #d9534f;padding:.5em .8em;margin:.8em 0}
code{background:#f4f4f6;padding:0 .25em;border-radius:3px}nav ol{columns:2}
table.wrap td,table.wrap th{white-space:normal;text-align:left}
"""


def render_html(report: Report, title: str, lead: list[str]) -> str:
    parts = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
             '<meta name="viewport" content="width=device-width, initial-scale=1">',
             f"<title>{html.escape(title)}</title><style>{CSS}</style></head><body>",
             f"<h1>{html.escape(title)}</h1>"]
    parts += [f"<p>{inline_html(t)}</p>" for t in lead]
    parts.append("<nav><ol>" + "".join(f'<li><a href="#{s.id}">{html.escape(s.title)}</a></li>'
                                       for s in report.sections) + "</ol></nav>")
    for s in report.sections:
        parts.append(f'<section id="{s.id}"><h2>{html.escape(s.title)}</h2>')
        for block in s.blocks:
            kind = block[0]
            if kind == "p":
                parts.append(f"<p>{inline_html(block[1])}</p>")
            elif kind == "ul":
                parts.append("<ul>" + "".join(f"<li>{inline_html(i)}</li>" for i in block[1]) + "</ul>")
            elif kind == "img":
                src, alt = html.escape(block[1], quote=True), html.escape(block[2], quote=True)
                parts.append(f'<figure><img src="{src}" alt="{alt}">'
                             f"<figcaption>{inline_html(block[2])}</figcaption></figure>")
            elif kind == "missing":
                _, what, step = block
                parts.append(f'<div class="missing"><strong>Missing:</strong> {inline_html(what)}. Make it with '
                             f"<code>{html.escape(step.make)}</code> (runs <code>{html.escape(step.command)}</code>)."
                             "</div>")
            elif kind == "table":
                t = block[1]
                cap = f"<caption>{inline_html(t.caption)}</caption>" if t.caption else ""
                head = "".join(f"<th>{inline_html(str(h))}</th>" for h in t.headers)
                rows = []
                for i, row in enumerate(t.rows):
                    rid = t.anchors[i] if t.anchors else None
                    attr = f' id="{rid}"' if rid else ""
                    rows.append(f"<tr{attr}>" + "".join(f"<td>{inline_html(str(c))}</td>" for c in row) + "</tr>")
                cls = ' class="wrap"' if t.wrap else ""
                parts.append(f"<table{cls}>{cap}<thead><tr>{head}</tr></thead><tbody>{''.join(rows)}</tbody></table>")
        if s.sources:
            links = ", ".join(f'<a href="#{report.sources[Path(p).resolve()]["anchor"]}"><code>{html.escape(str(p))}'
                              "</code></a>" for p in s.sources)
            parts.append(f"<p><small>Sources: {links}</small></p>")
        parts.append("</section>")
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"


def render_markdown(report: Report, title: str, lead: list[str]) -> str:
    lines = [f"# {title}", ""]
    for t in lead:
        lines += [t, ""]
    lines += [f"{i + 1}. [{s.title}](#{s.id})" for i, s in enumerate(report.sections)] + [""]
    for s in report.sections:
        lines += [f'<a id="{s.id}"></a>', "", f"## {s.title}", ""]
        for block in s.blocks:
            kind = block[0]
            if kind == "p":
                lines += [block[1], ""]
            elif kind == "ul":
                lines += [f"* {i}" for i in block[1]] + [""]
            elif kind == "img":
                lines += [f"![{block[2]}]({block[1]})", "", f"*{block[2]}*", ""]
            elif kind == "missing":
                _, what, step = block
                lines += [f"> **Missing:** {what}. Make it with `{step.make}` (runs `{step.command}`).", ""]
            elif kind == "table":
                t = block[1]
                if t.caption:
                    lines += [f"**{t.caption}**", ""]
                lines.append("| " + " | ".join(_md_cell(h) for h in t.headers) + " |")
                lines.append("|" + "---|" * len(t.headers))
                for i, row in enumerate(t.rows):
                    rid = t.anchors[i] if t.anchors else None
                    cells = [_md_cell(c) for c in row]
                    if rid:
                        cells[0] = f'<a id="{rid}"></a>{cells[0]}'
                    lines.append("| " + " | ".join(cells) + " |")
                lines.append("")
        if s.sources:
            lines += ["<small>Sources: " + ", ".join(f"[`{p}`](#{report.sources[Path(p).resolve()]['anchor']})"
                                                    for p in s.sources) + "</small>", ""]
    return "\n".join(lines)


# --- small helpers ---------------------------------------------------------------------

def fmt(value, spec: str = ".3g", unit: str = "") -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    return format(value, spec) + (f" {unit}" if unit else "")


def read_csv(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def num(row: dict, key: str) -> float | None:
    try:
        v = float(row.get(key, ""))
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def markdown_tables(text: str) -> list[tuple[list[str], list[list[str]]]]:
    """Every pipe table of a Markdown text as (headers, rows)."""
    tables, current = [], []
    for line in text.splitlines() + [""]:
        if line.strip().startswith("|"):
            current.append(line.strip())
            continue
        if len(current) >= 2:
            cells = [_split_row(r) for r in current]
            tables.append((cells[0], [c for c in cells[2:]]))
        current = []
    return tables


def _split_row(line: str) -> list[str]:
    cells = re.split(r"(?<!\\)\|", line.strip().strip("|"))
    return [c.strip().replace("\\|", "|") for c in cells]


# --- the sections ----------------------------------------------------------------------------

def section_model(rep: Report) -> Section:
    sec = Section("model", "The model: geometry, materials, scene")
    sc = scenes.load(SCENE)
    rep.source(scenes.resolve_path(SCENE), sec)
    d, c, ld = sc.dea, sc.coin, sc.load
    e0 = ld.voltage_max_V / d.film_thickness_m
    eps = 8.854187817e-12 * d.relative_permittivity
    strain = eps * e0 ** 2 / (2 * d.youngs_modulus_Pa)
    pullin = 0.69 * math.sqrt(d.youngs_modulus_Pa / 3 / eps)
    sec.p(f"Scene `{SCENE}` (`deapull/scenes/{SCENE}.toml`, resolved with `deapull show-scene {SCENE} --setup "
          f"{sc.setup}`): {sc.scene.description}. A unimorph DEA (active electrode stack on a passive layer) is "
          f"clamped at x = 0 with its free end at x = −{d.length_m * 1e3:g} mm resting on a steel coin; "
          f"V rises 0 → {ld.voltage_max_V:g} V in {ld.ramp_time_s:g} s ({ld.protocol}). y is up, the coin moves "
          "toward −x (the paper's V^T convention). Every number below comes from the scene file.")
    rows = [
        ("DEA length × width", f"{d.length_m * 1e3:g} × {d.width_m * 1e3:g} mm", "dea.length_m, dea.width_m"),
        ("active stack / passive layer", f"{d.active_thickness_m * 1e3:g} / {d.passive_thickness_m * 1e3:g} mm",
         "dea.active_thickness_m, dea.passive_thickness_m"),
        ("film thickness (field = V / film)", f"{d.film_thickness_m * 1e6:g} µm", "dea.film_thickness_m"),
        ("material", f"{d.material}, E = {d.youngs_modulus_Pa / 1e6:g} MPa, ν = {d.poisson_ratio:g} "
         f"(paper: E = 0.56 MPa, ν = 0.5)", "dea.material, dea.youngs_modulus_Pa, dea.poisson_ratio"),
        ("ε_r, elastomer density", f"{d.relative_permittivity:g}, {d.density_kg_m3:g} kg/m³",
         "dea.relative_permittivity, dea.density_kg_m3"),
        ("clamp gap (gravity pre-load)", f"{d.clamp_gap_m * 1e3:g} mm", "dea.clamp_gap_m"),
        ("coin radius × height", f"{c.radius_m * 1e3:g} × {c.height_m * 1e3:g} mm (paper: 5 × 2.25 mm)",
         "coin.radius_m, coin.height_m"),
        ("coin centre from the tip", f"{c.center_from_tip_m * 1e3:g} mm toward the clamp", "coin.center_from_tip_m"),
        (f"coin density, μ_t, μ_b (setup {sc.setup})", f"{c.density_kg_m3 / 1e3:g} g/cm³, {c.mu_t:g}, {c.mu_b:g}",
         "coin.density_kg_m3, coin.mu_t, coin.mu_b"),
        ("contact", f"penalty {sc.contact.penalty_N_m3:.3g} N/m³, friction regularised at "
         f"{sc.contact.slip_rate_regularisation_m_s:g} m/s", "contact.*"),
        ("mesh", f"{sc.mesh.cell} order {sc.mesh.order}, {sc.mesh.n_length} × {sc.mesh.n_width} × "
         f"({sc.mesh.n_active} + {sc.mesh.n_passive}) cells, level {sc.mesh.level}", "mesh.*"),
        ("solver", f"{sc.solver.formulation}" + (" (Taylor–Hood u–p)" if sc.solver.formulation == "mixed" else "")
         + f", electrostatics {sc.solver.electrostatics}",
         "solver.*"),
        ("time", f"t ∈ [0, {ld.end_time_s:g}] s, dt ≤ {sc.time.dt_max_s * 1e3:.3g} ms (≥ 700 points)",
         "time.dt_max_s"),
        ("gravity", f"{sc.gravity_m_s2:g} m/s² along −y", "gravity_m_s2"),
        ("nominal field at V_max", f"{e0 / 1e6:.0f} MV/m (pull-in estimate ≈ {pullin / 1e6:.0f} MV/m)", "derived"),
        ("free actuation strain at V_max", f"ε E₀²/(2E) = {strain * 100:.1f} %", "derived"),
    ]
    sec.table(Table(["quantity", "value", "scene key"], [list(r) for r in rows], caption="Key values", wrap=True))
    setup_rows = []
    for s in scenes.setups_of(SCENE):
        ss = scenes.load(SCENE, setup=s)
        vol = math.pi * ss.coin.radius_m ** 2 * ss.coin.height_m
        setup_rows.append([s, f"{ss.coin.density_kg_m3 / 1e3:g}", f"{ss.coin.mu_t:g}", f"{ss.coin.mu_b:g}",
                           f"{vol * ss.coin.density_kg_m3 * 1e3:.3f}"])
    sec.table(Table(["setup", "ρ (g/cm³)", "μ_t", "μ_b", "m_c ideal disc (g)"], setup_rows,
                    caption="The 8 setups (the paper's numbering; C3 is its Fig. 5 coin)"))
    sec.p("The design choices the paper leaves open (sizes, films, the push direction) are derived in "
          "`docs/physics.md`; the flat-top contact pushes the coin away from the clamp (−x), as measured there.")
    return sec


def section_pictures(rep: Report, inputs: Inputs, frames: int, progress: bool) -> Section:
    sec = Section("pictures", "Pictures of the DEA and the coin (the paper's Fig. 4)")
    xdmf = inputs.fields
    if not (xdmf.is_file() and dataset.is_complete(_fields_run(xdmf))):
        sec.lack(f"the displacement fields `{xdmf}` and their run `{_fields_run(xdmf)}`", "report-fields")
        return sec
    from deapull.workflows import site_render
    s3 = site_render.load_scene3d(xdmf)
    rep.source(xdmf, sec)
    rep.source(_fields_run(xdmf), sec)
    stages = site_render.stage_frames(s3)
    sec.p(f"Setup {s3.setup}, rendered off-screen from the solver's field output ({len(s3.fields.times)} frames, "
          "XDMF + HDF5) with matplotlib; colour: displacement magnitude |u| from the reference (flat, "
          "unloaded) configuration. The grey disc is the rigid coin, moved by its x(t) from the run's dataset. "
          "The DEA (20 mm wide) is wider than the coin (10 mm): its corners curl down beside the coin.")
    for key, title in site_render.STAGES:
        name = f"dea_{key}.png"
        site_render.stage_picture(s3, key, stages[key], rep.img / name)
        sec.img(f"img/{name}", f"{s3.setup}, {title}: side view (left) and 3/4 view (right).")
    name = f"dea_{s3.setup}.gif"
    site_render.animation(s3, rep.img / name, frames=frames, progress=progress)
    sec.img(f"img/{name}", f"Animation of {s3.setup}: the 1 s ramp, 3/4 view (GIF).")
    lowest = [float((s3.points + s3.displacement(i))[:, 1].min()) for i in range(len(s3.fields.times))]
    below = [i for i, y in enumerate(lowest) if y < 0.0]
    if below:
        i0, worst = below[0], int(np.argmin(lowest))
        v0 = float(np.interp(s3.fields.times[i0], s3.run_t, s3.run_V))
        sec.p(f"**Caveat:** the DEA's corners beside the coin reach y = {lowest[worst] * 1e3:.2f} mm, below the "
              f"ground (y = 0), from t = {s3.fields.times[i0]:.3f} s (V ≈ {v0:.0f} V) on: the FEM has no contact "
              "between the DEA and the ground, only with the coin.")
        rep.claims.append(Claim("The DEA stays above the table", "– (not shown)",
                                f"no: its corners reach y = {lowest[worst] * 1e3:.2f} mm (below the ground) "
                                f"from {v0:.0f} V", "#pictures", "caveat"))
    sec.p("Paper, Fig. 4: (a) the inactive DEA, (b) the static-friction stage (the DEA bends, the coin stays), "
          "(c) the kinetic stage (the coin moves). Ours shows the same three stages; the paper's ABAQUS mesh had "
          "10 elements per membrane and 20 for the coin, ours is in the model table.")
    return sec


def _crossing(V, g) -> float | None:
    """The V at which ``g`` first becomes >= 0 (linear interpolation; None if never)."""
    idx = np.flatnonzero(g >= 0)
    if idx.size == 0:
        return None
    i = int(idx[0])
    if i == 0:
        return float(V[0])
    w = -g[i - 1] / (g[i] - g[i - 1])
    return float(V[i - 1] + w * (V[i] - V[i - 1]))


def setup_facts(run: dataset.Run) -> dict:
    """The sweep table's row of one dataset: V^T, the friction-cone prediction, slip onset, wall time."""
    col, a = run.columns, run.attrs
    V, x, Fx, Fy = col["V"], col["x"], col["Fx"], col["Fy"]
    m, mu_b, g = run.number("coin_mass_kg"), run.number("coin_mu_b", positive=False), run.number("gravity_m_s2")
    cone = np.abs(Fx) - mu_b * (m * g + Fy)            # >= 0: the ground's friction cone is left
    stick = col.get("stick")
    force = np.abs(Fx) + np.abs(Fy)
    lost = force <= 1e-3 * force.max() if force.max() > 0 else np.zeros_like(force, bool)
    contact_lost = None
    if lost[-1]:
        touching = np.flatnonzero(~lost)
        contact_lost = float(V[int(touching[-1]) + 1]) if touching.size else float(V[0])
    return {"setup": a.get("setup", ""), "rho": num(a, "coin_density_kg_m3"), "mu_t": num(a, "coin_mu_t"),
            "mu_b": mu_b, "mass_g": m * 1e3, "points": len(V), "travel_mm": float(np.abs(x).max()) * 1e3,
            "max_Fy_mN": float(Fy.max()) * 1e3, "max_Fx_mN": float(np.abs(Fx).max()) * 1e3,
            "V_T": _crossing(V, THRESHOLD_M - x),
            "V_cone": _crossing(V, cone), "V_slip": _crossing(V, (stick == 0).astype(float) - 0.5)
            if stick is not None else None, "V_contact_lost": contact_lost,
            "wall_s": num(a, "wall_time_total_s"), "ranks": a.get("mpi_ranks", ""), "commit": a.get("git_commit", "")}


def plot_sweep(runs: dict, png: Path) -> Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(3, 1, figsize=(8, 8.5), sharex=True)
    cmap = plt.get_cmap("tab10")
    for i, (name, run) in enumerate(runs.items()):
        c = run.columns
        style = dict(color=cmap(i % 10), lw=1.2, label=name, ls="-" if i % 2 == 0 else "--")
        ax[0].plot(c["t"], c["x"] * 1e3, **style)
        ax[1].plot(c["t"], c["Fy"] * 1e3, **style)
        ax[2].plot(c["t"], c["Fx"] * 1e3, **style)
    ax[0].set_ylabel("coin x [mm]")
    ax[1].set_ylabel("Fy (pressing) [mN]")
    ax[2].set_ylabel("Fx [mN]")
    ax[2].set_xlabel("t [s] (V = 400 t V)")
    ax[0].legend(ncol=4, fontsize=8)
    for a in ax:
        a.grid(alpha=0.3)
    fig.suptitle("The 8-setup sweep (paper, Fig. 5: C3): static stage, then the coin slides toward −x")
    fig.tight_layout()
    atomic_write(png, lambda p: fig.savefig(p, dpi=100, format="png"), suffix=".png")
    plt.close(fig)
    return png


def section_sweep(rep: Report, inputs: Inputs) -> Section:
    sec = Section("sweep", "The 8-setup sweep (the paper's Fig. 5 and §VI-A timing)")
    runs, absent = {}, []
    for s in SETUPS:
        path = inputs.data / f"{s}.nc"
        if dataset.is_complete(path):
            runs[s] = dataset.read(path, optional=("stick",))
            rep.source(path, sec)
        else:
            absent.append(s)
    if absent:
        sec.lack(f"FEM datasets {', '.join(absent)} in `{inputs.data}/`", "sweep")
    if not runs:
        return sec
    plot_sweep(runs, rep.img / "sweep.png")
    sec.img("img/sweep.png", "x, Fy and Fx against t for every setup, shared axes.")
    facts = [setup_facts(r) for r in runs.values()]
    rows, anchors = [], []
    for f in facts:
        ratio = f["wall_s"] / PAPER_FEM_S if f["wall_s"] else None
        rows.append([f["setup"], fmt(f["rho"] / 1e3 if f["rho"] else None, "g"), fmt(f["mu_t"], "g"),
                     fmt(f["mu_b"], "g"), fmt(f["mass_g"], ".4f"), str(f["points"]), fmt(f["travel_mm"], ".3f"),
                     fmt(f["max_Fy_mN"], ".2f"), fmt(f["V_slip"], ".0f"), fmt(f["V_cone"], ".0f"), fmt(f["V_T"], ".0f"),
                     fmt(f["V_contact_lost"], ".0f"), fmt(f["wall_s"], ".1f"), str(f["ranks"]),
                     fmt(ratio, ".2f")])
        anchors.append(f"sweep-{f['setup']}")
    sec.table(Table(["setup", "ρ g/cm³", "μ_t", "μ_b", "m_c g", "points", "travel mm", "max Fy mN",
                     "V slip onset (FEM)", "V friction cone", "V^T", "V contact lost", "wall s", "ranks",
                     "wall / ABAQUS 130 s"], rows, anchors,
                    caption="Per setup: stages, threshold voltages and wall time"))
    walls = [f["wall_s"] for f in facts if f["wall_s"]]
    pts = [f["points"] for f in facts]
    mean_wall = float(np.mean(walls)) if walls else None
    sec.p("**V^T** (the paper's threshold, §V): the voltage at which the coin first reaches x = −10⁻⁵ m. "
          "**V friction cone**: the prediction from Coulomb's law on the ground, the first V at which the DEA's "
          "horizontal force leaves the cone, |Fx| ≥ μ_b (m_c g + Fy). **V slip onset**: the FEM's own stick → "
          "slip switch. The three agree when the coin starts to slide as soon as the cone is left; V^T lies a "
          "little later (10 µm of travel). The paper gives no V^T per setup; it assumes contact is lost from "
          "300 V on (ours: the last column; – = the DEA still touches the coin at 400 V).")
    if mean_wall is not None:
        sec.p(f"Mean wall time per setup {mean_wall:.1f} s for {np.mean(pts):.0f} points (ABAQUS in the paper: "
              f"130 s for 700 points), {mean_wall / np.mean(pts) * 1e3:.0f} ms per point; ranks as in the table.")
        rep.claims.append(Claim("FEM wall time, one 1 s setup", "130 s (ABAQUS, 700 points)",
                                f"{mean_wall:.1f} s (dolfinx, {np.mean(pts):.0f} points, mean of {len(walls)})",
                                "#sweep-" + facts[0]["setup"],
                                "faster" if mean_wall < PAPER_FEM_S else "slower"))
    rep.claims.append(Claim("Points per setup", "700 (§VI-A); 1000–2000 (§V)",
                            str(min(pts)) if min(pts) == max(pts) else f"{min(pts)}–{max(pts)}",
                            "#sweep-" + facts[0]["setup"]))
    c3 = next((f for f in facts if f["setup"] == "C3"), facts[0])
    two = c3["V_slip"] is not None and c3["travel_mm"] >= 1.0
    rep.claims.append(Claim("Two stages under the ramp (Fig. 4, 5)", "static: Fy rises, no motion; kinetic: "
                            "the coin moves", f"{c3['setup']}: slides from {fmt(c3['V_slip'], '.0f')} V, travel "
                            f"{c3['travel_mm']:.2f} mm", f"#sweep-{c3['setup']}", "same" if two else "differs"))
    return sec


def section_fidelity(rep: Report, inputs: Inputs) -> Section:
    sec = Section("fidelity", "Error against run time (the FEM ladder and the surrogates)")
    csv_path = inputs.fidelity / "fidelity.csv"
    if not rep.found(csv_path, sec, "the fidelity ladder", "fidelity"):
        return sec
    rows = read_csv(csv_path)
    png = inputs.fidelity / "fidelity_pareto.png"
    if png.is_file():
        sec.img(rep.copy_image(png, "fidelity_pareto.png"), "Error against wall time: every rung, Pareto fronts "
                "joined, the shipped default and the reference marked (`docs/fidelity_stability.md`).")
    keys = [("case", "rung", ""), ("kind", "kind", ""), ("elements", "elements", ""), ("dofs", "dofs", ".0f"),
            ("steps", "steps", ".0f"), ("wall_s", "wall s", ".3g"), ("mae_x_mm", "MAE x mm", ".3g"),
            ("mae_Fy_mN", "MAE Fy mN", ".3g"), ("error_pct", "error %", ".3g"), ("on_pareto", "Pareto", ""),
            ("status", "status", "")]
    table_rows = []
    for r in rows:
        table_rows.append([_yes(r.get(k, "")) if not spec else fmt(num(r, k), spec) for k, _, spec in keys])
    sec.table(Table([h for _, h, _ in keys], table_rows, [f"fid-{r.get('case', i)}" for i, r in enumerate(rows)],
                    caption="The ladder (reference: the finest affordable rung)"))
    if not any(r.get("kind", "") not in ("", "fem") for r in rows):
        sec.p("No surrogate on this ladder yet: `mpirun -n 2 deapull fidelity --scene coin_pull --setup C3 --out "
              f"{inputs.fidelity} --surrogate {inputs.experiments}/set1/f-coulomb` adds one (the FEM rungs are "
              "reused).")
    default = next((r for r in rows if r.get("is_default") in ("True", "true", "1")), None)
    if default is not None:
        rep.claims.append(Claim("FEM accuracy of the shipped discretisation", "not reported (ABAQUS C3D8E, 10 "
                                "elements per membrane)", f"{fmt(num(default, 'error_pct'), '.3g')} % against the "
                                "reference rung", f"#fid-{default.get('case')}"))
    return sec


def _yes(value: str) -> str:
    """CSV booleans as yes / no, other text as it is."""
    return {"True": "yes", "False": "no", "true": "yes", "false": "no"}.get(value, value)


def section_stability(rep: Report, inputs: Inputs) -> Section:
    sec = Section("stability", "Stability: stiff and extreme cases")
    md = inputs.stability / "stability.md"
    if not rep.found(md, sec, "the stability table", "stability"):
        return sec
    text = md.read_text()
    tables = markdown_tables(text)
    for line in text.splitlines():
        if line.startswith("Base:"):
            sec.p(line)
    if tables:
        headers, rows = tables[0]
        sec.table(Table(headers, rows, [f"stab-{r[0]}" for r in rows], caption="One row per case"))
        conv = sum(1 for r in rows if len(r) > 1 and r[1] == "yes")
        rep.claims.append(Claim("Robustness (not in the paper)", "–", f"{conv}/{len(rows)} cases converge; the "
                                "rest fail as expected (pull-in, ν = 0.5 displacement)", "#stability"))
    bullets = [line[2:] for line in text.splitlines() if line.startswith("* ")]
    if bullets:
        sec.bullets(bullets)
    return sec


def section_fem_accuracy(rep: Report, inputs: Inputs) -> Section:
    sec = Section("fem-accuracy", "FEM speed and accuracy (issue 12)")
    path = inputs.bench_fem / "bench_fem.json"
    if not rep.found(path, sec, "the FEM benchmark", "bench-fem"):
        return sec
    res = json.loads(path.read_text())
    ref = res.get("reference", {})
    sec.p(f"Reference: {ref.get('label', '–')}, travel {fmt(1e3 * ref['travel_ref_m'], '.4f', 'mm')}"
          if "travel_ref_m" in ref else "Reference: –")
    rows = []
    for label, r in res.items():
        if label in ("sweep", "reference"):
            continue
        rows.append([label, fmt(r["wall_s"], ".1f"), format(130.0 / r["wall_s"], ".1f") + "×", str(r["points"]),
                     str(r["dofs"]), str(r["newton_its"]), fmt(r["travel_mm"], ".4f"),
                     fmt(100 * r["travel_err"], "+.2f", "%"), fmt(100 * r["x_mae"], ".2f", "%")])
    rows.append(["paper (ABAQUS)", "130", "1.0×", "700", "–", "–", "–", "–", "–"])
    sec.table(Table(["run", "wall s", "vs ABAQUS", "points", "dofs", "Newton its", "travel mm", "travel err",
                     "x(t) MAE"], rows, [f"fem-{i}" for i in range(len(rows))],
                    caption="coin_pull C3 on one core; errors against the reference above"))
    if "sweep" in res:
        sw = res["sweep"]
        sec.p(f"The 8-setup sweep under `mpirun -n {sw['np']}`: {fmt(sw['wall_s'], '.1f', 's')} "
              f"(ABAQUS 8 × 130 s = 1040 s).")
        rep.claims.append(Claim("FEM time, 8 setups", "8 × 130 s (ABAQUS)", fmt(sw["wall_s"], ".0f", "s"),
                                "#fem-accuracy"))
    bound = ref.get("error_bound_rel")
    if bound is None:
        sec.p("The reference's own error is not known (it is not a converged estimate), so the errors above "
              "are distances to a finer mesh, not to the continuum answer (docs/fem_accuracy.md).")
    else:
        sec.p(f"The reference's own error bound: ± {fmt(100 * bound, '.2f', '%')} of its travel "
              "(docs/fem_accuracy.md).")
    return sec


def section_protocols(rep: Report, inputs: Inputs) -> Section:
    sec = Section("protocols", "Surrogates on held-out voltage protocols (issue 13)")
    md = inputs.protocols / "protocols.md"
    if not md.is_file() and not step_done("excitation", inputs):
        sec.lack(f"the excitation datasets under `{inputs.excitation}`", "excitation")
    if not rep.found(md, sec, "the held-out-protocol table", "experiments-protocols"):
        return sec
    tables = markdown_tables(md.read_text())
    for k, (headers, rows) in enumerate(tables[:2]):
        sec.table(Table(headers, rows, [f"proto-{k}-{i}" for i in range(len(rows))],
                        caption="x error in % of travel on held-out protocols and coins" if k == 0 else ""))
    png = inputs.protocols / "protocols.png"
    if png.is_file():
        sec.img(rep.copy_image(png, "protocols.png"), "Rollouts on held-out protocols")
    return sec


def section_surrogates(rep: Report, inputs: Inputs) -> Section:
    sec = Section("surrogates", "Surrogates: Table II, box plot, rollouts, speed")
    csv_path = inputs.experiments / "experiments.csv"
    if not rep.found(csv_path, sec, "the experiment sets", "experiments"):
        return sec
    rows = read_csv(csv_path)
    meta = {}
    jpath = inputs.experiments / "experiments.json"
    if jpath.is_file():
        rep.source(jpath, sec)
        meta = json.loads(jpath.read_text())
    paper = meta.get("paper") or PAPER_TABLE2
    kinds = list(dict.fromkeys(r["model"] for r in rows))
    sets = sorted({int(r["set"]) for r in rows})

    def diverged(r) -> bool:
        return r.get("diverged") in ("True", "true", "1")

    def mean(kind, key):
        """Mean over the sets; errors leave diverged rollouts out, times keep them."""
        vals = [num(r, key) for r in rows if r["model"] == kind and (key == "rollout_ms" or not diverged(r))]
        vals = [v for v in vals if v is not None]
        return float(np.mean(vals)) if vals else None

    quantities = [("mae_x_m", "x", 1e-4, "10⁻⁴ m", ".3g"), ("mae_Fx_N", "Fx", 1e-4, "10⁻⁴ N", ".3g"),
                  ("mae_Fy_N", "Fy", 1e-4, "10⁻⁴ N", ".3g"),
                  ("x_error_pct_travel", "x error, % of travel", 1.0, "%", ".3g"),
                  ("rollout_ms", "1 s rollout", 1.0, "ms", ".4g")]
    t_rows, anchors = [], []
    for key, label, scale, unit, spec in quantities:
        cells = [f"{label} ({unit})"]
        for k in kinds:
            v = mean(k, key)
            cells.append(fmt(v / scale if v is not None else None, spec))
        for k in ("f", "lstm", "nn"):
            v = paper.get(key, {}).get(k)
            cells.append(fmt(v / scale if v is not None else None, spec))
        t_rows.append(cells)
        anchors.append(f"table2-{key}")
    div = ["diverged rollouts"] + [str(sum(1 for r in rows if r["model"] == k and diverged(r))) for k in kinds] \
        + ["–"] * 3
    t_rows.append(div)
    anchors.append("table2-diverged")
    sec.table(Table(["mean over sets " + ",".join(map(str, sets))] + [f"ours: {MODEL_LABELS.get(k, k)}" for k in kinds]
                    + ["paper: f", "paper: LSTM", "paper: NN"], t_rows, anchors,
                    caption="Table II: mean absolute errors of 1 s recursive rollouts, ours beside the paper's"))
    sec.p("Set i trains on C_i, early-stops on C_i+1 and tests on C_i+2 (the paper's six sets). Diverged "
          "rollouts are left out of the means and counted in the last row.")
    for name, cap in (("x_error_boxplot.png", "|x error| per set and model (the paper's Fig. 5 box plot)."),
                      ("rollouts.png", "x(t) of the FEM and of each model on each test setup.")):
        p = inputs.experiments / name
        if p.is_file():
            sec.img(rep.copy_image(p, f"experiments_{name}"), cap)
    fem = meta.get("fem_wall_time_s") or {}
    fem_mean = float(np.mean(list(fem.values()))) if fem else None
    s_rows = []
    for k in kinds:
        ms = mean(k, "rollout_ms")
        p_ms = paper.get("rollout_ms", {}).get(k.split("-")[0] if k.startswith("f") else k)
        s_rows.append([MODEL_LABELS.get(k, k), fmt(ms, ".3g"), fmt(p_ms, ".4g"),
                       fmt(fem_mean / (ms / 1e3) if (fem_mean and ms) else None, ".3g"),
                       fmt(PAPER_FEM_S / (p_ms / 1e3) if p_ms else None, ".3g")])
    sec.table(Table(["model", "ours: 1 s rollout ms", "paper ms", "ours: speed-up vs our FEM",
                     "paper: speed-up vs ABAQUS"], s_rows, [f"speed-{k}" for k in kinds],
                    caption="Speed per model (batch 1, CPU)"))
    per_set = [[r["set"], r["test"], MODEL_LABELS.get(r["model"], r["model"])]
               + (["diverged"] * 3 if diverged(r) else [fmt(num(r, "mae_x_m"), ".3g"),
                                                        fmt(num(r, "x_error_pct_travel"), ".3g"),
                                                        fmt(num(r, "mae_Fy_N"), ".3g")])
               + [fmt(num(r, "rollout_ms"), ".3g")] for r in rows]
    sec.table(Table(["set", "test", "model", "MAE x m", "x error % travel", "MAE Fy N", "rollout ms"], per_set,
                    caption="Per set"))
    for k in kinds:
        if k.startswith("f"):
            v = mean(k, "mae_x_m")
            pct = mean(k, "x_error_pct_travel")
            rep.claims.append(Claim(f"MAE of x, {MODEL_LABELS.get(k, k)} (Table II)", "0.34 × 10⁻⁴ m",
                                    _e4(v, "m"), "#table2-mae_x_m", _verdict(v, 0.34e-4)))
            rep.claims.append(Claim(f"x error of {MODEL_LABELS.get(k, k)} relative to the motion", "≤ 5 %",
                                    f"{pct:.3g} % of the travel" if pct is not None else _e4(None, ""),
                                    "#table2-x_error_pct_travel",
                                    "" if pct is None else ("same" if pct <= 5 else "differs")))
    for k, paper_v in (("lstm", 3.86e-4), ("nn", 9.86e-4)):
        if k in kinds:
            v = mean(k, "mae_x_m")
            rep.claims.append(Claim(f"MAE of x, {MODEL_LABELS[k]} (Table II)", f"{paper_v / 1e-4:.2f} × 10⁻⁴ m",
                                    _e4(v, "m"), "#table2-mae_x_m", _verdict(v, paper_v)))
    for k in (k for k in kinds if k.startswith("f")):
        for key, paper_v, label in (("mae_Fx_N", 3.68e-4, "Fx"), ("mae_Fy_N", 12.01e-4, "Fy")):
            v = mean(k, key)
            rep.claims.append(Claim(f"MAE of {label}, {MODEL_LABELS.get(k, k)} (Table II)",
                                    f"{paper_v / 1e-4:.2f} × 10⁻⁴ N", _e4(v, "N"), f"#table2-{key}",
                                    _verdict(v, paper_v)))
    if "f" in kinds:
        ms = mean("f", "rollout_ms")
        rep.claims.append(Claim("1 s rollout of f", "≤ 0.7 s", f"{fmt(ms, '.3g')} ms", "#speed-f",
                                "" if ms is None else ("faster" if ms < 700 else "slower")))
    return sec


def _e4(value, unit: str) -> str:
    """A Table II number in units of 1e-4, or why there is none."""
    return f"{value / 1e-4:.3g} × 10⁻⁴ {unit}" if value is not None else "none: every rollout diverged"


def _verdict(ours, paper) -> str:
    if ours is None:
        return ""
    r = ours / paper
    return "same order" if 0.3 <= r <= 3 else ("better" if r < 1 else "worse")


def section_control(rep: Report, inputs: Inputs) -> Section:
    sec = Section("control", "Control and inference (the paper's Fig. 6, §VI-B/C)")
    csv_path = inputs.control / "control.csv"
    if rep.found(csv_path, sec, "the closed-loop episodes", "control"):
        rows = read_csv(csv_path)
        run_json = inputs.control / "run.json"
        if run_json.is_file():
            rep.source(run_json, sec)
        sec.p("The task (`docs/control.md`): push the coin to x^T = −1 mm in 1 ms steps, |ΔV| ≤ the same limit "
              "for every policy; success is |x − x^T| < 0.01 mm on the true state; 10 episodes per policy, plant "
              "and observation noise. Paper, Fig. 6: C2, mean of 10 episodes with the 25–75 % band; MPC reaches "
              "the target in ≤ 200 iterations, SAC ~10,000, PD ~1,500, the heuristic ~500 (with noise 1 mm).")
        noises = sorted({float(r["noise_std_m"]) for r in rows})
        plants = list(dict.fromkeys(r["plant"] for r in rows))
        policies = list(dict.fromkeys(r["policy"] for r in rows))
        paper_plant = "surrogate:C2" if "surrogate:C2" in plants else plants[0]
        f_rows, anchors = [], []
        for pol in policies:
            paper_it, paper_ms = PAPER_CONTROL.get(pol.split("+")[0], ("–", None))
            for plant in sorted(plants, key=lambda p: p != paper_plant):       # the paper's plant first
                cells = [pol, plant, paper_it, fmt(paper_ms, "g")]
                for noise in noises:
                    sel = [r for r in rows if r["policy"] == pol and r["plant"] == plant
                           and float(r["noise_std_m"]) == noise]
                    its = [num(r, "iterations_to_target") for r in sel if r.get("reached") in ("True", "1")]
                    its = [i for i in its if i is not None]
                    cells.append(f"{np.median(its):.0f} ({len(its)}/{len(sel)})" if its else f"– (0/{len(sel)})")
                ms = [num(r, "ms_per_iteration") for r in rows if r["policy"] == pol and r["plant"] == plant]
                ms = [m for m in ms if m is not None]
                cells.append(fmt(float(np.median(ms)) if ms else None, ".3g"))
                f_rows.append(cells)
                anchors.append(f"control-{pol}" if plant == paper_plant else f"control-{pol}-{plant}")
        heads = (["policy", "plant", "paper: iterations", "paper: ms / it"] + [f"noise {n:g} m" for n in noises]
                 + ["ours: ms / it"])
        sec.table(Table(heads, f_rows, anchors, caption="Iterations to target, median (reached / episodes), ours "
                                                         "beside the paper's (its Fig. 6: f_s,2 = surrogate:C2, "
                                                         "noise 0.001 m)"))
        paper_noise = 1e-3 if 1e-3 in noises else noises[-1]
        for pol in policies:
            sel = [r for r in rows if r["policy"] == pol and r["plant"] == paper_plant
                   and float(r["noise_std_m"]) == paper_noise]
            its = [num(r, "iterations_to_target") for r in sel if r.get("reached") in ("True", "1")]
            its = [i for i in its if i is not None]
            ours = (f"median {np.median(its):.0f} ({len(its)}/{len(sel)} reached)" if its
                    else f"never reached (0/{len(sel)})")
            paper_it = PAPER_CONTROL.get(pol.split("+")[0], ("–",))[0]
            rep.claims.append(Claim(f"Iterations to target, {pol} ({paper_plant}, noise {paper_noise:g} m)",
                                    paper_it, ours, f"#control-{pol}",
                                    _fewer(float(np.median(its)) if its else None, paper_it)))
        md = inputs.control / "table.md"
        if md.is_file():
            rep.source(md, sec)
            tables = markdown_tables(md.read_text())
            if tables:
                sec.table(Table(*tables[0], caption="Per policy, plant and noise (`table.md` of the run)"))
        for pattern, cap in (("position_*.png", "coin position, mean and 25–75 % band per policy (Fig. 6)"),
                             ("voltage_*.png", "voltage per policy"),
                             ("inferred_*.png", "inferred φ per iteration beside the true value")):
            # the paper's Fig. 6 first: plant f_s,2 (C2), the paper's noise (largest first)
            for png in sorted(inputs.control.glob(pattern),
                              key=lambda p: ("_C2_" not in p.name, _noise_key(p.stem), p.stem)):
                sec.img(rep.copy_image(png, f"control_{png.name}"), f"`{png.stem}`: {cap}.")
        inf_rows = []
        for pol in policies:
            for q, label in (("mass_kg", "m_c"), ("mu_b", "μ_b"), ("mu_t", "μ_t")):
                errs = [abs(num(r, f"inferred_{q}") / num(r, f"true_{q}") - 1) * 100 for r in rows if r["policy"] == pol
                        and num(r, f"inferred_{q}") is not None and num(r, f"true_{q}")]
                if errs:
                    inf_rows.append([pol, label, f"{np.median(errs):.3g}", f"{max(errs):.3g}", str(len(errs))])
        if inf_rows:
            sec.table(Table(["policy", "φ", "median error %", "max error %", "episodes"], inf_rows,
                            [f"infer-{r[0]}-{i}" for i, r in enumerate(inf_rows)],
                            caption="Online inference at the end of the episodes (paper: m_c within 10 % after "
                                    "2,000 iterations, μ_b within 300)"))
            mc = [r for r in inf_rows if r[1] == "m_c"]
            if mc:
                rep.claims.append(Claim("Inferred m_c", "≤ 10 % error within 2,000 iterations",
                                        f"median {mc[0][2]} % ({mc[0][0]})", f"#infer-{mc[0][0]}-0"))
        else:
            sec.p("No policy in this run inferred φ (the MPC does): `make control` runs all four.")
    bench = inputs.bench_control / "bench_control.json"
    if rep.found(bench, sec, "the MPC step beside mpc.pytorch", "bench-control"):
        b = json.loads(bench.read_text())
        b_rows = [[r.get("solver", ""), fmt(r.get("median_ms"), ".3g"), fmt(r.get("median_ms_per_iteration"), ".3g"),
                   fmt(r.get("mean_cost"), ".5g")] for r in b.get("rows", [])]
        sec.table(Table(["solver", "median ms / MPC step", "ms / iteration", "mean cost"], b_rows,
                        [f"mpc-{i}" for i in range(len(b_rows))],
                        caption=f"MPC step (horizon {b.get('horizon')}, {b.get('iterations')} iterations), ours beside "
                                f"mpc.pytorch on the same problem; paper: {b.get('paper_s', 1.2)} s per iteration"))
        if b.get("mpc_pytorch_skipped"):
            sec.p(f"mpc.pytorch was not run: {b['mpc_pytorch_skipped']}")
        if b_rows:
            rep.claims.append(Claim("MPC time per iteration", "1.2 s (mpc.pytorch)", f"{b_rows[0][1]} ms "
                                    f"({b_rows[0][0]})", "#mpc-0"))
    return sec


def _fewer(ours, paper: str) -> str:
    """Our iteration count against the paper's "≤ 200" / "~1,500": fewer, similar or more."""
    digits = re.sub(r"[^0-9]", "", paper)
    if ours is None or not digits:
        return "never reached" if ours is None and digits else ""
    ref = float(digits)
    return "fewer" if ours < 0.7 * ref else ("more" if ours > 1.3 * ref else "similar")


def _noise_key(stem: str) -> float:
    m = re.search(r"noise([0-9.e+-]+)$", stem)
    try:
        return -float(m.group(1)) if m else 0.0
    except ValueError:
        return 0.0


def _versions() -> dict:
    import importlib
    import importlib.metadata as md
    out = {"python": platform.python_version()}
    for dist, module in VERSIONS:
        try:
            out[dist] = md.version(dist)
            continue
        except md.PackageNotFoundError:
            pass
        try:
            out[dist] = str(getattr(importlib.import_module(module), "__version__", "?"))
        except Exception:   # noqa: BLE001 — a package that fails to import is "not installed" here
            continue
    return out


def _machine() -> str:
    mem = ""
    try:
        kb = int(next(line.split()[1] for line in open("/proc/meminfo") if line.startswith("MemTotal")))
        mem = f", {kb / 2 ** 20:.0f} GiB RAM"
    except (OSError, StopIteration, ValueError):
        pass
    cpu = platform.processor() or platform.machine()
    try:
        cpu = next(line.split(":", 1)[1].strip() for line in open("/proc/cpuinfo") if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return f"{platform.platform()}, {cpu}, {os.cpu_count()} cores{mem}"


def section_provenance(rep: Report) -> Section:
    sec = Section("provenance", "Provenance of every number")
    commit = provenance.git_commit()
    sec.p(f"Page built {_dt.datetime.now(_dt.timezone.utc).strftime('%Y-%m-%d %H:%M UTC')} by `deapull report` at "
          f"commit `{commit[:12]}` on {_machine()}. Each study's files say which commit made them (last column); "
          "a section's Sources line links here.")
    v = _versions()
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


def section_summary(rep: Report) -> Section:
    sec = Section("summary", "Does this reproduce the paper? Paper against ours")
    rep.claims.sort(key=lambda c: c.verdict == "caveat")          # stable: the caveats last
    if rep.claims:
        sec.table(Table(["result", "paper", "ours", "where", "verdict"],
                        [[c.what, c.paper, c.ours, f"[row]({c.anchor})", c.verdict or "–"] for c in rep.claims],
                        [f"claim-{i}" for i in range(len(rep.claims))],
                        caption="Each paper number beside ours; 'row' links to the row it comes from", wrap=True))
    missing = [m for s in rep.sections for m in s.missing]
    if missing:
        steps = list(dict.fromkeys(step for _, step in missing))
        sec.p("Not on this page yet (each section says what and how): " + "; ".join(
            f"{STEP[s].what} — `{STEP[s].make}`" for s in steps) + ". `make report FULL=1` runs the missing steps "
            "(they resume) and rebuilds the page.")
    sec.p("Where we differ by design: the FEM is dolfinx (mixed u–p hexahedra, penalty contact with regularised "
          "Coulomb friction), not ABAQUS; the flat-top contact pushes the coin away from the clamp (−x) rather than "
          "pulling it (`docs/physics.md`); the surrogate adds a tip-contact law beside the paper's; control limits "
          "|ΔV| per step equally for every policy (`docs/control.md`).")
    return sec


# --- the build -----------------------------------------------------------------------------

def build(out, inputs: Inputs, frames: int = 30, progress: bool = True) -> dict:
    """Build the report into ``out`` from the outputs in ``inputs``; returns its summary
    (``index``, ``markdown``, ``missing`` steps, ``claims``, ``images``)."""
    from tqdm import tqdm
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {str(out)!r}: exists and is not a folder")
    if frames < 2:
        raise InputError(f"--frames {frames}: need at least 2 frames for the animation")
    if inputs.data.exists() and not inputs.data.is_dir():
        raise InputError(f"--data {str(inputs.data)!r}: not a folder")
    rep = Report(out)
    rep.img.mkdir(parents=True, exist_ok=True)
    makers = [("model", lambda: section_model(rep)),
              ("pictures", lambda: section_pictures(rep, inputs, frames, progress)),
              ("sweep", lambda: section_sweep(rep, inputs)),
              ("fem-accuracy", lambda: section_fem_accuracy(rep, inputs)),
              ("fidelity", lambda: section_fidelity(rep, inputs)),
              ("stability", lambda: section_stability(rep, inputs)),
              ("surrogates", lambda: section_surrogates(rep, inputs)),
              ("protocols", lambda: section_protocols(rep, inputs)),
              ("control", lambda: section_control(rep, inputs))]
    for name, make in tqdm(makers, desc="report", unit="section", disable=not progress or None):
        log.debug("report: section %s", name)
        rep.sections.append(make())
    rep.sections.insert(0, section_summary(rep))
    rep.sections.append(section_provenance(rep))
    _drop_stale_images(rep)
    title = "deapull: reproduction report of Lahariya et al., IROS 2022"
    lead = ["The whole pipeline on one page — FEM (dolfinx) of a dielectric-elastomer actuator pushing a coin, "
            "physics-informed surrogates (torch), closed-loop control — beside the paper's numbers "
            "(“Learning physics-informed simulation models for soft robotic manipulation: a case study with "
            "dielectric elastomer actuators”). Built by `deapull report` from the outputs found; nothing is "
            "recomputed here. The [summary](#summary) links each paper number to its row."]
    index = write_text(out / "index.html", render_html(rep, title, lead))
    md = write_text(out / "report.md", render_markdown(rep, title, lead))
    found = {step for s in rep.sections for _, step in s.missing}
    missing = [s.name for s in STEPS if s.name in found]          # in pipeline order
    summary = {"index": str(index), "markdown": str(md), "missing": missing,
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
