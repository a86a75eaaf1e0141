"""The convergence study's numbers (workflows/convergence.py) and the generated tables
(workflows/docs_tables.py) against cases with known answers."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from deapull.errors import InputError
from deapull.workflows import convergence, docs_tables
from tests.conftest import REPO


@pytest.mark.parametrize("p", [0.8, 2.0, 3.5])
def test_a_ladder_of_a_known_power_law_gives_its_order_and_limit(p):
    """f(h) = 1.25 + 0.1 h^p at h = 1, 1/2, 1/4: the observed order is p, the Richardson value
    1.25, and the fine level's GCI is F_s times its true relative error. Broken once with the
    ladder taken fine to coarse: the order came out negative."""
    f = [1.25 + 0.1 * h ** p for h in (1.0, 0.5, 0.25)]
    got = convergence.observed(*f, 2.0)
    assert got["observed_order"] == pytest.approx(p, rel=1e-10)
    assert got["richardson"] == pytest.approx(1.25, rel=1e-12)
    assert got["gci_percent"] == pytest.approx(1.25 * 100 * abs(f[2] - 1.25) / f[2], rel=1e-10)
    assert convergence.order_of_differences(abs(f[1] - f[0]), abs(f[2] - f[1]), 2.0) == pytest.approx(p)


def test_a_ladder_that_turns_back_has_no_order():
    got = convergence.observed(1.0, 1.1, 1.05, 2.0)
    assert not got["monotone"] and math.isnan(got["observed_order"]) and math.isnan(got["gci_percent"])


def test_a_ladder_whose_steps_grow_has_no_richardson_value_only_roaches_fallback():
    """Monotone but with a fine step larger than the coarse one (order < 0, as the tip ladder at the
    rim band's 8 divisions): no Richardson value and no GCI (a negative GCI once made the bound
    −0.72 %); the fallback GCI is 3 × the fine step / (2 − 1)."""
    got = convergence.observed(1.0, 1.01, 1.03, 2.0)
    assert got["monotone"] and got["observed_order"] == pytest.approx(-1.0)
    assert math.isnan(got["richardson"]) and math.isnan(got["gci_percent"])
    assert got["gci_fixed_order_percent"] == pytest.approx(100 * 3 * 0.02 / 1.03)


def test_a_study_naming_a_case_it_lacks_is_refused_before_any_run(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('[study]\nscene = "coin_pull"\nsetup = "C3"\ntime_s = 0.95\n[cases]\na = []\nb = []\n'
                   '[ladders.x]\ncases = ["a", "b", "c"]\nratio = 2\n')
    with pytest.raises(InputError, match=r"ladders\.x\.cases"):
        convergence.load_study(bad)
    bad.write_text('[study]\nscene = "coin_pull"\nsetup = "C3"\ntime_s = 0.95\n[cases]\na = []\nb = []\nc = []\n'
                   '[ladders.x]\ncases = ["a", "b", "c"]\nratio = 2\n[checks]\ncandidates = ["z"]\n')
    with pytest.raises(InputError, match=r"\[checks\] names 'z', not a case"):
        convergence.load_study(bad)
    with pytest.raises(InputError, match="unknown study"):
        convergence.load_study("no_such_study")
    shipped = convergence.load_study("contact_reference")
    assert shipped["checks"]["corner"] == "corner" and shipped["checks"]["default"] == "default"
    assert "rim band x 2" in shipped["checks"]["converged"]


def test_the_committed_reference_bound_is_its_rungs_bound():
    """bench/reference/contact_reference.json's bound recomputed from its rungs' stored x(0.95 s)
    and the step's change (the JSON is what `make fem-study` publishes). Broken once with one
    rung's value edited in the JSON: it failed."""
    path = REPO / "bench" / "reference" / "contact_reference.json"
    if not path.is_file():
        pytest.fail(f"{path} is missing: make fem-study publishes it")
    result = json.loads(path.read_text())
    if not all(lad["complete"] for lad in result["ladders"].values()) or math.isnan(result["bound_percent"]):
        # a ladder not solved to its end, or outside its asymptotic range: no bound either way
        assert math.isnan(result["bound_percent"]) and math.isnan(convergence.bound_from_rungs(result))
        return
    assert convergence.bound_from_rungs(result) == pytest.approx(result["bound_percent"], rel=1e-9)
    for lad in result["ladders"].values():
        assert lad["x_at_t_mm"] == [result["cases"][n]["x_at_t_mm"] for n in lad["cases"]]


def test_the_pages_tables_are_their_results_files():
    """Every results block of the README and docs/ is what its file renders to (deapull docs)."""
    assert docs_tables.stale_pages() == []


def test_a_results_block_is_rewritten_from_its_file(tmp_path):
    (tmp_path / "bench" / "reference").mkdir(parents=True)
    page = tmp_path / "README.md"
    page.write_text("a\n<!-- results:headline -->\nold\n<!-- /results:headline -->\nb\n")
    assert "is missing" in docs_tables.render(page.read_text(), tmp_path)
    result = {"time_s": 0.95, "bound_percent": 0.5, "default_error_percent": 1.0, "default_case": "default",
              "cases": {"default": {"wall_s": 60.0, "dofs": 100, "travel_mm": 1.2, "min_points": 25}}}
    (tmp_path / "bench" / "reference" / "contact_reference.json").write_text(json.dumps(result))
    text = docs_tables.render(page.read_text(), tmp_path)
    assert "| coin travel, C3 at 400 V | 1.200 mm |" in text and "old" not in text and text.endswith("\nb\n")
    speed = {"runs": {"data fidelity (scene file)": {"wall_s": 60.0, "dofs": 100},
                      "baseline: linear predictor": {"wall_s": 120.0, "dofs": 100}}}
    (tmp_path / "bench" / "reference" / "fem_speed.json").write_text(json.dumps(speed))
    text = docs_tables.render("<!-- results:fem_speed_headline -->\nold\n<!-- /results:fem_speed_headline -->", tmp_path)
    assert "| 60 s at 100 dofs (the solver path before its last speed-up: 120 s, same run) | 130 s (ABAQUS) |" in text
    with pytest.raises(KeyError, match="nope"):
        docs_tables.render("<!-- results:nope -->\nx\n<!-- /results:nope -->", tmp_path)


def test_two_ladders_through_different_cases_meet_at_their_corner():
    """Errors that add, x(a, b) = 1 + 0.1 h_a^2 + 0.05 h_b: a tip ladder at h_a = 1/2, 1/4, 1/8 on the
    coarsest layers and a layers ladder at h_b = 1, 1/2, 1/4 on the coarsest tip zone share no case;
    with the corner (h_a = 1, h_b = 1) named the reference is the exact 1. Broken once with the corner
    left out: no reference (the ladders share no case)."""
    def x(ha, hb):
        return 1.0 + 0.1 * ha ** 2 + 0.05 * hb
    grid = {"a2": (0.5, 1.0), "a4": (0.25, 1.0), "a8": (0.125, 1.0), "b1": (1.0, 1.0), "b2": (1.0, 0.5),
            "b4": (1.0, 0.25)}
    metrics = {n: {"x_at_t_mm": x(*h), "x_end_mm": x(*h), "peak_overlap_um": 1.0, "min_points": 30,
                   "t": [0.0, 1.0], "x": [0.0, 1e-3 * x(*h)]} for n, h in grid.items()}
    study = {"study": {"scene": "coin_pull", "time_s": 0.95}, "cases": {n: [] for n in grid},
             "ladders": {"tip": {"cases": ["a2", "a4", "a8"], "ratio": 2},
                         "layers": {"cases": ["b1", "b2", "b4"], "ratio": 2}},
             "checks": {"corner": "b1", "default": "a2"}, "path": "x.toml"}
    out = convergence.summarise(study, metrics)
    assert out["ladders"]["tip"]["observed_order_x_at_t"] == pytest.approx(2.0)
    assert out["ladders"]["layers"]["observed_order_x_at_t"] == pytest.approx(1.0)
    assert out["reference_x_at_t_mm"] == pytest.approx(1.0, rel=1e-12)
    assert out["default_error_percent"] == pytest.approx(100 * (x(0.5, 1.0) - 1.0), rel=1e-9)
    del study["checks"]["corner"]
    assert math.isnan(convergence.summarise(study, metrics)["reference_x_at_t_mm"])


def test_a_candidate_mesh_is_measured_against_the_reference():
    """``[checks] candidates``: a case that could replace the data fidelity gets its error against the
    additive reference (here x(1/4, 1/2) of x = 1 + 0.1 h_a^2 + 0.05 h_b, exact reference 1), printed with
    its cost."""
    def x(ha, hb):
        return 1.0 + 0.1 * ha ** 2 + 0.05 * hb
    grid = {"a2": (0.5, 1.0), "a4": (0.25, 1.0), "a8": (0.125, 1.0), "b1": (1.0, 1.0), "b2": (1.0, 0.5),
            "b4": (1.0, 0.25), "cand": (0.25, 0.5)}
    metrics = {n: {"x_at_t_mm": x(*h), "x_end_mm": x(*h), "peak_overlap_um": 1.0, "min_points": 30,
                   "t": [0.0, 1.0], "x": [0.0, 1e-3 * x(*h)], "dofs": 1000, "wall_s": 10.0} for n, h in grid.items()}
    study = {"study": {"scene": "coin_pull", "time_s": 0.95}, "cases": {n: [] for n in grid},
             "ladders": {"tip": {"cases": ["a2", "a4", "a8"], "ratio": 2},
                         "layers": {"cases": ["b1", "b2", "b4"], "ratio": 2}},
             "checks": {"corner": "b1", "default": "a2", "candidates": ["cand"]}, "path": "x.toml"}
    out = convergence.summarise(study, metrics)
    assert out["candidates"]["cand"]["error_percent"] == pytest.approx(100 * (x(0.25, 0.5) - 1.0), rel=1e-9)
    assert any(line.startswith("  candidate cand (") and "+3.125 %" in line for line in convergence.report_lines(out))


def test_a_published_case_is_reused_only_with_its_overrides_and_keeps_its_x_of_t():
    """``--reuse``: a case of a published result is taken where its overrides are the study's, with
    x(t) from the stored series (the differences between levels come out as from the datasets, to
    the series' resolution); a case whose overrides changed is solved again. Broken once with the
    overrides' comparison left out: case b was taken."""
    t = convergence.GRID
    x_a, x_b = -1e-3 * t ** 2, -1.1e-3 * t ** 2
    study = {"cases": {"a": [], "b": ["mesh.n_passive=4"]}}
    metrics = {"a": {"x_at_t_mm": -0.9, "t": t, "x": x_a}, "b": {"x_at_t_mm": -1.0, "t": t, "x": x_b}}
    previous = {"cases": {n: {"x_at_t_mm": m["x_at_t_mm"], **convergence._series(m)} for n, m in metrics.items()},
                "overrides": {"a": [], "b": ["mesh.n_passive=2"]}}
    got = convergence.reused_metrics(previous, study, ["a", "b"])
    assert list(got) == ["a"] and got["a"]["reused"] and got["a"]["x_at_t_mm"] == -0.9
    np.testing.assert_allclose(np.interp(t, got["a"]["t"], got["a"]["x"]), x_a, atol=1e-8)
    reused_b = {"t": got["a"]["t"], "x": np.interp(got["a"]["t"], t, x_b)}
    assert convergence.mae_mm(got["a"], reused_b) == pytest.approx(convergence.mae_mm(metrics["a"], metrics["b"]),
                                                                   rel=1e-3)
    assert math.isnan(convergence.mae_mm({"x_at_t_mm": 1.0}, metrics["a"]))


def test_a_published_case_solved_on_another_scene_file_is_not_reused():
    """A published case carries the digest of the resolved scene it was solved on: with the scene file
    changed under the same overrides (the data fidelity moved), it is solved again, not taken. Broken
    once with the digest's comparison left out: the stale case was taken."""
    from deapull import scene as scenes
    from deapull.workflows.runner import scene_digest
    study = {"study": {"scene": "coin_pull", "setup": "C3"},
             "cases": {"now": ["contact.quadrature_degree=42"], "before": ["contact.quadrature_degree=42"]}}
    today = scene_digest(scenes.load("coin_pull", setup="C3", overrides=("contact.quadrature_degree=42",)))
    other = scene_digest(scenes.load("coin_pull", setup="C3", overrides=("contact.quadrature_degree=42",
                                                                         "mesh.n_length=8")))
    previous = {"cases": {"now": {"x_at_t_mm": -1.0, "scene_digest": today},
                          "before": {"x_at_t_mm": -1.1, "scene_digest": other}},
                "overrides": study["cases"]}
    assert list(convergence.reused_metrics(previous, study, ["now", "before"])) == ["now"]


def test_the_committed_reference_is_its_study_summarised_from_its_own_cases():
    """The published contact reference, re-summarised from the cases it holds under today's study
    file (studies/contact_reference.toml), gives its own bound, reference and data-fidelity error:
    the JSON and the study's ladders agree. Broken once with the tip ladder's cases in the study
    file set back to the data fidelity's coarse level: the bound came out 1.011 %."""
    path = REPO / "bench" / "reference" / "contact_reference.json"
    published = json.loads(path.read_text())
    study = convergence.load_study("contact_reference")
    metrics = convergence.reused_metrics(published, study, list(study["cases"]))
    assert sorted(metrics) == sorted(published["cases"])
    again = convergence.summarise(study, metrics)
    convergence.keep_published_mae(again, published)
    for key in ("bound_percent", "reference_x_at_t_mm", "default_error_percent"):
        assert again[key] == pytest.approx(published[key], rel=1e-9), key
    for name, lad in again["ladders"].items():
        assert lad["cases"] == published["ladders"][name]["cases"]


def test_the_fem_control_block_judges_g5_on_all_eight_plants():
    """G5 is met only with all eight FEM plants run: ≥ 22/24 settled, overshoot ≤ 10 µm, median ≤ 450."""
    def group(k, its=(450, 270, 270), settled=3, past=0.0):
        return {"policy": "mpc", "plant": f"fem:C{k}", "task": "-0.8", "episodes": 3, "settled": settled,
                "largest_overshoot_m": past, "iterations": list(its)}
    every = {"groups": [group(k) for k in range(1, 9)]}
    assert "settled 24/24, median 270" in docs_tables.control_fem(every) and ": met)" in docs_tables.control_fem(every)
    six = {"groups": every["groups"][:6]}
    assert "on 6 of the 8" in docs_tables.control_fem(six) and "not met" in docs_tables.control_fem(six)
    past = {"groups": every["groups"][:7] + [group(8, past=12e-6)]}
    assert "not met" in docs_tables.control_fem(past)
    slow = {"groups": [group(k, its=(900, 600, None), settled=2) for k in range(1, 9)]}
    assert "settled 16/24" in docs_tables.control_fem(slow) and "not met" in docs_tables.control_fem(slow)


def test_the_readmes_control_lines_pool_the_plants_of_each_noise():
    """The README's control lines: per noise the MPC's episodes on both surrogate plants pooled (the
    other policies left out), and the FEM plants' settled count, median and worst overshoot."""
    def group(policy, plant, noise, its, reached, settled):
        return {"policy": policy, "plant": plant, "noise_std_m": noise, "episodes": len(its), "reached": reached,
                "settled": settled, "iterations": list(its), "largest_overshoot_m": 3e-6}
    result = {"groups": [group("mpc", "surrogate:C1", 1e-4, (80, 90), 2, 2), group("mpc", "surrogate:C2", 1e-4, (100, None), 1, 0),
                         group("pd", "surrogate:C1", 1e-4, (1500, 1500), 2, 2), group("mpc", "surrogate:C1", 0.0, (84, 84), 2, 2)]}
    text = docs_tables.control_headline(result)
    assert "noise 0.0001 m | reached 3/4, median 90 iterations; settled within ±10 µm 2/4" in text
    assert "noise 0 m | reached 2/2, median 84" in text and text.count("| control:") == 2
    fem = {"groups": [group("mpc", f"fem:C{k}", 1e-4, (400, 250, 260), 3, 3 - (k == 1)) for k in range(1, 9)]}
    assert "(8 setups, 80 % of each one's travel, noise 1e-4 m) | settled 23/24, median 260 iterations, at most 3.0 µm past" \
        in docs_tables.control_fem_headline(fem)


def test_the_multi_setpoint_block_is_met_only_where_every_setpoint_settled():
    """The push-push-pull-back task's rows come from the episodes' rows (summary_counts keeps each
    episode's setpoints settled and iterations to each), and the goal needs every setpoint settled."""
    from deapull.workflows.control_outputs import summary_counts

    def row(episode, settled, its):
        return {"policy": "mpc", "plant": "fem:C3", "noise_std_m": 1e-4, "setpoints_mm": "-0.5;-1;-0.7",
                "episode": episode, "status": "ok", "reached": True, "settled": settled == 3,
                "iterations_to_target": its[0], "overshoot_m": 2e-6, "setpoints_settled": settled,
                "iterations_per_setpoint": ";".join(str(i) for i in its)}
    good = {"groups": summary_counts([row(0, 3, (300, 120, 90))])}
    assert good["groups"][0]["iterations_per_setpoint"] == [[300, 120, 90]]
    text = docs_tables.control_fem_multi(good)
    assert "| fem:C3 | -0.5, -1, -0.7 | 1 | 300 / 120 / 90 | 3/3 | 2.0 |" in text and ": met)" in text
    short = {"groups": summary_counts([row(0, 3, (300, 120, 90)), row(1, 2, (280, 110, None))])}
    assert "280 / 110 / –" in docs_tables.control_fem_multi(short)
    assert "in 1 of 2 episode(s)" in docs_tables.control_fem_multi(short)
    assert "not met" in docs_tables.control_fem_multi(short)


def test_the_fem_control_block_names_the_commit_that_ran_each_plant():
    """Plants run one command each carry their own commit (a table of mixed runs says which is which);
    a summary written in one run carries one; a summary without any shows no commit column."""
    def group(k, commit=None):
        g = {"policy": "mpc", "plant": f"fem:C{k}", "task": "-0.8", "episodes": 3, "settled": 3,
             "largest_overshoot_m": 0.0, "iterations": [450, 270, 270]}
        return g if commit is None else {**g, "git_commit": commit}
    mixed = docs_tables.control_fem({"groups": [group(1, "aaaaaaa1234"), group(2, "bbbbbbb5678")]})
    lines = mixed.splitlines()
    assert lines[0].endswith("run at commit |")
    assert lines[2].endswith("| aaaaaaa |") and lines[3].endswith("| bbbbbbb |")
    one_run = docs_tables.control_fem({"git_commit": "ccccccc9", "groups": [group(1), group(2, "ddddddd0")]})
    assert one_run.splitlines()[2].endswith("| ccccccc |") and one_run.splitlines()[3].endswith("| ddddddd |")
    assert "commit" not in docs_tables.control_fem({"groups": [group(1), group(2)]})
    noted = docs_tables.control_fem({"groups": [group(1, "before fd8c86c"), group(2, "e" * 40)]}).splitlines()
    assert noted[2].endswith("| before fd8c86c |") and noted[3].endswith("| eeeeeee |")


def test_the_pairs_table_gives_the_bands_coverage_beside_its_goal():
    """surrogate_pairs: where pairs.json holds each held-out run's band coverage, the page says the
    mean and the lowest beside the goal; a result without bands has no such line. Broken once with
    the mean taken over the excitation runs too: 60.0 % read 50.0 %."""
    run = {"pair": "C1/C2", "travel_m": 1e-3, "f-patch-lag": 0.2}
    result = {"kinds": ["f-patch-lag"], "labels": {"f-patch-lag": "f (tip patch, lag)"}, "band_level": 0.9,
              "designs": {"C1/C2": {"train": ["C4"], "val": ["C3"]}},
              "runs": [{**run, "run": "C1", "protocol": "ramp", "band_coverage": {"f-patch-lag": 0.5}},
                       {**run, "run": "C2", "protocol": "ramp", "band_coverage": {"f-patch-lag": 0.7}},
                       {**run, "run": "C1_rhr", "protocol": "rhr", "band_coverage": {"f-patch-lag": 0.3}}]}
    text = docs_tables.surrogate_pairs(result)
    assert "held-out ramps: its 90 % band covers 60.0 % of the points (lowest 50.0 %; goal ≥ 80 %)" in text
    assert "held-out excitation runs: its 90 % band covers 30.0 %" in text
    for r in result["runs"]:
        r.pop("band_coverage")
    assert "band covers" not in docs_tables.surrogate_pairs(result)


def test_the_stability_block_counts_and_names_the_cases_not_as_expected():
    headers = ["case", "converged", "as expected", "steps", "Newton its", "cut-backs", "travel mm", "wall s", "outcome"]
    result = {"header": "Study `stability`", "pull_in": ["`pullin`: detected at V = 900 V"],
              "table": {"headers": headers, "rows": [["a", "yes", "yes", "101", "300", "0", "1.2", "60", "converged"],
                                                     ["b", "no", "no", "40", "900", "12", "–", "30", "failed: x|y"]]},
              "not_as_expected": ["b"]}
    text = docs_tables.stability(result)
    assert "| a | yes | 101 | 300 | 0 | 1.2 | 60 | converged |" in text
    assert "failed: x\\|y" in text and "converged | yes" not in text      # the cell's bar escaped; a column left out
    assert text.endswith("1 of 2 cases as expected; not as expected: b.") and "* `pullin`: detected" in text


def test_every_docs_page_is_checked_for_stale_tables(tmp_path):
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "new_page.md").write_text("<!-- results:headline -->\nold\n<!-- /results:headline -->\n")
    assert docs_tables.stale_pages(tmp_path) == ["docs/new_page.md"]
