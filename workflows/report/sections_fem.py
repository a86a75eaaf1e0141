"""The report's FEM sections: the model, pictures of the DEA, the sweep, the FEM's speed and
accuracy, the fidelity ladder and the stability suite."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from deapull import dataset, scene as scenes
from deapull.paper import (ABAQUS_COIN_ELEMENTS, ABAQUS_ELEMENTS_PER_MEMBRANE, ABAQUS_POINTS, ABAQUS_S,
                           CONTACT_LOST_V, DATASET_POINTS, POISSON_RATIO, THRESHOLD_M, YOUNGS_MODULUS_PA)
from deapull.io import atomic_write
from deapull.workflows.fidelity import AS_WRITTEN
from deapull.workflows.report import pictures, pictures_contact
from deapull.workflows.report.document import Claim, Report, Section, Table
from deapull.workflows.report.inputs import SCENE, SETUPS, fields_run
from deapull.workflows.report.plots import plot_sweep
from deapull.workflows.report.tabular import fmt, num, read_csv


#: the largest penetration of the DEA into the table that the page calls resolved at the shipped
#: penalty (µm; the table's penalty is chosen for < 1 µm under the C3 drape: coin_pull.toml)
TABLE_PENETRATION_GOAL_UM = 1.0


def datasets_fidelity(data: Path, setup: str = "C3") -> str | None:
    """The fidelity of the scene that ``data``/<setup>.nc was made at (:func:`deapull.scene.fidelity_of_resolved`):
    a ``[fidelities.NAME]`` of the scene, "" for the file as written, None when it is none of
    them (other ``--set`` overrides) or the dataset is absent."""
    path = Path(data) / f"{setup}.nc"
    if not path.is_file():
        return None
    text = str(dataset.read(path, ("t",)).attrs.get("scene_toml", ""))
    return scenes.fidelity_of_resolved(text, setup, SCENE)[0]


def mesh_patch_text(m) -> str:
    """The resolved contact patch of a mesh section (tip zone, rim band), or ""."""
    out = ""
    if m.tip_zone_m:
        out += (f"; a {m.tip_zone_m * 1e3:g} mm tip zone in {m.tip_zone_divisions} "
                f"({m.tip_zone_m * 1e3 / max(m.tip_zone_divisions, 1):g} mm elements)")
    if m.rim_band_m:
        a, b = m.rim_band_m
        out += f"; the rim band {a * 1e3:g} ≤ |z| ≤ {b * 1e3:g} mm in {m.rim_band_divisions}"
    return out


def section_model(rep: Report) -> Section:
    sec = Section("model", "The model: geometry, materials, scene")
    fidelity = datasets_fidelity(rep.inputs.data)
    sc = scenes.load(SCENE, overrides=scenes.fidelity_overrides(SCENE, fidelity))
    rep.source(scenes.resolve_path(SCENE), sec)
    d, c, ld = sc.dea, sc.coin, sc.load
    e0 = ld.voltage_max_V / d.film_thickness_m
    eps = 8.854187817e-12 * d.relative_permittivity
    strain = eps * e0 ** 2 / (2 * d.youngs_modulus_Pa)
    pullin = 0.69 * math.sqrt(d.youngs_modulus_Pa / 3 / eps)
    fid_arg = f" --fidelity {fidelity}" if fidelity else ""
    made = (f"the datasets in `{rep.inputs.data}` are made at its fidelity `{fidelity}`" if fidelity else
            f"the datasets in `{rep.inputs.data}` are made from the file as written" if fidelity == "" else
            f"the datasets in `{rep.inputs.data}` were made with other overrides (their `scene_toml`); the table "
            "shows the file as written")
    sec.p(f"Scene `{SCENE}` (`deapull/scenes/{SCENE}.toml`, resolved with `deapull show-scene {SCENE} --setup "
          f"{sc.setup}{fid_arg}`; {made}): {sc.scene.description}. A unimorph DEA (active electrode stack on a passive layer) is "
          f"clamped at x = 0 with its free end at x = −{d.length_m * 1e3:g} mm resting on a steel coin; "
          f"V rises 0 → {ld.voltage_max_V:g} V in {ld.ramp_time_s:g} s ({ld.protocol}). y is up, the coin moves "
          "toward −x (the paper's V^T convention). Every number below comes from the scene file.")
    rows = [
        ("DEA length × width", f"{d.length_m * 1e3:g} × {d.width_m * 1e3:g} mm", "dea.length_m, dea.width_m"),
        ("active stack / passive layer", f"{d.active_thickness_m * 1e3:g} / {d.passive_thickness_m * 1e3:g} mm",
         "dea.active_thickness_m, dea.passive_thickness_m"),
        ("film thickness (field = V / film)", f"{d.film_thickness_m * 1e6:g} µm", "dea.film_thickness_m"),
        ("material", f"{d.material}, E = {d.youngs_modulus_Pa / 1e6:g} MPa, ν = {d.poisson_ratio:g} "
         f"(paper: E = {YOUNGS_MODULUS_PA / 1e6:g} MPa, ν = {POISSON_RATIO:g})",
         "dea.material, dea.youngs_modulus_Pa, dea.poisson_ratio"),
        ("ε_r, elastomer density", f"{d.relative_permittivity:g}, {d.density_kg_m3:g} kg/m³",
         "dea.relative_permittivity, dea.density_kg_m3"),
        ("clamp gap (gravity pre-load)", f"{d.clamp_gap_m * 1e3:g} mm", "dea.clamp_gap_m"),
        ("coin radius × height", f"{c.radius_m * 1e3:g} × {c.height_m * 1e3:g} mm (paper: 5 × 2.25 mm)",
         "coin.radius_m, coin.height_m"),
        ("coin centre from the tip", f"{c.center_from_tip_m * 1e3:g} mm toward the clamp", "coin.center_from_tip_m"),
        (f"coin density, μ_t, μ_b (setup {sc.setup})", f"{c.density_kg_m3 / 1e3:g} g/cm³, {c.mu_t:g}, {c.mu_b:g}",
         "coin.density_kg_m3, coin.mu_t, coin.mu_b"),
        ("contact", f"penalty {sc.contact.penalty_N_m3:.3g} N/m³, {sc.contact.quadrature_degree // 2 + 1} × "
         f"{sc.contact.quadrature_degree // 2 + 1} {sc.contact.quadrature_rule} points per facet, friction "
         f"regularised at {sc.contact.slip_rate_regularisation_m_s:g} m/s", "contact.*"),
        ("mesh", f"{sc.mesh.cell} order {sc.mesh.order}, {sc.mesh.n_length} × {sc.mesh.n_width} × "
         f"({sc.mesh.n_active} + {sc.mesh.n_passive}) cells, level {sc.mesh.level}" + mesh_patch_text(sc.mesh),
         "mesh.*"),
        ("solver", f"{sc.solver.formulation}" + (" (Taylor–Hood u–p)" if sc.solver.formulation == "mixed" else "")
         + f", electrostatics {sc.solver.electrostatics}",
         "solver.*"),
        ("time", f"t ∈ [0, {ld.end_time_s:g}] s, dt ≤ {sc.time.dt_max_s * 1e3:.3g} ms (≥ {ABAQUS_POINTS} points)",
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
                    caption="The 8 setups (the paper's numbering; C3 is the coin of its C3 data figure, left out of the published version)"))
    sec.p("The design choices the paper leaves open (sizes, films, the push direction) are derived in "
          "`docs/physics.md`; the flat-top contact pushes the coin away from the clamp (−x), as measured there.")
    return sec


def section_pictures(rep: Report) -> Section:
    sec = Section("pictures", "Pictures of the DEA and the coin (the paper's Fig. 4)")
    inputs, frames, progress = rep.inputs, rep.frames, rep.progress
    xdmf = inputs.fields
    if not (xdmf.is_file() and dataset.is_complete(fields_run(xdmf))):
        sec.lack(f"the displacement fields `{xdmf}` and their run `{fields_run(xdmf)}`", "report-fields")
        return sec
    s3 = pictures.load_scene3d(xdmf)
    rep.source(xdmf, sec)
    rep.source(fields_run(xdmf), sec)
    stages = pictures.stage_frames(s3)
    sec.p(f"Setup {s3.setup}, rendered off-screen from the solver's field output ({len(s3.fields.times)} frames, "
          "XDMF + HDF5) with matplotlib. Colour: the **actuation** |u(t) − u(rest)|, the displacement since the "
          "rest state (the first frame: the DEA settled on the coin under gravity at V = 0), so the gravity sag is "
          "left out; the rest picture itself shows that sag |u(rest)| on its own scale. The grey body is the "
          "rigid coin (its rounded rim included), moved by its x(t) from the run's dataset; the hatched band the "
          "table. In the side views the DEA's far half is drawn behind the coin and its near half in front, as in "
          "space. The DEA (20 mm wide) is wider than the coin (10 mm): its corners curl down beside the coin.")
    for key, title in pictures.STAGES:
        name = f"dea_{key}.png"
        pictures.stage_picture(s3, key, stages[key], rep.img / name)
        sec.img(f"img/{name}", f"{s3.setup}, {title}: side view (left) and 3/4 view, the DEA see-through (right).")
    _contact_pictures(rep, sec, s3, stages)
    name = f"dea_{s3.setup}.gif"
    pictures.animation(s3, rep.img / name, frames=frames, progress=progress)
    sec.img(f"img/{name}", f"Animation of {s3.setup}: the whole ramp, side view with the coin and the table (left), "
            "the coin's x(t) with a marker at the frame's time (right) (GIF).")
    _ship_fields(rep, sec, xdmf)
    lowest = [float((s3.points + s3.displacement(i))[:, 1].min()) for i in range(len(s3.fields.times))]
    ground = s3.table_height_m
    below = [i for i, y in enumerate(lowest) if y < (0.0 if ground is None else ground)]
    if below and ground is not None:
        # the DEA rests on the table through a penalty: it sinks by what the penalty allows
        depth_um = ((ground - min(lowest)) * 1e6, 1e6 * float(np.max(s3.run.get("table_penetration_m", [0.0]))))
        within = max(depth_um) <= TABLE_PENETRATION_GOAL_UM
        sec.p(f"The DEA rests on the table (y = {ground * 1e3:g} mm) where its corners drape past the coin; the "
              f"table's penalty lets them sink at most {depth_um[0]:.2f} µm at the nodes drawn and "
              f"{depth_um[1]:.2f} µm at the table's quadrature points (the dataset's `table_penetration_m`; goal "
              f"≤ {TABLE_PENETRATION_GOAL_UM:g} µm).")
        rep.claims.append(Claim("The DEA stays above the table", "– (not shown)",
                                f"{'yes' if within else 'no'}: it sinks ≤ {max(depth_um):.2f} µm into the table "
                                f"(penalty contact; goal ≤ {TABLE_PENETRATION_GOAL_UM:g} µm)", "#pictures",
                                "within the penalty's tolerance" if within else "caveat"))
    elif below:
        i0, worst = below[0], int(np.argmin(lowest))
        v0 = float(np.interp(s3.fields.times[i0], s3.run_t, s3.run_V))
        sec.p(f"**Caveat:** the DEA's corners beside the coin reach y = {lowest[worst] * 1e3:.2f} mm, below the "
              f"ground (y = 0), from t = {s3.fields.times[i0]:.3f} s (V ≈ {v0:.0f} V) on: this run's scene has no "
              "table, so nothing holds the DEA up where it drapes past the coin.")
        rep.claims.append(Claim("The DEA stays above the table", "– (not shown)",
                                f"no: its corners reach y = {lowest[worst] * 1e3:.2f} mm (below the ground) "
                                f"from {v0:.0f} V (no table in this run's scene)", "#pictures", "caveat"))
    sec.p("Paper, Fig. 4: (a) the inactive DEA, (b) the static-friction stage (the DEA bends, the coin stays), "
          "(c) the kinetic stage (the coin moves). Ours shows the same three stages; the paper's ABAQUS mesh had "
          f"{ABAQUS_ELEMENTS_PER_MEMBRANE} elements per membrane and {ABAQUS_COIN_ELEMENTS} for the coin, ours is in "
          "the model table.")
    return sec


def _contact_pictures(rep: Report, sec: Section, s3, stages: dict) -> None:
    """The section at z = 0 with the contact patch, at the static and the kinetic stage."""
    if s3.coin is None or s3.scene is None:
        return
    for key, title in pictures.STAGES[1:]:
        name = f"section_{key}.png"
        pictures_contact.section_picture(s3, key, stages[key], rep.img / name)
        sec.img(f"img/{name}", f"{s3.setup}, {title}: the section at the symmetry plane z = 0 (left) and the "
                "contact seen from above (right).")
    sec.p("The contact pressure is recomputed from the field file (the dataset records only the number of "
          "active points and the traction-weighted centre): the deformed underside is sampled at the contact "
          "integral's own quadrature points, each point's depth δ in the coin (cylinder with the rounded rim) or "
          "below the table gives p_n = k_n δ with the scene's penalty. The count of the coin's points is printed "
          "beside the solver's `n_contact`, the blue × is the solver's `contact_x`, `contact_z`.")


def _ship_fields(rep: Report, sec: Section, xdmf) -> None:
    """Copy the field file (XDMF + its HDF5) beside the page and link it."""
    folder = rep.out / "fields"
    names = []
    for src in (xdmf, xdmf.with_suffix(".h5")):
        data = src.read_bytes()
        atomic_write(folder / src.name, lambda p, d=data: Path(p).write_bytes(d), suffix=src.suffix)
        names.append(src.name)
    sec.p(f"The run's displacement field for ParaView: [fields/{names[0]}](fields/{names[0]}) with its data "
          f"[fields/{names[1]}](fields/{names[1]}) (keep the two side by side); in ParaView, File → Open the "
          "`.xdmf` with the *Xdmf3 Reader (Top Level Partition)*, Apply, then Filters → Warp By Vector "
          "(displacement) and play the time steps.")


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


def section_sweep(rep: Report) -> Section:
    sec = Section("sweep", "The 8-setup sweep (the paper's Fig. 4 stages and §VI-A timing)")
    inputs = rep.inputs
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
        ratio = f["wall_s"] / ABAQUS_S if f["wall_s"] else None
        rows.append([f["setup"], fmt(f["rho"] / 1e3 if f["rho"] else None, "g"), fmt(f["mu_t"], "g"),
                     fmt(f["mu_b"], "g"), fmt(f["mass_g"], ".4f"), str(f["points"]), fmt(f["travel_mm"], ".3f"),
                     fmt(f["max_Fy_mN"], ".2f"), fmt(f["V_slip"], ".0f"), fmt(f["V_cone"], ".0f"), fmt(f["V_T"], ".0f"),
                     fmt(f["V_contact_lost"], ".0f"), fmt(f["wall_s"], ".1f"), str(f["ranks"]),
                     fmt(ratio, ".2f")])
        anchors.append(f"sweep-{f['setup']}")
    sec.table(Table(["setup", "ρ g/cm³", "μ_t", "μ_b", "m_c g", "points", "travel mm", "max Fy mN",
                     "V slip onset (FEM)", "V friction cone", "V^T", "V contact lost", "wall s", "ranks",
                     f"wall / ABAQUS {ABAQUS_S:g} s"], rows, anchors,
                    caption="Per setup: stages, threshold voltages and wall time"))
    walls = [f["wall_s"] for f in facts if f["wall_s"]]
    pts = [f["points"] for f in facts]
    mean_wall = float(np.mean(walls)) if walls else None
    sec.p("**V^T** (the paper's threshold, §V): the voltage at which the coin first reaches x = −10⁻⁵ m. "
          "**V friction cone**: the prediction from Coulomb's law on the ground, the first V at which the DEA's "
          "horizontal force leaves the cone, |Fx| ≥ μ_b (m_c g + Fy). **V slip onset**: the FEM's own stick → "
          "slip switch. The three agree when the coin starts to slide as soon as the cone is left; V^T lies a "
          "little later (10 µm of travel). The paper gives no V^T per setup; it assumes contact is lost from "
          f"{CONTACT_LOST_V:g} V on (ours: the last column; – = the DEA still touches the coin at 400 V).")
    if mean_wall is not None:
        sec.p(f"Mean wall time per setup {mean_wall:.1f} s for {np.mean(pts):.0f} points (ABAQUS in the paper: "
              f"{ABAQUS_S:g} s for {ABAQUS_POINTS} points), {mean_wall / np.mean(pts) * 1e3:.0f} ms per point; "
              "ranks as in the table.")
        rep.claims.append(Claim("FEM wall time, one 1 s setup", f"{ABAQUS_S:g} s (ABAQUS, {ABAQUS_POINTS} points)",
                                f"{mean_wall:.1f} s (dolfinx, {np.mean(pts):.0f} points, mean of {len(walls)})",
                                "#sweep-" + facts[0]["setup"],
                                "faster" if mean_wall < ABAQUS_S else "slower"))
    rep.claims.append(Claim("Points per setup",
                            f"{ABAQUS_POINTS} (§VI-A); {DATASET_POINTS[0]}–{DATASET_POINTS[1]} (§V)",
                            str(min(pts)) if min(pts) == max(pts) else f"{min(pts)}–{max(pts)}",
                            "#sweep-" + facts[0]["setup"]))
    c3 = next((f for f in facts if f["setup"] == "C3"), facts[0])
    two = c3["V_slip"] is not None and c3["travel_mm"] >= 1.0
    rep.claims.append(Claim("Two stages under the ramp (Fig. 4)", "static: Fy rises, no motion; kinetic: "
                            "the coin moves", f"{c3['setup']}: slides from {fmt(c3['V_slip'], '.0f')} V, travel "
                            f"{c3['travel_mm']:.2f} mm", f"#sweep-{c3['setup']}", "same" if two else "differs",
                            "reproduced" if two else "not reproduced"))
    lost = c3["V_contact_lost"]
    rep.claims.append(Claim("Contact lost at high voltage (§V)", f"the coin loses contact with the DEA for V ≥ "
                            f"{CONTACT_LOST_V:.0f} V (assumed)",
                            f"{c3['setup']}: " + (f"contact lost at {lost:.0f} V" if lost is not None else
                                                  "the DEA presses the coin up to the end of the ramp"),
                            f"#sweep-{c3['setup']}",
                            "same" if lost is not None and lost <= CONTACT_LOST_V * 1.1 else
                            "differs: our FEM keeps the contact (the flat-top contact presses harder as V rises)",
                            "reproduced" if lost is not None and lost <= CONTACT_LOST_V * 1.1 else "not reproduced"))
    return sec


def section_fem_accuracy(rep: Report) -> Section:
    """The FEM's speed beside ABAQUS (``bench_fem.json``) and its accuracy: the contact reference's
    ladders, orders and bound, and the data fidelity against it (``contact_reference.json``)."""
    sec = Section("fem-accuracy", "FEM speed and accuracy")
    inputs = rep.inputs
    ref_path = Path(inputs.reference)
    if rep.found(ref_path, sec, "the contact reference", "fem-study"):
        ref = json.loads(ref_path.read_text())
        t = ref["time_s"]
        rows = [[lad["label"], " / ".join(fmt(v, ".4f") for v in lad["x_at_t_mm"]),
                 fmt(lad["observed_order_x_at_t"], ".2f"), fmt(lad["richardson_x_at_t_mm"], ".4f"),
                 fmt(lad["gci_x_at_t_percent"], ".3f", "%")] for lad in ref["ladders"].values()]
        sec.table(Table(["ladder", f"x({t:g} s) mm, coarse / middle / fine", "observed order", "Richardson mm", "GCI"],
                        rows, [f"ladder-{i}" for i in range(len(rows))],
                        caption="coin_pull C3: two mesh ladders of ratio 2 through one middle case "
                                "(studies/contact_reference.toml)"))
        bound, err = ref.get("bound_percent"), ref.get("default_error_percent")
        sec.p(f"The reference x({t:g} s) = {fmt(ref.get('reference_x_at_t_mm'), '.4f', 'mm')}, its bound (the "
              f"ladders' GCIs and the step halved) {fmt(bound, '.3f', '%')}; the data fidelity lies "
              f"{fmt(err, '+.3f', '%')} from it (docs/fem_accuracy.md).")
        rep.claims.append(Claim("Contact convergence of the FEM (not in the paper)", "not reported",
                                f"bound {fmt(bound, '.2f', '%')}; the data fidelity {fmt(err, '+.2f', '%')}",
                                "#fem-accuracy",
                                verdict=("within" if bound is not None and bound <= 1.0 else "outside")
                                + " the goal of a bound ≤ 1 %"))
    path = inputs.bench_fem / "bench_fem.json"
    if not rep.found(path, sec, "the FEM benchmark", "bench-fem"):
        return sec
    res = json.loads(path.read_text())
    rows = []
    for label, r in res["runs"].items():
        rows.append([label, fmt(r["wall_s"], ".1f"), format(ABAQUS_S / r["wall_s"], ".2f") + "×", str(r["points"]),
                     str(r["dofs"]), str(r["newton_its"]), fmt(r["x_at_t_mm"], ".4f"),
                     fmt(r.get("error_percent"), "+.2f", "%")])
    rows.append(["paper (ABAQUS)", f"{ABAQUS_S:g}", "1.00×", str(ABAQUS_POINTS), "–", "–", "–", "–"])
    sec.table(Table(["run", "wall s", "vs ABAQUS", "points", "dofs", "Newton its", "x(0.95 s) mm", "vs reference"],
                    rows, [f"fem-{i}" for i in range(len(rows))],
                    caption="coin_pull C3 on one core; errors against the contact reference above"))
    if "sweep" in res:
        sw = res["sweep"]
        sec.p(f"The 8-setup sweep under `mpirun -n {sw['np']}`: {fmt(sw['wall_s'], '.1f', 's')} "
              f"(ABAQUS 8 × {ABAQUS_S:g} s = {8 * ABAQUS_S:g} s).")
        rep.claims.append(Claim("FEM time, 8 setups", f"8 × {ABAQUS_S:g} s (ABAQUS)", fmt(sw["wall_s"], ".0f", "s"),
                                "#fem-accuracy"))
    return sec


def section_fidelity(rep: Report) -> Section:
    sec = Section("fidelity", "Error against run time (the FEM ladder and the surrogates)")
    inputs = rep.inputs
    csv_path = inputs.fidelity / "fidelity.csv"
    if not rep.found(csv_path, sec, "the fidelity ladder", "fidelity"):
        return sec
    rows = read_csv(csv_path)
    results = inputs.fidelity / "fidelity.json"
    # the ladder's own fidelity (its CSV's column), so that the hint below reuses its rungs
    named = {r["fidelity"] for r in rows if r.get("fidelity")}
    if results.is_file():   # what the ladder refined (its scene and fidelity), its reference and the verdict
        rep.source(results, sec)
        for line in json.loads(results.read_text()).get("notes", []):
            sec.p(line)
    else:
        sec.lack(f"the ladder's notes `{results}` (written by `deapull fidelity`; re-run it: it resumes)", "fidelity")
    fidelity = named.pop() if len(named) == 1 else None
    fidelity_arg = f" --fidelity {fidelity}" if fidelity and fidelity != AS_WRITTEN else ""
    png = inputs.fidelity / "fidelity_pareto.png"
    if png.is_file():
        sec.img(rep.copy_image(png, "fidelity_pareto.png"), "Error against wall time: every rung, Pareto fronts "
                "joined, the shipped default and the reference marked (`docs/fidelity_stability.md`).")
    keys = [("case", "rung", ""), ("kind", "kind", ""), ("elements", "elements", ""), ("dofs", "dofs", ".0f"),
            ("ranks", "ranks", ".0f"), ("steps", "steps", ".0f"), ("wall_s", "wall s", ".3g"), ("mae_x_mm", "MAE x mm", ".3g"),
            ("mae_Fy_mN", "MAE Fy mN", ".3g"), ("error_pct", "error %", ".3g"), ("on_pareto", "Pareto", ""),
            ("status", "status", "")]
    table_rows = []
    for r in rows:
        table_rows.append([_yes(r.get(k, "")) if not spec else fmt(num(r, k), spec) for k, _, spec in keys])
    sec.table(Table([h for _, h, _ in keys], table_rows, [f"fid-{r.get('case', i)}" for i, r in enumerate(rows)],
                    caption="The ladder (reference: the finest affordable rung)"))
    if not any(r.get("kind", "") not in ("", "fem") for r in rows):
        sec.p(f"No surrogate on this ladder yet: `mpirun -n 2 deapull fidelity --scene coin_pull --setup C3{fidelity_arg} "
              f"--out {inputs.fidelity} --surrogate {inputs.experiments}/set1/f-patch` adds one (the FEM rungs are "
              "reused).")
    default = next((r for r in rows if r.get("is_default") in ("True", "true", "1")), None)
    if default is not None:
        rep.claims.append(Claim("FEM accuracy of the shipped discretisation", "not reported (ABAQUS C3D8E, "
                                f"{ABAQUS_ELEMENTS_PER_MEMBRANE} elements per membrane)",
                                f"{fmt(num(default, 'error_pct'), '.3g')} % against the reference rung", f"#fid-{default.get('case')}"))
    return sec


def _yes(value: str) -> str:
    """CSV booleans as yes / no, other text as it is."""
    return {"True": "yes", "False": "no", "true": "yes", "false": "no"}.get(value, value)


def section_stability(rep: Report) -> Section:
    sec = Section("stability", "Stability: stiff and extreme cases")
    inputs = rep.inputs
    path = inputs.stability / "stability.json"
    if not rep.found(path, sec, "the stability results", "stability"):
        return sec
    result = json.loads(path.read_text())
    sec.p(result["header"])
    headers, rows = result["table"]["headers"], result["table"]["rows"]
    sec.table(Table(headers, rows, [f"stab-{r[0]}" for r in rows], caption="One row per case"))
    conv = sum(1 for r in rows if len(r) > 1 and r[1] == "yes")
    rep.claims.append(Claim("Robustness (not in the paper)", "–", f"{conv}/{len(rows)} cases converge; the "
                            "rest fail as expected (pull-in, ν = 0.5 displacement)", "#stability"))
    if result["pull_in"]:
        sec.bullets(result["pull_in"])
    return sec
