"""``deapull report``: the page builds from partial tiny outputs and names what is missing,
its images are real, every link points at a row, and a real browser loads it cleanly."""
import csv
import json
import re
import shutil
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from deapull.errors import InputError
from deapull.io import write_csv
from deapull.paper import TABLE2
from deapull.workflows import report
from deapull.workflows.report import assemble, pictures
from deapull.workflows.report.document import Claim, Report, Section
from deapull.workflows.report.tabular import read_csv
from deapull.workflows.report.check import BrowserUnavailable, check_page, find_browser
from tests.conftest import REPO, SHARP, SWEEP

ALL_STEPS = [s.name for s in report.STEPS]


def _cli(*args, cwd=REPO):
    return subprocess.run([sys.executable, "-m", "deapull.workflows", *args], cwd=cwd, capture_output=True,
                          text=True, timeout=300)


def _inputs(tmp_path, data) -> report.Inputs:
    return report.Inputs.under(tmp_path / "out", data)


def _sweep(tmp_path, setups) -> Path:
    data = tmp_path / "data"
    data.mkdir(exist_ok=True)
    for s in setups:
        shutil.copy(SWEEP / f"{s}.nc", data / f"{s}.nc")
    return data


class _Page(HTMLParser):
    """ids, local hrefs, image sources and every external reference of an HTML page."""

    def __init__(self):
        super().__init__()
        self.ids, self.hrefs, self.imgs, self.external = set(), [], [], []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if "id" in a:
            self.ids.add(a["id"])
        for key in ("href", "src"):
            v = a.get(key)
            if v and re.match(r"^[a-z]+:", v):
                self.external.append(v)
        if tag == "a" and a.get("href", "").startswith("#"):
            self.hrefs.append(a["href"][1:])
        if tag == "img":
            self.imgs.append(a["src"])


def _parse(index: Path) -> _Page:
    page = _Page()
    page.feed(index.read_text())
    return page


def _png_ok(path: Path) -> None:
    from PIL import Image
    assert path.is_file() and path.stat().st_size > 2000, path
    with Image.open(path) as im:
        w, h = im.size
        assert w > 100 and h > 100
        px = np.asarray(im.convert("L"), dtype=float)
    assert px.std() > 5, f"{path}: a blank image"


# --- partial outputs ---------------------------------------------------------------------

def test_missing_hints_name_the_folders_the_report_reads():
    """``make report OUT=out/resolved``: a missing step's hint is ``make <step> OUT=out/resolved``
    and its command writes there; at the defaults the hint is the bare target. Broken once: the
    hint printed the default paths (``--out out/stability``) whatever OUT was."""
    moved = report.Inputs.under("out/resolved", "data")
    make, command = report.STEP["stability"].hint(moved)
    assert make == "make stability OUT=out/resolved" and command.endswith("--out out/resolved/stability")
    make, command = report.STEP["report-fields"].hint(moved)
    assert make == "make report-fields OUT=out/resolved" and "--out out/resolved/report_fields" in command
    make, command = report.STEP["excitation"].hint(report.Inputs.under("out/resolved", "data2"))
    assert make == "make sweep PROTOCOLS=excitation DATA=data2" and command.endswith("--out data2/excitation")
    assert report.STEP["sweep"].hint(report.Inputs()) == (
        "make sweep", "mpirun -n 2 deapull sweep --scene coin_pull --out data")
    for step in report.STEPS:
        make, command = step.hint(moved)
        assert make.startswith(step.make) and "{" not in command, (make, command)


def test_report_from_partial_outputs_names_what_is_missing(tmp_path):
    data = _sweep(tmp_path, ["C1", "C2", "C3"])
    out = tmp_path / "report"
    summary = report.build(out, _inputs(tmp_path, data), progress=False)
    studies = [s for s in ALL_STEPS if s != "fem-study"]     # the contact reference is committed
    assert summary["missing"] == studies          # 5 setups absent, and every other study
    md, html = (out / "report.md").read_text(), (out / "index.html").read_text()
    for text in (md, html):
        assert "C4, C5, C6, C7, C8" in text and "make sweep" in text
        for step in report.STEPS:
            assert step.name == "fem-study" or step.make in text, step.make
    # one block per missing output: sweep, fields, bench-fem, fidelity, stability, experiments,
    # excitation + experiments-protocols, control, control-fem, bench-control
    assert md.count("**Missing:**") == 11 and html.count('class="missing"') == 11
    # the sweep's rows: one per dataset found, with V^T and the cone prediction filled in
    rows = re.findall(r'<tr id="sweep-(C\d)">(.*?)</tr>', html)
    assert [r[0] for r in rows] == ["C1", "C2", "C3"]
    for _, cells in rows:
        values = re.findall(r"<td>(.*?)</td>", cells)
        v_cone, v_t = float(values[9]), float(values[10])
        assert 0 < v_cone <= v_t <= 400
    _png_ok(out / "img" / "sweep.png")
    page = _parse(out / "index.html")
    # the error-against-run-time figure is drawn even so: the committed reference's levels, and the
    # studies not run named on it
    assert page.imgs == ["img/sweep.png", "img/error_time.png"]
    assert not page.external
    assert json.loads((out / "report.json").read_text())["missing"] == studies


def test_report_with_every_study_links_each_paper_number_to_its_row(tmp_path):
    data = _sweep(tmp_path, report.SETUPS)
    inputs = _inputs(tmp_path, data)
    _fake_studies(inputs)
    out = tmp_path / "report"
    summary = report.build(out, inputs, progress=False)
    assert summary["missing"] == ["report-fields"]
    # the page is built from results files (CSV, JSON, datasets, figures), never a stage's Markdown:
    # the fixture's studies write none, and a Markdown source would be registered here
    assert summary["sources"] and not [s["path"] for s in summary["sources"] if s["path"].endswith(".md")]
    html = (out / "index.html").read_text()
    page = _parse(out / "index.html")
    assert not page.external
    dangling = [h for h in page.hrefs if h not in page.ids]
    assert not dangling, dangling
    claims = {c["what"]: c for c in summary["claims"]}
    assert claims["MAE of x, f (paper's law) (Table II)"]["paper"] == "0.34 × 10⁻⁴ m"
    assert claims["MAE of x, f (paper's law) (Table II)"]["ours"] == "0.5 × 10⁻⁴ m"
    assert claims["MAE of x, f (paper's law) (Table II)"]["anchor"] == "#table2-mae_x_m"
    assert "Iterations to target, mpc (surrogate:C2, noise 0.001 m)" in claims
    assert claims["Iterations to target, mpc (surrogate:C2, noise 0.001 m)"]["ours"] == "median 151 (3/3 reached)"
    row = re.search(r'<tr id="table2-mae_x_m">(.*?)</tr>', html).group(1)
    assert re.findall(r"<td>(.*?)</td>", row) == ["x (10⁻⁴ m)", "0.5", "2", "0.34", "3.86", "9.86"]
    for img in page.imgs:
        assert (out / img).is_file() and (out / img).stat().st_size > 0, img
    assert "img/control_position_surrogate_C2_noise0.001.png" in page.imgs
    assert "img/control_bands.png" in page.imgs and "img/error_time.png" in page.imgs
    assert re.search(r'<tr id="stab-baseline">', html) and re.search(r'<tr id="fid-ref">', html)
    # the ladder says which fidelity it refined (make fidelity: resolved, the datasets')
    fid = (out / "report.md").read_text().split('<a id="fidelity"></a>')[1].split('<a id="stability"></a>')[0]
    assert "fidelity `resolved`" in fid and "Shipped default (default, hex Q2): error 1.50 %" in fid
    # its hint to add a surrogate names that fidelity, so the rungs are reused, not re-solved as written
    assert "--setup C3 --fidelity resolved --out" in fid
    # and which rung ran on more ranks than the others (its time is shorter than one core's)
    assert "Ranks per rung: 1, except ref on 2" in fid
    # the ladder's CSV names its fidelity, so the hint keeps it without the notes file, which the page
    # then names as missing
    (inputs.fidelity / "fidelity.json").unlink()
    report.build(tmp_path / "r2", inputs, progress=False)
    fid2 = (tmp_path / "r2" / "report.md").read_text().split('<a id="fidelity"></a>')[1].split('<a id="stability"></a>')[0]
    assert "--setup C3 --fidelity resolved --out" in fid2 and "fidelity `resolved`" not in fid2
    assert "fidelity.json" in fid2
    points = list(csv.DictReader(open(out / "tables" / "error-time-points.csv")))
    assert [p["label"] for p in points if p["group"] == "FEM ladder"] == ["ref (2 ranks)"]
    assert re.findall(r"<td>(.*?)</td>", re.search(r'<tr id="fid-ref">(.*?)</tr>', html).group(1))[:5] == [
        "ref", "fem", "hex Q2", "900", "2"]
    assert "mpc.pytorch" in html
    # the FEM closed loop: counted from its CSV (one of the two fake episodes settled)
    fem = claims["The MPC on the FEM plant (noise 0.1 mm)"]
    assert fem["ours"] == "settled in 1/2 episodes; 1 plant(s) cannot reach the target (fem:C5)"
    assert fem["anchor"] == "#control-fem-0"
    assert re.search(r'<tr id="control-fem-2"><td>fem:C5</td>.*?<td>unreachable</td>', html)
    assert re.search(r'<tr id="control-fem-1">', html) and "img/control_fem_control_fem_position_fem_C1_noise0.0001.png" \
        in page.imgs
    # provenance: every source file listed with its hash
    for src in summary["sources"]:
        assert src["anchor"] in page.ids and len(src["sha256"]) == 12


def test_fem_section_names_a_missing_contact_reference_and_gives_the_bench_against_it(tmp_path):
    data = _sweep(tmp_path, report.SETUPS)
    inputs = report.Inputs.under(tmp_path / "out", data, reference=tmp_path / "none" / "contact_reference.json")
    _fake_studies(inputs)
    report.build(tmp_path / "r1", inputs, progress=False)
    text = (tmp_path / "r1" / "report.md").read_text()
    assert "the contact reference" in text and "make fem-study" in text
    assert "data fidelity (scene file) | 10.0 | 13.00× |" in text and "+1.60 %" in text.replace("−", "-")


def test_rebuild_drops_images_no_longer_shown(tmp_path):
    data = _sweep(tmp_path, report.SETUPS)
    inputs = _inputs(tmp_path, data)
    _fake_studies(inputs)
    out = tmp_path / "report"
    report.build(out, inputs, progress=False)
    assert (out / "img" / "fidelity_pareto.png").is_file()
    shutil.rmtree(inputs.fidelity)
    summary = report.build(out, inputs, progress=False)
    assert not (out / "img" / "fidelity_pareto.png").exists() and "fidelity" in summary["missing"]


def test_a_section_is_one_function_registered_in_one_place(tmp_path, monkeypatch):
    """A function of the Report added to assemble.SECTIONS shows on the page, in the contents, and
    its claim and missing step reach the summary."""
    def extra(rep: Report) -> Section:
        sec = Section("extra", "An extra section")
        sec.p(f"reads `{rep.inputs.data}`")
        rep.claims.append(Claim("An extra number", "1", "2", "#extra", "differs"))
        sec.lack("the extra study", "control")
        return sec

    monkeypatch.setattr(assemble, "SECTIONS", assemble.SECTIONS + (("extra", extra),))
    out = tmp_path / "report"
    summary = report.build(out, _inputs(tmp_path, tmp_path / "data"), progress=False)
    md = (out / "report.md").read_text()
    assert "## An extra section" in md and "[An extra section](#extra)" in md
    assert md.index("## An extra section") > md.index("## Control") and f"reads `{tmp_path / 'data'}`" in md
    assert summary["claims"][-1]["what"] == "An extra number" and "control" in summary["missing"]
    assert '<section id="extra"><h2>An extra section</h2>' in (out / "index.html").read_text()


def _png(path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(3, 2))
    ax.plot([0, 1], [0, 1])
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)


def _fake_studies(inputs: report.Inputs) -> None:
    """Tiny outputs of every study, in the formats their commands write."""
    write_csv(inputs.fidelity / "fidelity.csv",
              [dict(case="ref", kind="fem", fidelity="resolved", status="ok", elements="hex Q2", dofs=900, ranks=2,
                    steps=50, wall_s=9.0, mae_x_mm=0.0, error_pct=0.0, is_reference=True, is_default=False),
               dict(case="default", kind="fem", fidelity="resolved", status="ok", elements="hex Q2", dofs=300, ranks=1,
                    steps=50, wall_s=2.0, mae_x_mm=0.01, error_pct=1.5, is_reference=False, is_default=True)],
              ("case", "kind", "fidelity", "status", "elements", "dofs", "ranks", "steps", "wall_s", "mae_x_mm", "error_pct",
               "is_reference", "is_default"))
    (inputs.fidelity / "fidelity.json").write_text(json.dumps({"schema": 1, "notes": [
        "Scene `coin_pull`, fidelity `resolved`, setup `C3`, rungs `quick`.", "Reference rung: `ref` (900 dofs).",
        "Ranks per rung: 1, except ref on 2: the solve time of that rung is not on the others' one-core scale.",
        "Shipped default (default, hex Q2): error 1.50 %."]}))
    _png(inputs.fidelity / "fidelity_pareto.png")
    inputs.stability.mkdir(parents=True)
    (inputs.stability / "stability.json").write_text(json.dumps(
        {"schema": 1, "header": "Base: `coin_pull` C3. git 0123456789ab, dolfinx 0.5.2.",
         "table": {"headers": ["case", "converged", "outcome"],
                   "rows": [["baseline", "yes", "converged"], ["pullin", "no", "failed: DIVERGED_MAX_IT"]]},
         "pull_in": ["`pullin`: detected at V = 478 V."], "not_as_expected": []}))
    (inputs.stability / "stability.csv").write_text("case\nbaseline\npullin\n")
    rows = [dict(set=i, train=f"C{i}", val=f"C{i + 1}", test=f"C{i + 2}", model=m, mae_x_m=e, mae_Fx_N=1e-4,
                 mae_Fy_N=2e-4, x_error_pct_travel=3.0, rollout_ms=40.0, diverged=False)
            for i in (1, 2) for m, e in (("f", 0.5e-4), ("nn", 2e-4))]
    write_csv(inputs.experiments / "experiments.csv", rows, list(rows[0]))
    (inputs.experiments / "experiments.json").write_text(json.dumps(
        {"rows": rows, "paper": TABLE2, "fem_wall_time_s": {"C3": 60.0}}))
    for name in ("x_error_boxplot.png", "rollouts.png"):
        _png(inputs.experiments / name)
    episodes = [dict(policy=p, plant=f"surrogate:C{c}", noise_std_m=n, episode=k, reached=True,
                     iterations_to_target=it + k, ms_per_iteration=0.5, inferred_mass_kg=1.4e-3 if p == "mpc" else "",
                     true_mass_kg=1.36e-3)
                for p, it in (("mpc", 150), ("pd", 1500)) for c in (1, 2) for n in (0.0, 1e-3) for k in range(3)]
    write_csv(inputs.control / "control.csv", episodes, list(episodes[0]))
    (inputs.control / "run.json").write_text(json.dumps({"git_commit": "fedcba9876543210"}))
    (inputs.control / "summary.json").write_text(json.dumps(
        {"schema": 2, "groups": [], "table": {"headers": ["policy", "reached"], "rows": [["mpc", "3/3"], ["pd", "3/3"]]}}))
    np.savez(inputs.control / "traces.npz", **{f"{e['policy']}|{e['plant']}|{e['noise_std_m']:g}|{e['episode']}|x_m":
                                              np.linspace(0, -1e-3, 20 + 5 * e["episode"]) for e in episodes})
    for noise in ("0", "0.001"):
        _png(inputs.control / f"position_surrogate_C2_noise{noise}.png")
    fem = [dict(policy="mpc", plant=f"fem:C{c}", noise_std_m=1e-4, setpoints_mm="-1", iterations_per_setpoint="900",
                iterations_to_target=900, setpoints_settled=1, settled=c != 2, reached=True, overshoot_m=0.0,
                final_abs_error_m=4e-6, plant_ms_per_step=60.0, episode_wall_s=90.0, status="ok") for c in (1, 2)]
    fem.append({**{k: "" for k in fem[0]}, "policy": "mpc", "plant": "fem:C5", "noise_std_m": 1e-4, "setpoints_mm": "-1", "reached": False,
                "settled": False, "status": "unreachable: --target-mm -1: fem:C5 cannot reach it"})
    inputs.control_fem.mkdir(parents=True)
    write_csv(inputs.control_fem / "control.csv", fem, list(fem[0]))
    _png(inputs.control_fem / "position_fem_C1_noise0.0001.png")
    inputs.bench_fem.mkdir(parents=True)
    (inputs.bench_fem / "bench_fem.json").write_text(json.dumps(
        {"runs": {"data fidelity (scene file)": {"wall_s": 10.0, "points": 722, "dofs": 1587, "newton_its": 4500,
                                                 "x_at_t_mm": -1.116, "travel_mm": 1.326, "error_percent": 1.6,
                                                 "min_contact_points": 25}},
         "sweep": {"wall_s": 70.0, "np": 2},
         "reference": {"file": "contact_reference.json", "x_at_t_mm": -1.1, "time_s": 0.95, "bound_percent": 0.5}}))
    inputs.protocols.mkdir(parents=True)
    (inputs.protocols / "protocols.json").write_text(json.dumps(
        {"tables": [{"headers": ["model", "ramp", "triangle"],
                     "rows": [["f (tip memory)", "0.06", "0.16"], ["NN", "7.74", "5.36"]]}]}))
    _png(inputs.protocols / "protocols.png")
    inputs.bench_control.mkdir(parents=True)
    (inputs.bench_control / "bench_control.json").write_text(json.dumps(
        {"rows": [{"solver": "ours", "median_ms": 30.0, "median_ms_per_iteration": 1.5, "mean_cost": 0.01},
                  {"solver": "mpc.pytorch", "median_ms": 900.0, "median_ms_per_iteration": 45.0, "mean_cost": 0.01}],
         "horizon": 20, "iterations": 20, "paper_s": 1.2, "mpc_pytorch_skipped": ""}))


# --- pictures from field output ----------------------------------------------------------------

def _box_hex27(nx, ny, nz, size=(0.04, 0.003, 0.02), origin=(-0.04, 0.00625, -0.01)):
    """A box of nx × ny × nz 27-node hexahedra: node coordinates and cells (nodes shuffled per cell)."""
    shape = (2 * nx + 1, 2 * ny + 1, 2 * nz + 1)
    axes = [np.linspace(o, o + s, n) for o, s, n in zip(origin, size, shape)]
    X = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    ids = np.arange(len(X)).reshape(shape)
    rng = np.random.default_rng(0)
    cells = [rng.permutation(ids[2 * i:2 * i + 3, 2 * j:2 * j + 3, 2 * k:2 * k + 3].ravel())
             for i in range(nx) for j in range(ny) for k in range(nz)]
    return X, np.array(cells)


def _write_fields(folder: Path, times, nx=4) -> Path:
    """An XDMF + HDF5 field file laid out as dolfinx 0.5 writes it, the DEA bending down over time."""
    import h5py
    X, cells = _box_hex27(nx, 2, 2)
    keys = [f"{t:.17g}".replace(".", "_") for t in times]
    with h5py.File(folder / "C3_fields.h5", "w") as f:
        f["Mesh/mesh/geometry"] = X
        f["Mesh/mesh/topology"] = cells
        for t, key in zip(times, keys):
            s = (X[:, 0] / -0.04) ** 2               # 0 at the clamp, 1 at the tip
            f[f"Function/displacement/{key}"] = np.column_stack([-1e-3 * t * s, -4e-3 * s - 3e-3 * t * s, 0 * s])
    grids = "".join(
        f'<Grid Name="displacement" GridType="Uniform"><xi:include xpointer="x"/><Time Value="{t!r}"/>'
        f'<Attribute Name="displacement" AttributeType="Vector" Center="Node"><DataItem Dimensions="{len(X)} 3" '
        f'Format="HDF">C3_fields.h5:/Function/displacement/{key}</DataItem></Attribute></Grid>'
        for t, key in zip(times, keys))
    xdmf = folder / "C3_fields.xdmf"
    xdmf.write_text(
        '<?xml version="1.0"?><Xdmf Version="3.0" xmlns:xi="http://www.w3.org/2001/XInclude"><Domain>'
        f'<Grid Name="mesh" GridType="Uniform"><Topology TopologyType="Hexahedron_27" NumberOfElements="{len(cells)}" '
        f'NodesPerElement="27"><DataItem Dimensions="{len(cells)} 27" NumberType="Int" Format="HDF">'
        'C3_fields.h5:/Mesh/mesh/topology</DataItem></Topology><Geometry GeometryType="XYZ">'
        f'<DataItem Dimensions="{len(X)} 3" Format="HDF">C3_fields.h5:/Mesh/mesh/geometry</DataItem></Geometry></Grid>'
        f'<Grid Name="displacement" GridType="Collection" CollectionType="Temporal">{grids}</Grid></Domain></Xdmf>')
    shutil.copy(SWEEP / "C3.nc", folder / "C3.nc")      # the run: x(t), stick, the scene (coin)
    return xdmf


@pytest.mark.parametrize("sink_um, verdict", [(0.5, "yes"), (750.0, "no")])
def test_a_dea_resting_on_the_table_is_judged_by_the_penalty_tolerance(tmp_path, sink_um, verdict):
    # the synthetic tip sinks to its lowest y at t = 1; a table put sink_um above that point
    fields = tmp_path / "out" / "report_fields"
    fields.mkdir(parents=True)
    xdmf = _write_fields(fields, np.linspace(0, 1, 5))
    s3 = pictures.load_scene3d(xdmf)
    lowest = min(float((s3.points + s3.displacement(i))[:, 1].min()) for i in range(len(s3.fields.times)))
    height = lowest + sink_um * 1e-6
    run = xr.load_dataset(fields / "C3.nc")
    run.attrs["scene_toml"] += f"\n[table]\nheight_m = {height!r}\nmu_g = 0.5\npenalty_N_m3 = 1e11\n"
    run["table_penetration_m"] = ("step", np.zeros(run.sizes["step"]), {"units": "m"})
    run.to_netcdf(fields / "C3.nc", engine="h5netcdf")
    out = tmp_path / "report"
    report.build(out, _inputs(tmp_path, _sweep(tmp_path, ["C3"])), frames=3, progress=False)
    text = (out / "report.md").read_text()
    assert "rests on the table" in text and "below the ground" not in text
    assert f"{verdict}: it sinks ≤ {sink_um:.2f} µm into the table" in text


def test_boundary_faces_of_a_hex27_box():
    X, cells = _box_hex27(3, 2, 1)
    polys = pictures.boundary_faces(X, cells, "Hexahedron_27")
    # each element face on the boundary split in 4 quads
    assert len(polys) == 4 * 2 * (3 * 2 + 2 * 1 + 3 * 1)
    on_boundary = np.isclose(X, X.min(0)) | np.isclose(X, X.max(0))
    assert all(on_boundary[list(p)].all(axis=0).any() for p in polys)   # every quad lies in one box face


def test_half_model_is_mirrored_to_the_whole_box():
    X, cells = _box_hex27(2, 1, 1, size=(0.04, 0.003, 0.01), origin=(-0.04, 0.00625, 0.0))
    points, polys = pictures.mirror_z(X, pictures.boundary_faces(X, cells, "Hexahedron_27"))
    full, full_cells = _box_hex27(2, 1, 2)
    assert len(polys) == len(pictures.boundary_faces(full, full_cells, "Hexahedron_27")) == 64
    assert np.allclose(points[:, 2].min(), -0.01) and not any(np.allclose(points[list(p), 2], 0.0) for p in polys)


def test_pictures_and_animation_from_field_output(tmp_path):
    fields = tmp_path / "out" / "report_fields"
    fields.mkdir(parents=True)
    _write_fields(fields, np.linspace(0, 1, 9))
    out = tmp_path / "report"
    summary = report.build(out, _inputs(tmp_path, _sweep(tmp_path, ["C3"])), frames=5, progress=False)
    assert "report-fields" not in summary["missing"]
    for stage in ("rest", "static", "kinetic"):
        _png_ok(out / "img" / f"dea_{stage}.png")
    from PIL import Image
    with Image.open(out / "img" / "dea_C3.gif") as gif:
        assert gif.n_frames == 5 and gif.size[0] > 100
    a, b = (np.asarray(Image.open(out / "img" / f"dea_{s}.png").convert("L"), float) for s in ("rest", "kinetic"))
    h, w = min(a.shape[0], b.shape[0]), min(a.shape[1], b.shape[1])     # their colour bars' labels differ
    assert np.abs(a[:h, :w] - b[:h, :w]).mean() > 1.0    # the DEA moved between the stages
    # the synthetic tip sinks to y = -0.75 mm at t = 1: the page says so
    assert "reach y = -0.75 mm, below the ground" in (out / "report.md").read_text()
    page = _parse(out / "index.html")
    assert {"img/dea_rest.png", "img/dea_static.png", "img/dea_kinetic.png", "img/dea_C3.gif",
            "img/section_static.png", "img/section_kinetic.png"} <= set(page.imgs)
    for stage in ("static", "kinetic"):
        _png_ok(out / "img" / f"section_{stage}.png")
    # the field file ships beside the page for ParaView, linked (broken once: the copy left out)
    for name in ("C3_fields.xdmf", "C3_fields.h5"):
        assert (out / "fields" / name).read_bytes() == (fields / name).read_bytes()
        assert f'href="fields/{name}"' in (out / "index.html").read_text()
    assert "ParaView" in (out / "report.md").read_text()


def test_stages_pick_the_frame_before_sliding(tmp_path):
    _write_fields(tmp_path, np.linspace(0, 1, 11))
    s3 = pictures.load_scene3d(tmp_path / "C3_fields.xdmf")
    stages = pictures.stage_frames(s3)
    t_slip = s3.run_t[int(np.argmax(s3.stick == 0))]
    assert stages["rest"] == 0 and stages["kinetic"] == 10
    assert s3.fields.times[stages["static"]] < t_slip <= s3.fields.times[stages["static"] + 1]


def test_broken_field_file_is_an_input_error(tmp_path):
    (tmp_path / "C3_fields.xdmf").write_text("<Xdmf><Domain>")
    with pytest.raises(InputError, match="not valid XML"):
        pictures.read_fields(tmp_path / "C3_fields.xdmf")


# --- the command ---------------------------------------------------------------------------

def _main(*args):
    from deapull.workflows.cli import main
    return main(list(args))


def test_missing_steps_lists_make_targets(tmp_path, capsys):
    """One line of make arguments per missing step (make report FULL=1 runs each): a step whose
    target is another's with a variable says so (the excitation is the sweep's protocol set)."""
    lines = [s.make.removeprefix("make ") for s in report.STEPS]
    assert _main("report", "--outputs", str(tmp_path / "out"), "--data", str(tmp_path / "none"),
                 "--missing-steps") == 0
    assert capsys.readouterr().out.splitlines() == [x for x in lines if x != "fem-study"]
    assert "sweep PROTOCOLS=excitation" in lines and "control PRESET=fem" in lines
    _main("report", "--outputs", str(tmp_path / "out"), "--data", str(SWEEP), "--missing-steps")
    assert capsys.readouterr().out.splitlines() == [x for x in lines[1:] if x != "fem-study"]


def test_cli_builds_the_page(tmp_path):
    proc = _cli("report", "--out", str(tmp_path / "r"), "--outputs", str(tmp_path / "out"), "--data",
                str(_sweep(tmp_path, ["C1"])), "--no-progress", "--check", "no")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "wrote" in proc.stdout and "missing: the 8 FEM datasets" in proc.stdout
    assert (tmp_path / "r" / "index.html").is_file() and (tmp_path / "r" / "report.md").is_file()


def test_bad_input_exits_2_with_one_line(tmp_path, capsys):
    common = ("--outputs", str(tmp_path / "out"), "--no-progress", "--check", "no")
    assert _main("report", "--out", str(tmp_path / "r"), "--frames", "1", *common) == 2
    assert "--frames 1: need at least 2" in capsys.readouterr().err
    (tmp_path / "file").write_text("x")
    assert _main("report", "--out", str(tmp_path / "file"), *common) == 2
    assert "exists and is not a folder" in capsys.readouterr().err


# --- the browser ----------------------------------------------------------------------------

needs_browser = pytest.mark.skipif(find_browser() is None, reason="no chromium + playwright installed")


def _full_report(tmp_path) -> dict:
    """The page built from every study's outputs, field output included (3 animation frames)."""
    data = _sweep(tmp_path, report.SETUPS)
    inputs = _inputs(tmp_path, data)
    _fake_studies(inputs)
    inputs.fields.parent.mkdir(parents=True)
    _write_fields(inputs.fields.parent, np.linspace(0, 1, 5))
    return report.build(tmp_path / "report", inputs, frames=3, progress=False)


@needs_browser
def test_page_loads_cleanly_in_chromium(tmp_path):
    summary = _full_report(tmp_path)
    assert summary["missing"] == []
    result = check_page(summary["index"])
    assert result.ok, result.summary()
    assert result.images == len(_parse(Path(summary["index"])).imgs) >= 8
    assert result.tables >= 10 and not result.empty_tables


@needs_browser
def test_browser_check_catches_broken_images_errors_and_empty_tables(tmp_path):
    page = tmp_path / "index.html"
    page.write_text('<!DOCTYPE html><html><body><img src="img/none.png"><table><caption>t</caption><thead><tr>'
                    "<th>a</th></tr></thead><tbody></tbody></table><script>console.error('boom')</script>"
                    "</body></html>")
    result = check_page(page)
    assert not result.ok
    assert result.broken_images == ["img/none.png"] and result.empty_tables == ["t"]
    assert any("boom" in m for m in result.console_errors)


@needs_browser
@pytest.mark.parametrize("width", [390, 1920])
def test_the_standalone_page_renders_alone_at_phone_and_desktop_width(tmp_path, width):
    """The portable file, moved into an empty folder, shows every image; at 390 px (a phone) and
    at 1,920 px nothing but the tables' own boxes scrolls sideways."""
    summary = _full_report(tmp_path)
    alone = tmp_path / "elsewhere" / "page.html"
    alone.parent.mkdir()
    alone.write_text(Path(summary["standalone"]).read_text())
    result = check_page(alone, width_px=width)
    assert result.ok, result.summary()
    assert result.images >= 8 and not result.broken_images and result.overflow_px == 0


@needs_browser
def test_browser_check_catches_a_page_wider_than_the_phone(tmp_path):
    page = tmp_path / "index.html"
    page.write_text('<!DOCTYPE html><html><body><div style="width:900px">wide</div></body></html>')
    result = check_page(page, width_px=390)
    assert not result.ok and result.overflow_px >= 500


def test_check_without_browser_says_so(tmp_path):
    page = tmp_path / "index.html"
    page.write_text("<html></html>")
    with pytest.raises(BrowserUnavailable, match="apt-get install chromium"):
        check_page(page, browser=str(tmp_path / "no-such-browser"))


# --- the real solver's field output ----------------------------------------------------------

def _abs_z_by_quadrature(s3, frame: int) -> float:
    """Traction-weighted mean |z| of the coin's contact, summed in NumPy over the picture's
    sample points with the Gauss rule's weights and each underside face's reference area."""
    from deapull import scene as scenes
    from deapull.workflows.report import pictures_contact
    c = s3.scene.contact
    assert c.quadrature_rule == "gauss"
    faces = pictures_contact.underside_faces(s3, scenes.layout_bottom(s3.scene))
    x = pictures_contact.underside_samples(s3, frame, c.quadrature_degree, c.quadrature_rule)
    p = c.penalty_N_m3 * np.maximum(pictures_contact.coin_depth(x, s3.coin, s3.at(s3.run_x, frame)), 0.0)
    w = np.polynomial.legendre.leggauss(c.quadrature_degree // 2 + 1)[1] / 2.0
    ref = s3.fields.points
    lx = np.abs(ref[faces[:, -1, 0], 0] - ref[faces[:, 0, 0], 0])
    lz = np.abs(ref[faces[:, 0, -1], 2] - ref[faces[:, 0, 0], 2])
    weights = ((lx * lz)[:, None, None] * w[None, :, None] * w[None, None, :]).reshape(-1)
    assert p.max() > 0
    return float(np.sum(p * np.abs(x[:, 2]) * weights) / np.sum(p * weights))


@pytest.mark.fem
@pytest.mark.slow
def test_pictures_from_a_real_solve(tmp_path):
    """The solver's own XDMF (tiny mesh, short ramp) renders: the format is what we read."""
    tiny = (*SHARP, "mesh.n_length=4", "mesh.n_width=1", "mesh.coin_size_m=0.004", "load.end_time_s=0.1",
            "load.ramp_time_s=0.1", "time.dt_max_s=0.02", "time.dt_initial_s=0.02", "load.voltage_max_V=200")
    folder = tmp_path / "out" / "report_fields"
    proc = _cli("solve", "--scene", "coin_pull", "--setup", "C3", "--out", str(folder), "--fields-every", "2",
                *[a for o in tiny for a in ("--set", o)])
    assert proc.returncode == 0, proc.stderr[-2000:]
    s3 = pictures.load_scene3d(folder / "C3_fields.xdmf")
    assert len(s3.fields.times) >= 3 and s3.umax_mm > 0.1
    # the node order the pictures assume (VTK's) is the one dolfinx wrote: on these box cells its six
    # faces hold the nodes that the coordinates put on them (broken once with two edge midpoints
    # swapped in the table: it failed)
    f = s3.fields

    def faces(g):
        return {frozenset(face.ravel()) for face in (g[0], g[-1], g[:, 0], g[:, -1], g[:, :, 0], g[:, :, -1])}
    for cell in f.cells:
        assert faces(pictures._vtk_lattice(cell, 3)) == faces(pictures._hex_lattice(f.points, cell, 3))
    # coin_pull is a half model (z >= 0, 4 x 1 x (1 + 1) hexahedra) drawn mirrored: the outer faces
    # of a 4 x 2 x 2 block, each drawn as 4 sub-faces, the mid-plane dropped
    assert s3.mirrored and len(s3.polys) == 4 * 2 * (4 * 2 + 4 * 2 + 2 * 2)
    png = pictures.stage_picture(s3, "kinetic", len(s3.fields.times) - 1, tmp_path / "k.png")
    _png_ok(png)
    from deapull.workflows.report import pictures_contact
    last = len(s3.fields.times) - 1
    # the picture's count of the coin's active quadrature points is the solver's own
    assert pictures_contact.coin_contact(s3, last).n == round(s3.at("n_contact", last))
    # the solver's contact_abs_z (a UFL integral over the contact facets) is the picture's own
    # points' |z| weighted by their p_n and the Gauss rule's weights on each underside face
    assert _abs_z_by_quadrature(s3, last) == pytest.approx(s3.at("contact_abs_z", last), rel=1e-6)
    _png_ok(pictures_contact.section_picture(s3, "kinetic", last, tmp_path / "s.png"))


def test_a_diverged_model_is_never_better_or_faster_and_the_counts_come_from_the_rows(tmp_path):
    """The paper's f diverges on every set (as on our FEM data): its rows say so and are 'not
    reproduced', never 'better' or 'faster'; our variant is 'beyond the paper'; the summary's
    counts are the rows' outcomes."""
    data = _sweep(tmp_path, report.SETUPS)
    inputs = _inputs(tmp_path, data)
    _fake_studies(inputs)
    rows = [dict(set=i, train=f"C{i}", val=f"C{i + 1}", test=f"C{i + 2}", model=m, mae_x_m=e, mae_Fx_N=1e-5,
                 mae_Fy_N=2e-5, x_error_pct_travel=pct, rollout_ms=ms, diverged=div)
            for i in (1, 2) for m, e, pct, ms, div in (("f", 1e-9, 0.1, 0.01, True), ("f-coulomb", 0.1e-4, 0.5, 5.0, False),
                                                       ("nn", 2e-4, 9.0, 3.0, False), ("lstm", 9e-4, 12.0, 9.0, False))]
    write_csv(inputs.experiments / "experiments.csv", rows, list(rows[0]))
    (inputs.experiments / "experiments.json").write_text(json.dumps(
        {"rows": rows, "paper": TABLE2, "fem_wall_time_s": {"C3": 60.0}}))
    summary = report.build(tmp_path / "report", inputs, progress=False)
    claims = summary["claims"]
    f_rows = [c for c in claims if "f (paper's law)" in c["what"] or c["what"] == "1 s rollout of f"]
    assert len(f_rows) == 5
    for c in f_rows:
        assert c["outcome"] == "not reproduced", c
        assert not any(w in c["verdict"] for w in ("better", "faster", "lower error", "same")), c
    ours = [c for c in claims if "f (tip contact)" in c["what"]]
    assert ours and all(c["outcome"] == "beyond the paper" for c in ours)
    order = next(c for c in claims if c["what"] == "Baselines' order (Table II)")
    assert order["ours"] == "NN better than LSTM" and order["outcome"] == "not reproduced"
    md = (tmp_path / "report" / "report.md").read_text()
    n = {o: sum(1 for c in claims if c["outcome"] == o) for o in ("reproduced", "not reproduced", "beyond the paper")}
    assert f"**{n['reproduced']} reproduced · {n['not reproduced']} not reproduced · {n['beyond the paper']} beyond " \
           f"the paper**" in md
    assert n["not reproduced"] >= 6


def test_the_standalone_page_carries_its_images_and_tables_inline(tmp_path):
    """report_standalone.html opens with no file beside it: every image is a data URI of the very
    PNG the page shows, every table offers its CSV (inline there, a file under tables/ for
    index.html) with the table's rows."""
    import base64
    import csv as _csv
    data = _sweep(tmp_path, report.SETUPS)
    inputs = _inputs(tmp_path, data)
    _fake_studies(inputs)
    out = tmp_path / "report"
    summary = report.build(out, inputs, progress=False)
    alone = Path(summary["standalone"]).read_text()
    index = (out / "index.html").read_text()
    srcs = re.findall(r'<img src="([^"]+)"', alone)
    assert srcs and all(s.startswith("data:image/png;base64,") for s in srcs)
    for rel, inline in zip(re.findall(r'<img src="([^"]+)"', index), srcs):
        assert base64.b64decode(inline.split(",", 1)[1]) == (out / rel).read_bytes()
    hrefs = re.findall(r'href="([^"#][^"]*)"', alone)
    assert all(h.startswith("data:") for h in hrefs), [h[:40] for h in hrefs if not h.startswith("data:")]
    n_tables = index.count("<table")
    files = re.findall(r'<a href="(tables/[^"]+\.csv)"', index)
    # every table's CSV, and the numbers behind the figures drawn from data (error against run
    # time: its two panels; the control bands)
    figure_data = ["tables/control-bands.csv", "tables/error-time-points.csv", "tables/error-time-control.csv"]
    assert [f for f in files if f in figure_data] == figure_data
    assert len(files) == n_tables + len(figure_data) == alone.count("data:text/csv;base64,")
    assert all((out / f).is_file() for f in files)
    first = re.search(r'<table[^>]*>.*?</table>', index, re.S).group(0)
    with open(out / files[0], newline="") as f:
        rows = list(_csv.reader(f))
    assert len(rows) - 1 == first.count("<tr") - 1          # header row + one per body row
