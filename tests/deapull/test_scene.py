"""Scene files: every shipped scene loads; every class of bad input fails clearly."""
import dataclasses
import subprocess
import sys

import pytest

from deapull import scene as scenes
from deapull.workflows.cli import main


@pytest.mark.parametrize("name", scenes.list_scenes())
def test_every_shipped_scene_loads_and_round_trips(name, tmp_path):
    sc = scenes.load(name)
    path = tmp_path / "resolved.toml"
    path.write_text(sc.to_toml())
    again = scenes.load(path)
    assert again.to_dict() == sc.to_dict()


def test_setups_apply_the_design_table():
    table = {"C1": (7700, 0.50, 0.20), "C2": (7800, 0.50, 0.20), "C3": (7700, 0.55, 0.20),
             "C4": (7800, 0.55, 0.20), "C5": (7700, 0.50, 0.25), "C6": (7800, 0.50, 0.25),
             "C7": (7700, 0.55, 0.25), "C8": (7800, 0.55, 0.25)}
    assert scenes.setups_of("coin_pull") == list(table)
    for setup, (rho, mu_t, mu_b) in table.items():
        c = scenes.load("coin_pull", setup=setup).coin
        assert (c.density_kg_m3, c.mu_t, c.mu_b) == (rho, mu_t, mu_b)
    assert scenes.load("coin_pull").setup == "C3"


def test_free_bending_has_no_coin():
    sc = scenes.load("free_bending")
    assert sc.coin is None and sc.stop is None and not sc.has_obstacle


@pytest.mark.parametrize("assignment, key", [
    ("coin.density_kg_m3=-1", "coin.density_kg_m3"),
    ("coin.radius_m=0", "coin.radius_m"),
    ("dea.youngs_modulus_Pa=-5", "dea.youngs_modulus_Pa"),
    ("dea.poisson_ratio=0.6", "dea.poisson_ratio"),
    ("dea.poisson_ratio=-1", "dea.poisson_ratio"),
    ("dea.length_m=nan", "dea.length_m"),
    ("load.voltage_max_V=nan", "load.voltage_max_V"),
    ("load.voltage_max_V=inf", "load.voltage_max_V"),
    ("coin.mu_t=-0.1", "coin.mu_t"),
    ("coin.mu_b=-0.1", "coin.mu_b"),
    ("dea.length_m='long'", "dea.length_m"),
    ("mesh.cell='prism'", "mesh.cell"),
    ("mesh.n_length=2.5", "mesh.n_length"),
    ("coin.colour=1", "coin.colour"),
    ("nosection.key=1", "nosection.key"),
    ("gravity_m_s2=-9.8", "gravity_m_s2"),
    ("dea.film_thickness_m=0.01", "dea.film_thickness_m"),
])
def test_bad_values_name_the_key(assignment, key):
    with pytest.raises(scenes.SceneError, match=key.replace(".", r"\.")):
        scenes.load("coin_pull", overrides=[assignment])


def test_unknown_setup_lists_the_allowed_ones():
    with pytest.raises(scenes.SceneError, match="C9.*C1, C2"):
        scenes.load("coin_pull", setup="C9")
    with pytest.raises(scenes.SceneError, match="no setups"):
        scenes.load("free_bending", setup="C1")


def test_a_fidelity_is_a_named_set_of_overrides_that_the_users_set_overrides(capsys):
    """The file as written is the data fidelity; ``preview`` coarsens its resolution only."""
    data = scenes.load("coin_pull", setup="C5")
    sets = scenes.fidelity_overrides("coin_pull", "preview")
    quick = scenes.load("coin_pull", setup="C5", overrides=sets)
    assert (data.mesh.tip_zone_divisions, quick.mesh.tip_zone_divisions) == (4, 2)
    assert (data.contact.quadrature_degree, quick.contact.quadrature_degree) == (20, 8)
    assert (data.solver.linear_solver, quick.solver.linear_solver) == ("mumps", "umfpack")
    assert (quick.table.height_m, quick.table.mu_g) == (data.table.height_m, data.table.mu_g)   # the same table
    # only resolution changes: the coin, the DEA and the load are the file's
    assert (quick.coin, quick.dea, quick.load, quick.setup) == (data.coin, data.dea, data.load, "C5")
    assert scenes.fidelity_overrides("coin_pull", None) == () and scenes.fidelities_of("coin_pull") == ["preview"]
    # --set after the fidelity wins
    assert scenes.load("coin_pull", overrides=(*sets, "mesh.n_length=12")).mesh.n_length == 12
    assert main(["show-scene", "coin_release", "--fidelity", "preview", "--set", "mesh.n_length=12"]) == 0
    shown = capsys.readouterr().out
    assert "tip_zone_divisions = 2" in shown and "n_length = 12" in shown


def test_an_unknown_fidelity_lists_the_allowed_ones(capsys):
    with pytest.raises(scenes.SceneError, match="'fine'.*allowed: preview"):
        scenes.fidelity_overrides("coin_pull", "fine")
    with pytest.raises(scenes.SceneError, match="no fidelities"):
        scenes.fidelity_overrides("free_bending", "preview")
    assert main(["show-scene", "coin_pull", "--fidelity", "fine"]) == 2
    assert "fidelity = 'fine'" in capsys.readouterr().err


def test_missing_and_unknown_keys_in_a_file(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('[scene]\ndescription = "x"\n')
    with pytest.raises(scenes.SceneError, match=r"scene\.name: missing"):
        scenes.load(bad)
    bad.write_text('[scene]\nname = "x"\ndescription = "x"\n[dea]\nlenght_m = 0.02\n')
    with pytest.raises(scenes.SceneError, match=r"dea\.lenght_m: unknown key"):
        scenes.load(bad)
    bad.write_text('[scene]\nname = "x"\ndescription = "x"\n[load]\nvoltage_max_V = nan\n')
    with pytest.raises(scenes.SceneError, match=r"load\.voltage_max_V = nan"):
        scenes.load(bad)
    with pytest.raises(scenes.SceneError, match="no such file"):
        scenes.load(tmp_path / "missing.toml")


def test_cli_exits_2_with_a_message_and_no_traceback(tmp_path, capsys):
    rc = main(["mesh", "--scene", "coin_pull", "--set", "coin.density_kg_m3=-1", "--out", str(tmp_path / "m")])
    err = capsys.readouterr().err
    assert rc == 2
    assert "coin.density_kg_m3 = -1" in err and "Traceback" not in err
    assert not (tmp_path / "m").exists()


def test_console_script_exit_status(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "deapull.workflows", "show-scene", "coin_pull", "--set",
                           "coin.mu_b=nan"], capture_output=True, text=True)
    assert proc.returncode == 2 and "coin.mu_b" in proc.stderr and "Traceback" not in proc.stderr
    proc = subprocess.run([sys.executable, "-m", "deapull.workflows", "show-scene", "coin_pull", "--setup", "C2"],
                          capture_output=True, text=True)
    assert proc.returncode == 0 and "density_kg_m3 = 7800.0" in proc.stdout


def test_every_key_is_documented():
    rows = scenes.describe_keys()
    assert all(doc for *_, doc in rows)
    assert {"coin.density_kg_m3", "load.voltage_max_V", "gravity_m_s2", "mesh.level"} <= {r[0] for r in rows}


def test_the_keys_page_is_generated_from_the_schema():
    """docs/scene_keys.md is what `deapull show-scene --keys` prints (regenerate it with that command
    when a key changes). Broken once with a key's doc edited in scene.py: it failed."""
    from tests.conftest import REPO
    page = (REPO / "docs" / "scene_keys.md").read_text()
    assert page == scenes.keys_markdown()
    assert all(f"`{key}`" in page for key, *_ in scenes.describe_keys())


def test_a_dataset_written_before_the_penalty_in_n_m3_still_reads():
    """The committed fixture's C3 (written with contact.penalty_scale = 10 on an 8-element mesh:
    k_n = 10 E / 5 mm) reads with its penalty in N/m^3."""
    import xarray as xr
    from tests.conftest import DATA
    text = xr.open_dataset(DATA / "sweep" / "C3.nc").attrs["scene_toml"]
    assert "penalty_scale" in text
    sc = scenes.from_resolved_toml(text)
    assert sc.contact.penalty_N_m3 == pytest.approx(10 * 0.56e6 / 0.005, rel=1e-12)
    again = scenes.from_resolved_toml(scenes.load("coin_pull").to_toml())
    assert again.contact == scenes.load("coin_pull").contact and again.table == scenes.load("coin_pull").table


def test_a_fidelity_entry_for_one_protocol_applies_only_under_that_protocol(tmp_path):
    path = tmp_path / "two.toml"
    text = scenes.resolve_path("coin_pull").read_text()
    path.write_text(text + '\n[fidelities.banded]\n"mesh.rim_band_width_m" = 0.0\n"mesh.rim_band_m" = [0.003, 0.005]\n'
                    '\n[fidelities.banded.release]\n"mesh.rim_band_m" = [0.0015, 0.004]\n'
                    '"mesh.rim_band_divisions" = 5\n"table.penalty_N_m3" = 2e12\n')
    sets = scenes.fidelity_overrides(path, "banded")
    release = ("load.protocol='release'", "load.ramp_time_s=1.0", "load.end_time_s=1.0")
    ramp = scenes.load(path, setup="C1", overrides=sets)
    pulled = scenes.load(path, setup="C1", overrides=(*release, *sets))
    assert (ramp.mesh.rim_band_m, ramp.mesh.rim_band_divisions) == ((0.003, 0.005), 8)
    assert (pulled.mesh.rim_band_m, pulled.mesh.rim_band_divisions) == ((0.0015, 0.004), 5)
    assert dataclasses.replace(pulled.mesh, rim_band_m=ramp.mesh.rim_band_m, rim_band_divisions=8) == ramp.mesh
    assert (ramp.table.penalty_N_m3, pulled.table.penalty_N_m3) == (1e12, 2e12)
    assert (pulled.contact, pulled.coin, pulled.solver) == (ramp.contact, ramp.coin, ramp.solver)
    # the protocol may come after the entry; a later --set still wins
    assert scenes.load(path, overrides=(*sets, *release)).mesh.rim_band_m == (0.0015, 0.004)
    assert scenes.load(path, overrides=(*release, *sets, "mesh.rim_band_divisions=7")).mesh.rim_band_divisions == 7
    # the release scene places its band where the edge placed at 400 V crosses the rim
    own = scenes.load("coin_release")
    assert (own.mesh.rim_band_m, own.table.penalty_N_m3) == ((0.0015, 0.004), 2e12)


@pytest.mark.parametrize("assignment, message", [
    ("mesh.rim_band_m@sine9=[0.001,0.002]", "unknown protocol 'sine9'.*allowed: ramp"),
    ("load.voltage_max_V@release=300", "load key cannot depend on the protocol"),
    ("mesh.rim_bnd_m@release=[0.001,0.002]", "unknown key 'mesh.rim_bnd_m'.*rim_band_m"),
])
def test_a_per_protocol_override_is_checked_even_when_it_does_not_apply(assignment, message):
    with pytest.raises(scenes.SceneError, match=message):
        scenes.load("coin_pull", overrides=(assignment,))          # a ramp scene: the entry is for another


def test_a_key_added_after_the_datasets_is_written_only_when_set():
    """``mesh.underside_grading`` came after the datasets: at its default the resolved scene
    (what a dataset records and a resume compares) leaves it out, so a dataset made before it
    still matches its scene; set, it is written and loads back. Broken once: the key always
    written (the scene at the default then differed from the older one's TOML)."""
    import tomllib
    sc = scenes.load("coin_pull", setup="C3")
    assert "underside_grading" not in sc.to_toml()
    assert scenes.from_dict(tomllib.loads(sc.to_toml())).mesh.underside_grading == 1.0
    graded = scenes.load("coin_pull", setup="C3", overrides=("dea.free_edge_radius_m=0.0", "mesh.underside_grading=4.0"))
    assert tomllib.loads(graded.to_toml())["mesh"]["underside_grading"] == 4.0
    assert scenes.from_dict(tomllib.loads(graded.to_toml())).mesh.underside_grading == 4.0
    assert graded.to_toml() != sc.to_toml()


def test_the_solver_path_keys_do_not_make_another_fidelity():
    """A dataset made with another Jacobian reuse ratio, factor package, coupling or Newton tolerance is the
    scene file as written (the same solution to the Newton and coupling tolerances); a mesh key makes
    another fidelity."""
    def made(*overrides):
        return scenes.load("coin_pull", setup="C3", overrides=list(overrides)).to_toml()
    name, print0 = scenes.fidelity_of_resolved(made(), "C3")
    assert name == ""
    for path_key in ("solver.jacobian_reuse_ratio=0.9", "solver.linear_solver=superlu", "solver.coupling_tol_m=1e-8",
                     "solver.newton_atol=1e-9"):
        assert scenes.fidelity_of_resolved(made(path_key), "C3") == ("", print0)
    name, print1 = scenes.fidelity_of_resolved(made("mesh.tip_zone_divisions=8"), "C3")
    assert name is None and print1 != print0
