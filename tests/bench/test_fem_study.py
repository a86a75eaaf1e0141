"""The reference ladder's Richardson extrapolation (deapull fem-study): an observed order,
an extrapolated value and an error bound from three levels with unequal refinement ratios,
checked on sequences f(h) = f0 + C h^p whose limit and order are known."""
from __future__ import annotations

import math
import re

import pytest

from deapull.workflows.fem_study import GCI_SAFETY, richardson

#: the ladder's element lengths (16, 24, 32 divisions): ratios 1.5 and 4/3
H = (1 / 16, 1 / 24, 1 / 32)
RATIOS = (H[0] / H[1], H[1] / H[2])


@pytest.mark.parametrize("p", [0.5, 1.0, 2.0, 3.0])
@pytest.mark.parametrize("c", [0.4, -0.3])
def test_richardson_recovers_the_order_and_the_limit(p, c):
    f0 = 1.3e-3
    travels = [f0 + c * 1e-3 * h ** p for h in H]
    order, limit, bound = richardson(travels, RATIOS)
    assert order == pytest.approx(p, rel=1e-6)
    assert limit == pytest.approx(f0, rel=1e-9)
    # the bound is the safety factor times the finest level's true error
    assert bound == pytest.approx(GCI_SAFETY * abs(travels[-1] - f0), rel=1e-6)


def test_oscillating_levels_give_no_order_and_the_larger_difference_as_bound():
    order, limit, bound = richardson([1.3563, 1.3302, 1.3400], RATIOS)
    assert math.isnan(order)
    assert limit == 1.3400
    assert bound == pytest.approx(1.3563 - 1.3302)


def test_bad_studies_cases_or_reference_are_refused_before_any_run(tmp_path, monkeypatch):
    from deapull.errors import InputError
    from deapull.workflows import fem_study

    def ran(*args, **kwargs):
        raise AssertionError("a case ran before the input was checked")

    monkeypatch.setattr(fem_study, "solve", ran)
    with pytest.raises(InputError, match="--study 'bogus'.*allowed: reference"):
        fem_study.studies_from("bogus")
    with pytest.raises(InputError, match=r"--reference .*nowhere: no reference.json"):
        fem_study.run_studies(["shipped"], tmp_path / "out", tmp_path / "nowhere")
    ref = tmp_path / "ref"
    ref.mkdir()
    (ref / "reference.json").write_text("{}")
    with pytest.raises(InputError, match="--cases: foo not in study 'shipped'"):
        fem_study.run_studies(["shipped"], tmp_path / "out", ref, cases=["foo"])


def test_a_case_writes_its_solve_log_as_it_runs_and_a_failure_quotes_it(tmp_path, monkeypatch):
    """``fem-study`` runs each case as a child ``deapull solve``; the child's output goes to
    ``<case>/solve.log`` while it runs, and a failed child is reported with that log's tail.
    A stand-in interpreter (a shell script) plays the child so that nothing is solved. Broken
    once: the output captured in memory again (no solve.log)."""
    from deapull.workflows import fem_study
    child = tmp_path / "python"
    child.write_text("#!/bin/sh\necho 'placement 40 %' >&2\necho 'DIVERGED_MAX_IT at t = 0.5 s'\nexit 3\n")
    child.chmod(0o755)
    monkeypatch.setattr(fem_study.sys, "executable", str(child))
    with pytest.raises(RuntimeError, match="DIVERGED_MAX_IT") as err:
        fem_study.solve(tmp_path / "study", "case-a", ())
    assert "(3)" in str(err.value)
    log = (tmp_path / "study" / "case-a" / "solve.log").read_text()
    assert "placement 40 %" in log and "DIVERGED_MAX_IT" in log


def test_the_reference_bound_adds_the_mesh_and_the_penalty_shares():
    """The penalty share: a travel f(k) = f_rigid + c / k measured at x 100 and x 1000 leaves
    the x 1000 level c / k_1000 from the rigid limit, which the share must equal. The mesh share:
    with an order, the GCI; oscillating levels, the two finest levels' difference (the spread of
    all three is kept). Broken once: the share as the pair's whole difference (9x too large)."""
    from deapull.workflows.fem_study import REFERENCE_TIMES, reference_estimate
    f_rigid, c = 1.311e-3, -3.9e-3 * 2.24e9            # k in units of the shipped 2.24e9 N/m^3
    pair = [f_rigid + c / (2.24e9 * k) for k in (100, REFERENCE_TIMES)]
    oscillating = [1.3470e-3, 1.3071e-3, 1.3112e-3]
    est = reference_estimate(oscillating, (2.0, 2.0), pair)
    assert est["penalty_bound_m"] == pytest.approx(abs(pair[1] - f_rigid), rel=1e-9)
    assert math.isnan(est["observed_order"]) and est["travel_extrapolated_m"] == oscillating[-1]
    assert est["mesh_bound_m"] == pytest.approx(0.0041e-3)
    assert est["three_level_spread_m"] == pytest.approx(0.0399e-3)
    assert est["travel_error_bound_m"] == pytest.approx(est["mesh_bound_m"] + est["penalty_bound_m"])
    smooth = [1.3e-3 + 0.4e-3 * h ** 2 for h in H]
    est = reference_estimate(smooth, RATIOS, pair)
    assert est["observed_order"] == pytest.approx(2.0, rel=1e-6)
    assert est["mesh_bound_m"] == pytest.approx(GCI_SAFETY * abs(smooth[-1] - 1.3e-3), rel=1e-6)


def _refine_case(out, name, travel_m, dofs, stroke_m, scene_overrides=None):
    """A stand-in dataset of one ``refine`` case: x ramps linearly to ``travel_m`` (the coin's
    push is -x), made with the case's resolved scene unless ``scene_overrides`` says otherwise."""
    import numpy as np

    from deapull import dataset
    from deapull.workflows import fem_study
    cols = {v: np.zeros(11) for v in dataset.VARIABLES}
    cols["t"] = np.linspace(0.0, 1.0, 11)
    cols["x"] = -travel_m * cols["t"]
    cols["tip_ux"] = -stroke_m * cols["t"]
    cols["n_contact"] = np.full(11, 30.0)
    overrides = fem_study.REFINE[name] if scene_overrides is None else scene_overrides
    attrs = {"scene_toml": fem_study.resolved_scene(overrides), "mesh_dofs": dofs, "wall_time_total_s": 1.0}
    dataset.write(dataset.build(cols, attrs), out / name / "C3.nc")


def test_the_refine_study_compares_with_its_finest_case_and_fits_the_layers_triple_by_triple(tmp_path):
    """``fem-study --study refine``'s own table: each case against ``resolved`` at the same step
    and against the finest case present (the most dofs), and the layers ladder 1 / 2 / 4 / 8
    through Richardson, each three levels on their own. The layers travel f0 + C h^2 except the
    first level, which is off the asymptote: the 2 / 4 / 8 triple must give order 2 and f0, the
    1 / 2 / 4 triple must say it has no order. A case made with another scene (a stale run) is
    left out. Broken once: the finest case taken by the fewest dofs (vs finest was against
    resolved, +0.00 % there)."""
    from deapull.workflows import fem_study
    f0, c = 1.2400e-3, 0.0320e-3                       # travel at h = 1 / n elements per layer
    travels = {"layers2": f0 + c / 4, "layers4": f0 + c / 16, "layers8": f0 + c / 64}
    travels[fem_study.REFINE_BASE] = travels["layers2"] + 0.0010e-3      # a first step smaller than the second
    for name, dofs in ((fem_study.REFINE_BASE, 5148), ("layers2", 9230), ("layers4", 17394), ("layers8", 33722)):
        _refine_case(tmp_path, name, travels[name], dofs, 1.66e-3)
    _refine_case(tmp_path, "level1", 1.0e-3, 34700, 1.6e-3, scene_overrides=fem_study.REFINE["layers2"])  # stale
    rows, lines = fem_study.refine_summary(tmp_path)
    by = {r["case"]: r for r in rows}
    assert set(by) == {fem_study.REFINE_BASE, "layers2", "layers4", "layers8"}
    assert lines[0].startswith("finest case: layers8 (33,722 dofs)")
    assert by["layers8"]["vs_finest_pct"] == 0.0 and by["layers8"]["x_mae_finest_pct"] == 0.0
    assert math.isclose(by["layers4"]["vs_finest_pct"], 100 * (travels["layers4"] / travels["layers8"] - 1))
    assert math.isclose(by["layers8"]["vs_base_pct"], 100 * (travels["layers8"] / travels[fem_study.REFINE_BASE] - 1))
    assert math.isclose(by["layers4"]["stroke_mm"], 1.66)
    assert math.isclose(by["layers4"]["x_09_mm"], 0.9e3 * travels["layers4"])
    [first, second] = [x for x in lines if x.startswith("layers ")]
    assert "no observed order" in first and fem_study.REFINE_BASE in first
    order, extrap = re.search(r"observed order ([\d.]+), Richardson travel ([\d.]+) mm", second).groups()
    assert abs(float(order) - 2.0) < 0.01 and abs(float(extrap) - 1e3 * f0) < 1e-4
    assert fem_study.refine_summary(tmp_path / "empty")[0] == []


def test_the_pause_study_finds_the_coins_stops_in_the_slide_and_the_contact_line_across_them(tmp_path):
    """``fem-study --study pause``: the coin stands at first (stick = 1, x = 0), slides, stops for
    records 6-8 while the contact line jumps from 3.80 to 3.71 mm, slides again, and stands at the
    end. Only records 6-8 are a stop in the slide. Broken once: the stop's last record taken one
    record late (t1 0.9 instead of 0.8, and the contact line after it 3.72 instead of 3.71)."""
    import numpy as np

    from deapull import dataset
    from deapull.workflows import fem_study
    t = np.linspace(0.0, 1.2, 13)
    stick = np.array([1, 1, 0, 0, 0, 0, 1, 1, 1, 0, 0, 1, 1], dtype=float)
    x = -1e-4 * np.cumsum(1 - stick)
    z = np.array([3.6, 3.6, 3.7, 3.75, 3.78, 3.80, 3.79, 3.75, 3.72, 3.71, 3.72, 3.72, 3.72]) * 1e-3
    [stop] = fem_study.stops(t, x, stick, contact_abs_z=z)
    assert (stop["t0"], stop["t1"]) == pytest.approx((0.6, 0.8))
    assert (stop["z_before"], stop["z_after"]) == pytest.approx((3.80e-3, 3.71e-3))
    assert fem_study.stops(t, np.zeros_like(x), np.ones_like(stick)) == []
    for name, scale in ((fem_study.PAUSE_BASE, 1.0), ("l4p2-dt10ms-shift", 1.05)):
        cols = {v: np.zeros(t.size) for v in dataset.VARIABLES}
        cols.update(t=t, x=scale * x, stick=stick, contact_abs_z=z, n_contact=np.arange(t.size) + 100.0)
        attrs = {"scene_toml": fem_study.resolved_scene(fem_study.PAUSE[name]), "mesh_dofs": 37026,
                 "wall_time_total_s": 1.0}
        dataset.write(dataset.build(cols, attrs), tmp_path / name / "C3.nc")
    by = {r["case"]: r for r in fem_study.pause_summary(tmp_path)}
    assert set(by) == {fem_study.PAUSE_BASE, "l4p2-dt10ms-shift"}
    assert by["l4p2-dt10ms-shift"]["vs_base_pct"] == pytest.approx(5.0)
    assert by[fem_study.PAUSE_BASE]["stopped"] == "0.600–0.800" and by[fem_study.PAUSE_BASE]["stops"] == 1
    assert by[fem_study.PAUSE_BASE]["contact_z_mm"] == "3.800 → 3.710"
    assert by[fem_study.PAUSE_BASE]["min_points"] == 102          # the first sliding record's


def test_the_pause_studys_ladders_state_a_bound_from_the_tip_zone_the_underside_and_the_rule(tmp_path):
    """``pause_ladders``: the tip-zone ladder's travels follow 1.15 mm + C h^2 (h = 0.5 / 0.25 /
    0.125 mm), so Richardson gives order 2, the limit 1.15 mm and the GCI 1.25 x (f3 - 1.15 mm);
    the underside's pair moves -0.2 % and the rule's +1 µm; the stated bound is the three summed.
    Without the finest tip level there is no ladder and no bound. Broken once: the rule's change
    left out of the bound (the total then 6.23 µm, not 7.23 µm)."""
    import numpy as np

    from deapull import dataset
    from deapull.workflows import fem_study
    f = {h: 1.15e-3 + 0.2e-3 * h ** 2 for h in (0.5, 0.25, 0.125)}
    travels = dict(zip(fem_study.PAUSE_TIP_LADDER, f.values()))
    travels[fem_study.PAUSE_UNDERSIDE_PAIR[1]] = travels[fem_study.PAUSE_UNDERSIDE_PAIR[0]] * (1 - 0.002)
    travels[fem_study.PAUSE_RULE_PAIR[0]] = 1.15e-3
    travels[fem_study.PAUSE_RULE_PAIR[1]] = 1.151e-3
    t = np.linspace(0.0, 1.0, 11)

    def write(name):
        cols = {v: np.zeros(t.size) for v in dataset.VARIABLES}
        cols.update(t=t, x=-travels[name] * t)
        attrs = {"scene_toml": fem_study.resolved_scene(fem_study.PAUSE[name]), "mesh_dofs": 1, "wall_time_total_s": 1.0}
        dataset.write(dataset.build(cols, attrs), tmp_path / name / "C3.nc")

    for name in travels:
        if name != fem_study.PAUSE_TIP_LADDER[-1]:
            write(name)
    lines = fem_study.pause_ladders(fem_study.pause_summary(tmp_path))
    assert not any(x.startswith(("tip zone", "stated bound")) for x in lines)
    assert any(x.startswith("underside") and "(-0.20 %)" in x for x in lines)
    write(fem_study.PAUSE_TIP_LADDER[-1])
    lines = fem_study.pause_ladders(fem_study.pause_summary(tmp_path))
    [tip] = [x for x in lines if x.startswith("tip zone")]
    gci = 1.25 * 0.2e-3 * 0.125 ** 2
    assert "observed order 2.00" in tip and "Richardson travel 1.1500 mm" in tip
    [stated] = [x for x in lines if x.startswith("stated bound")]
    total = gci + 0.002 * f[0.25] + 1e-6
    assert f"± {1e3 * total:.4f} mm" in stated and f"({100 * total / 1.15e-3:.2f} %" in stated


def _beyond(folder, runs, bound_rel=None):
    """A ``beyond_the_ladder.json`` in ``folder``: ``runs`` as (travel_m, resolved_same_step_m)."""
    import json
    doc = {"runs": [{"refines": f"direction {i}", "dofs": 1000 * (i + 1), "dt_max_s": 0.005, "travel_m": t,
                     "resolved_same_step_m": r} for i, (t, r) in enumerate(runs)]}
    if bound_rel is not None:
        doc["finest_ladder"] = {"bound_rel": bound_rel}
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "beyond_the_ladder.json").write_text(json.dumps(doc))


def test_the_ladders_table_says_what_its_bound_leaves_out(tmp_path, monkeypatch):
    """A reference whose ladder refines some directions only: the runs refined in the others
    (``beyond_the_ladder.json``, the folder's own before the committed one) are listed under the
    table with their change against ``resolved`` at the same step, and the table says that no
    bound ≤ 1 % is stated and that the error is likely the smallest change or more. Without such
    runs the table is the ladder's alone. Broken once: the smallest change taken by sign (−10 %,
    not the +4 % nearest zero)."""
    import json

    from deapull.workflows import fem_study
    ref = {"cases": ["a", "b", "c"], "travel_m": [1.2e-3, 1.1e-3, 1.1e-3], "dofs": [1, 2, 3], "wall_s": [1, 2, 3],
           "observed_order": float("nan"), "travel_extrapolated_m": 1.1e-3, "travel_error_bound_m": 3.3e-6,
           "travel_error_bound_rel": 0.003, "error_bound_rel": 0.003}
    folder = tmp_path / "ref"
    folder.mkdir()
    (folder / "reference.json").write_text(json.dumps(ref))
    monkeypatch.setattr(fem_study, "COMMITTED_REFERENCE", tmp_path / "committed")
    assert "beyond" not in fem_study.ladder_table(fem_study.load_reference(folder))
    _beyond(tmp_path / "committed", [(0.9e-3, 1.0e-3)])
    _beyond(folder, [(0.9e-3, 1.0e-3), (1.04e-3, 1.0e-3), (1.15e-3, 1.25e-3)], bound_rel=0.043)
    loaded = fem_study.load_reference(folder)
    gap = fem_study.ladder_gap(loaded)
    assert gap["least_rel"] == pytest.approx(0.04) and gap["most_rel"] == pytest.approx(-0.1)
    table = fem_study.ladder_table(loaded)
    assert re.search(r"direction 2: 3,000 dofs, dt 0.005 s, travel 1.1500 mm, -8.0 %", table), table
    assert "moves the travel +4.0 % to -10.0 %" in table and "bound 4.3 %" in table
    assert "none ≤ 1 % (goal)" in table and "likely 4.0 % or more" in table
    # a folder without its own runs takes the committed ones
    (folder / "beyond_the_ladder.json").unlink()
    assert fem_study.ladder_gap(fem_study.load_reference(folder))["most_rel"] == pytest.approx(-0.1)


def test_the_committed_reference_carries_the_runs_beyond_its_ladder():
    """The committed reference (bench/reference) and its runs beyond the ladder: the layers move
    the travel 5 % or more, so the printed table states no bound ≤ 1 %."""
    from deapull.workflows import fem_study
    ref = fem_study.load_reference(fem_study.COMMITTED_REFERENCE)
    gap = fem_study.ladder_gap(ref)
    assert gap is not None and abs(gap["least_rel"]) > 0.04 and len(gap["runs"]) >= 4
    assert "stated bound on the reference: none ≤ 1 % (goal)" in fem_study.ladder_table(ref)
