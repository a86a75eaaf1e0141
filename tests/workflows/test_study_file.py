"""Studies as data: the fidelity ladder and the stability suite read their cases from
``studies/*.toml``; a relative value follows the scene the study runs on; a bad file is refused
naming the key, the value and what is allowed (no solve here)."""
import pytest

from deapull import scene as scenes
from deapull.errors import InputError
from deapull.workflows import fidelity, stability, study_file


def _scene(case):
    return scenes.load(case.scene, setup=case.setup, overrides=case.overrides)


def test_a_relative_value_is_taken_from_the_scene_it_runs_on():
    """``@key*f`` scales the loaded scene's key, ``@key+n`` adds to it, and an integer key stays an
    integer of at least 1. Broken once with the base value ignored (the factor alone): failed."""
    base = scenes.load("coin_pull", setup="C3", overrides=("contact.penalty_N_m3=3e11", "mesh.n_length=5"))
    out = study_file.resolve(["contact.penalty_N_m3=@contact.penalty_N_m3*0.01", "mesh.n_length=@mesh.n_length*0.5",
                              "mesh.n_width=@mesh.n_width*0.1", "mesh.level=@mesh.level+2", "coin.mu_b=0.3"], base)
    assert out == ("contact.penalty_N_m3=3000000000.0", "mesh.n_length=2", "mesh.n_width=1", "mesh.level=2",
                   "coin.mu_b=0.3")
    for bad, match in (("coin.mu_b=@coin.nope*2", "@coin.nope is not a number"),
                       ("coin.mu_b=@coin.mu_b/2", "expected key=@section.key"),
                       ("coin.mu_b=@coin.mu_b*two", "'two' is not a number")):
        with pytest.raises(InputError, match=match):
            study_file.resolve([bad], base)


def test_the_stability_cases_scale_the_scene_they_run_on():
    """The penalty, mass and step cases follow the base scene (here a user's --set), and the case
    keys of the file (scene, expected) reach the rows. Broken once with the suite's protocol applied
    after the case (dt-huge kept the protocol's 0.01 s): failed."""
    cases = {c.name: c for c in stability.stability_cases(overrides=("contact.penalty_N_m3=1e11",))}
    assert _scene(cases["penalty-x100"]).contact.penalty_N_m3 == pytest.approx(1e13)
    assert _scene(cases["mass-x10"]).coin.density_kg_m3 == pytest.approx(10 * _scene(cases["baseline"]).coin.density_kg_m3)
    assert _scene(cases["dt-huge"]).time.dt_max_s == 0.5 and _scene(cases["baseline"]).time.dt_max_s == 0.01
    tiny = _scene(cases["dt-tiny"])
    assert (tiny.load.end_time_s, tiny.time.dt_max_s) == pytest.approx((0.1, 1e-4))
    assert cases["pullin-free-bending"].scene == "free_bending" and cases["pullin-free-bending"].setup is None
    assert cases["pullin-coin-pull"].meta == {"expected": "instability", "protocol": "quick", "voltage_max_V": 1500.0}
    assert cases["nu0.5-disp"].meta["expected"] == "rejected"


def test_a_users_study_file_is_run_and_a_bad_one_is_refused(tmp_path):
    """``--study FILE``: a user's cases replace the shipped ones; an unknown case key or a value
    outside its allowed ones is refused naming them. Broken once with the key check removed: the
    typo'd key was ignored and the case ran as the baseline."""
    mine = tmp_path / "mine.toml"
    mine.write_text('[study]\nname = "mine"\nscene = "coin_pull"\nsetup = "C5"\n\n'
                    '[cases.soft]\nset = ["contact.penalty_N_m3=@contact.penalty_N_m3*0.5"]\n'
                    'description = "half the penalty"\n')
    (case,) = stability.stability_cases(study=mine)
    assert case.name == "soft" and case.setup == "C5" and case.description == "half the penalty"
    assert _scene(case).contact.penalty_N_m3 == pytest.approx(0.5 * scenes.load("coin_pull", "C5").contact.penalty_N_m3)
    for text, match in (('[cases.soft]\nsett = ["coin.mu_b=0.1"]\n', r"cases.soft.sett: unknown key; allowed: set, "
                                                                    r"description, scene, expected"),
                        ('[cases.soft]\nexpected = "maybe"\n', "cases.soft.expected = 'maybe': expected one of "
                                                               "converged, instability, rejected"),
                        ('[cases.soft]\nset = "coin.mu_b=0.1"\n', "expected a list of 'section.key=value'")):
        mine.write_text('[study]\nscene = "coin_pull"\n' + text)
        with pytest.raises(InputError, match=match):
            stability.stability_cases(study=mine)
    with pytest.raises(InputError, match="--study 'nope': unknown study; shipped: contact_reference, fidelity, "
                                         "stability"):
        stability.stability_cases(study="nope")


def test_the_ladder_file_names_its_reference_and_keeps_the_scene_step_rung_out_of_a_full_ladder(tmp_path):
    """The quick ladder adds the rung at the scene's own steps (not the ladder's end/100) and makes
    it the default; a full ladder leaves it out; a reference that names no rung is refused.
    Broken once with ``steps = "scene"`` ignored: the rung took the ladder's 0.01 s step."""
    head, rungs = fidelity.ladder()
    quick = {c.name: c for c in fidelity.ladder_cases("coin_pull", "C3", "quick")}
    shipped = _scene(quick[head["quick_default"]])
    assert shipped.time.dt_max_s == scenes.load("coin_pull", "C3").time.dt_max_s
    assert quick[head["quick_default"]].meta["is_default"] and quick[head["reference"]].meta["is_reference"]
    full = [c.name for c in fidelity.ladder_cases("coin_pull", "C3", "full")]
    assert head["quick_default"] not in full and len(full) == len(rungs) - 1
    bad = tmp_path / "ladder.toml"
    bad.write_text('[study]\nreference = "finest"\ndefault = "a"\nquick_default = "a"\n[cases.a]\n')
    with pytest.raises(InputError, match=r"study.reference = 'finest': expected one of its rungs \(a\)"):
        fidelity.ladder_cases("coin_pull", "C3", study=bad)
