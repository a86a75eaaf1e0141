"""The report's error-against-run-time plot and the control bands: the points come from the
result files and nowhere else, a diverged model never gets a finite error, the bands are
numpy's percentiles of the episodes."""
import csv
import json
import re

import numpy as np

from deapull.io import write_csv
from deapull.workflows import report
from deapull.workflows.report import plots, sections_control, sections_error_time


def _fidelity(inputs, rows):
    write_csv(inputs.fidelity / "fidelity.csv", rows,
              ("case", "kind", "status", "wall_s", "mae_x_pct", "travel_err_pct", "is_reference"))


def _experiments(inputs, rows):
    """experiments.csv in the columns `deapull experiments` writes (the other errors: fixed)."""
    rows = [dict(train=f"C{r['set']}", val=f"C{r['set'] + 1}", test=f"C{r['set'] + 2}", mae_x_m=1e-4, mae_Fx_N=1e-4,
                 mae_Fy_N=1e-4, **r) for r in rows]
    write_csv(inputs.experiments / "experiments.csv", rows, list(rows[0]))


def _read(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _inputs(tmp_path):
    return report.Inputs.under(tmp_path / "out", tmp_path / "data",
                               reference=tmp_path / "none" / "contact_reference.json")


def test_the_points_are_exactly_those_of_the_result_files(tmp_path):
    """Two fake result files (a fidelity ladder, an experiment run): the page's CSV holds exactly
    their points; every other input is a "not run" row naming its make target."""
    inputs = _inputs(tmp_path)
    _fidelity(inputs, [dict(case="ref", kind="fem", status="ok", wall_s=900.0, mae_x_pct=0.0, travel_err_pct=0.0,
                            is_reference=True),
                       dict(case="coarse", kind="fem", status="ok", wall_s=12.5, mae_x_pct=2.25, travel_err_pct=0.75,
                            is_reference=False)])
    _experiments(inputs, [dict(set=1, model="nn", x_error_pct_travel=4.0, rollout_ms=30.0, diverged=False),
                          dict(set=2, model="nn", x_error_pct_travel=6.0, rollout_ms=50.0, diverged=False)])
    out = tmp_path / "report"
    summary = report.build(out, inputs, progress=False)
    rows = _read(out / "tables" / "error-time-points.csv")
    ok = [(r["group"], r["label"], r["metric"], float(r["wall_s"]), float(r["error_pct"])) for r in rows
          if r["status"].startswith("ok")]
    assert ok == [("FEM ladder", "coarse", "x(t) MAE", 12.5, 2.25), ("FEM ladder", "coarse", "travel error", 12.5, 0.75),
                  ("surrogate", "NN", "x(t) MAE", 0.04, 5.0)]
    ref = [r for r in rows if r["status"].startswith("reference")]
    assert [(r["label"], r["error_pct"]) for r in ref] == [("ref", "0.0")]      # error 0: not a log point
    not_run = {r["group"]: r["make"] for r in rows if r["status"] == "not run"}
    assert not_run == {"FEM benchmark": "make bench BENCH=fem", "contact convergence": "make fem-study"}
    assert [r["label"] for r in rows if r["group"] == "paper"] == ["ABAQUS (Lahariya et al.)"]
    control = _read(out / "tables" / "error-time-control.csv")
    assert {(r["status"], r["make"]) for r in control} == {("not run", "make control"),
                                                          ("not run", "make control PRESET=fem")}
    html = (out / "index.html").read_text()
    assert 'src="img/error_time.png"' in html and 'href="tables/error-time-points.csv"' in html
    assert "error_time.png" in summary["images"]
    assert "make fem-study" in html and "make bench BENCH=fem" in html
    # the section's Sources in one order whatever the hash seed: sorted (broken once: a set's order)
    section = html.split('<section id="error-time">')[1].split("</section>")[0]
    sources = re.findall(r"<code>([^<]*)</code></a>", section.split("Sources:")[1])
    assert len(sources) == 2 and sources == sorted(sources), sources


REFERENCE = {"time_s": 0.95, "reference_x_at_t_mm": -1.0, "bound_percent": 0.5, "default_error_percent": 1.0,
             "cases": {"a": {"x_at_t_mm": -1.01, "wall_s": 10.0}, "b": {"x_at_t_mm": -0.995, "wall_s": 40.0}},
             "ladders": {"tip": {"label": "tip", "x_at_t_mm": [-1.02, -1.01, -1.005], "observed_order_x_at_t": 1.0,
                                 "richardson_x_at_t_mm": -1.0, "gci_x_at_t_percent": 0.3}}}


def test_the_contact_convergence_points_come_from_the_reference_file(tmp_path):
    """Each case of the contact study at its x(0.95 s) error against the Richardson value, and the
    bound at the costliest case's time. Broken once with the error taken against the finest case:
    the points moved."""
    path = tmp_path / "contact_reference.json"
    path.write_text(json.dumps(REFERENCE))
    points = sections_error_time.reference_points(path)
    assert [(p["label"], p["metric"], p["wall_s"]) for p in points] == [("a", "travel error", 10.0),
                                                                        ("b", "travel error", 40.0),
                                                                        ("reference", "travel error bound", 40.0)]
    assert np.allclose([p["error_pct"] for p in points], [1.0, 0.5, 0.5])


def test_the_fem_accuracy_section_gives_the_ladders_and_the_bound(tmp_path):
    """The section's ladder table and its claim come from contact_reference.json: the bound and the
    data fidelity's error, and whether the bound meets the 1 % goal."""
    from deapull.workflows.report import sections_fem
    from deapull.workflows.report.document import Report
    from deapull.workflows.report.inputs import Inputs
    path = tmp_path / "contact_reference.json"
    path.write_text(json.dumps(REFERENCE))
    rep = Report(tmp_path / "report", Inputs.under(tmp_path, reference=path), progress=False)
    sec = sections_fem.section_fem_accuracy(rep)
    tables = [b[1] for b in sec.blocks if b[0] == "table"]
    text = " ".join(str(b[1]) for b in sec.blocks if b[0] == "p")
    assert tables[0].rows[0][0] == "tip" and tables[0].rows[0][2] == "1.00"
    assert "0.500 %" in text and "+1.000 %" in text, text
    assert "within" in rep.claims[-1].verdict


def test_a_diverged_model_gets_no_finite_point(tmp_path):
    """f diverged on one set of two (its rows still carry numbers): its row has no error and the
    figure draws no point for it on the data axes, only the word on the top edge."""
    inputs = _inputs(tmp_path)
    _experiments(inputs, [dict(set=1, model="f", x_error_pct_travel=0.5, rollout_ms=7.0, diverged=False),
                          dict(set=2, model="f", x_error_pct_travel=1e-3, rollout_ms=9.0, diverged=True),
                          dict(set=1, model="lstm", x_error_pct_travel=8.0, rollout_ms=70.0, diverged=False)])
    points = sections_error_time.error_time_points(inputs)
    f = [p for p in points if p["label"] == "f (paper's law)"]
    assert len(f) == 1 and f[0]["error_pct"] is None and f[0]["status"] == "diverged on 1/2 sets"
    fig = plots.draw_error_time(points, [])
    ax = fig.axes[0]
    drawn = [(x, y) for line in ax.get_lines() if line.get_transform() == ax.transData
             for x, y in zip(line.get_xdata(), line.get_ydata()) if np.isfinite(y)]
    assert drawn == [(0.07, 8.0)]                     # the LSTM only; f's 8 ms has no point
    words = [t.get_text() for t in ax.texts]
    assert "f (paper's law): diverged on 1/2 sets" in words
    import matplotlib.pyplot as plt
    plt.close(fig)
    out = tmp_path / "report"
    report.build(out, inputs, progress=False)
    row = next(r for r in _read(out / "tables" / "error-time-points.csv") if r["label"] == "f (paper's law)")
    assert row["error_pct"] == "" and row["status"].startswith("diverged")


def _traces():
    """Two policies, episodes of different lengths (a finished episode is held at its end)."""
    rng = np.random.default_rng(3)
    eps = {"mpc": [rng.normal(size=n).cumsum() * 1e-4 for n in (5, 9, 7, 9)],
           "pd": [rng.normal(size=n).cumsum() * 1e-4 for n in (12, 4, 12)]}
    arrays = {f"{pol}|surrogate:C2|0.001|{k}|x_m": x for pol, xs in eps.items() for k, x in enumerate(xs)}
    arrays["mpc|surrogate:C2|0.001|0|V_V"] = np.zeros(5)
    return eps, arrays


def test_the_bands_are_numpys_percentiles_of_the_episodes(tmp_path):
    eps, arrays = _traces()
    np.savez(tmp_path / "traces.npz", **arrays)
    panels = sections_control.trace_bands(tmp_path / "traces.npz")
    assert list(panels) == [("surrogate:C2", 0.001)]
    for pol, xs in eps.items():
        n = max(len(x) for x in xs)
        held = 1e3 * np.array([np.concatenate([x, np.full(n - len(x), x[-1])]) for x in xs])
        b = panels[("surrogate:C2", 0.001)][pol]
        for q in (10, 50, 90):
            np.testing.assert_allclose(b[f"p{q}"], np.percentile(held, q, axis=0), rtol=1e-12, atol=0)
        assert b["episodes"] == len(xs)
        assert list(b["running"]) == [sum(len(x) > i for x in xs) for i in range(n)]
    rows = sections_control.band_rows(panels, max_rows=4)
    mpc = [r for r in rows if r["policy"] == "mpc"]
    assert [r["iteration"] for r in mpc] == [0, 3, 6, 8]           # every 3rd and the last
    assert mpc[-1]["x_p50_mm"] == panels[("surrogate:C2", 0.001)]["mpc"]["p50"][8]


def test_the_fem_control_text_says_how_each_run_moved_v_from_its_own_run_json():
    """The FEM closed-loop section describes each run's MPC settings from its ``run.json``, not
    from typed text: the rate limit, the approach, the stand-off, the innovation check, the
    fixed φ and f_a's folder appear only when that run used them. Broken once: the rate read
    from the wrong key (the first check failed); and the window read from the wrong key
    (the last check failed); and the reach gate's sentence written whatever the flag (the
    gate-on checks failed)."""
    def text(mpc=None, **control):
        return sections_control.mpc_settings_text({**control, "mpc": mpc or {}})

    rate = text({"rate_V": 0.4, "approach_m": 0.0, "standoff_stds": 0.0})
    assert "0.4 V per step" in rate and "mm of the target" not in rate and "stds" not in rate
    slow = text({"rate_V": 0.0, "approach_m": 1e-3, "standoff_stds": 2.0}, dv_max_V=5.0)
    assert "5 V per step" in slow and "within 1 mm" in slow and "2 stds" in slow and "0.5 V per step" in slow
    taper = text({"rate_V": 0.4, "approach_m": 1e-4, "creep_V": 0.1})
    assert "within 0.1 mm" in taper and "down to 0.1 V per step" in taper
    assert "innovations" not in taper and "no online inference" not in taper and "f_a from" not in taper
    memory = text({"rate_V": 0.4, "estimator": {"innovation_window": 25}}, mpc_phi="prior",
                  mpc_model="out/models/fa_mem")
    assert "last 25 innovations" in memory and "no online inference" in memory and "`out/models/fa_mem`" in memory
    assert "reach" not in slow and "reach" not in memory      # the gate on (the default) or nothing it gates
    gate_off = text({"rate_V": 5.0, "approach_m": 2e-4, "standoff_stds": 2.0, "reach_gate": False})
    assert "`mpc.reach_gate = false`" in gate_off
    assert "reach" not in text({"rate_V": 5.0, "reach_gate": False})


def test_the_model_section_describes_the_scene_at_the_datasets_fidelity(tmp_path):
    """The report's model table shows the scene the datasets were made with: their ``scene_toml``
    matched against the scene file's fidelities (resolved: the tip zone, 11 × 11 points, × 100
    penalty), the file as written, or neither (the test fixture's tiny mesh: the file is shown and
    the sentence says so). Broken once: the fidelity looked up on C1.nc, absent here."""
    import xarray as xr

    from deapull import dataset, scene as scenes
    from deapull.workflows.report import sections_fem
    from deapull.workflows.report.document import Report
    from deapull.workflows.report.inputs import Inputs
    from tests.conftest import SWEEP
    for fidelity, want in (("preview", "preview"), ("", ""), (None, None)):
        data = tmp_path / f"data_{fidelity}"
        data.mkdir()
        with xr.open_dataset(SWEEP / "C3.nc") as ds:
            ds = ds.load()
        if fidelity is not None:
            sc = scenes.load("coin_pull", setup="C3", overrides=scenes.fidelity_overrides("coin_pull", fidelity))
            ds.attrs["scene_toml"] = sc.to_toml()
        dataset.write(ds, data / "C3.nc")
        assert sections_fem.datasets_fidelity(data) == want
        sec = sections_fem.section_model(Report(tmp_path / f"r_{fidelity}", Inputs.under(tmp_path, data=data),
                                                progress=False))
        text = " ".join(str(b[1]) for b in sec.blocks if b[0] == "p")
        table = " ".join(str(c) for b in sec.blocks if b[0] == "table" for row in b[1].rows for c in row)
        if want == "preview":
            assert "--fidelity preview" in text and "5 × 5" in table and "2.24e+10" in table
        elif want == "":
            assert "2 mm tip zone in 4" in table and "11 × 11" in table and "2.24e+11" in table
        assert ("other overrides" in text) == (want is None)
