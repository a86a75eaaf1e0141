"""The sweep over protocols: one command makes the excitation datasets, named by setup and
protocol, under mpirun, and resumes."""
import pytest

from deapull import dataset, protocol, scene as scenes
from deapull.errors import InputError
from deapull.workflows.sweep import PROTOCOL_SETS, format_table, sweep_cases
from tests.conftest import SHARP, TINY_MESH, mpirun

pytestmark = pytest.mark.fem

SHORT = ("load.end_time_s=0.02", "time.dt_max_s=0.01", "time.dt_initial_s=0.01")


def test_excitation_cases_name_setup_and_protocol():
    cases = sweep_cases("coin_pull", ["C1", "C5"], (), "excitation")
    names = [c.name for c in cases]
    assert names == [f"{s}_{p}" for s in ("C1", "C5") for p in PROTOCOL_SETS["excitation"]]
    kinds = {c.name.split("_", 1)[1]: scenes.load("coin_pull", setup=c.setup, overrides=c.overrides).load.protocol
             for c in cases[:6]}
    assert kinds == {"rhr": "ramp_hold_ramp", "triangle": "triangle", "release": "release",
                     "random1": "random", "random2": "random", "random3": "random"}
    with pytest.raises(InputError, match="--protocols 'chirp'"):
        sweep_cases("coin_pull", ["C1"], (), "chirp")


def test_the_push_case_is_the_mpcs_full_push_then_held():
    (case,) = sweep_cases("coin_pull", ["C3"], (), "push", fidelity=scenes.fidelity_overrides("coin_pull", "preview"))
    sc = scenes.load("coin_pull", setup=case.setup, overrides=case.overrides)
    volts = protocol.from_load(sc.load)
    assert case.name == "C3_fast" and sc.time.dt_max_s == 0.001, "1 ms steps, the control plants' step"
    assert [volts.voltage(t) for t in (0.001, 0.04, 0.08, 0.28)] == pytest.approx([5.0, 200.0, 400.0, 400.0])
    assert sc.load.end_time_s == 0.28 and sc.contact.quadrature_degree == 8, "held 200 ms, at the fidelity asked"
    assert sc.table.penalty_N_m3 == 2e12, "the push presses the table harder: <= 1 um needs it twice as stiff"
    (mine,) = sweep_cases("coin_pull", ["C3"], ("mesh.rim_band_divisions=6",), "push")
    assert scenes.load("coin_pull", setup="C3", overrides=mine.overrides).mesh.rim_band_divisions == 6


def test_the_release_case_meshes_the_rim_where_the_placed_dea_crosses_it():
    """Placed at 400 V the free edge crosses the rim nearer the middle: the release case carries its
    own band; the ramps' band follows the coin (its width from the file): the edge at rest 2 mm from
    the coin's axis crosses the rim's middle circle (4.5 mm) at |z| = 4.03 mm, so the 2 mm band starts
    at 3.03 mm."""
    from deapull.meshing.build import rim_band
    cases = sweep_cases("coin_pull", ["C1"], (), "excitation")
    bands = {c.name: rim_band(scenes.load("coin_pull", setup=c.setup, overrides=c.overrides)) for c in cases}
    assert bands.pop("C1_release") == (0.0015, 0.004)
    assert len(set(bands.values())) == 1 and 0.0030 < min(bands.values())[0] < 0.00305


def test_the_closing_table_names_the_cases_whose_contact_was_thin():
    rows = [{"case": "C1_rhr", "status": "ok", "steps": 725, "travel_mm": 1.18, "max_Fy_mN": 41.4, "below_min": 0,
             "wall_s": 553.8},
            {"case": "C1_release", "status": "ok", "steps": 732, "travel_mm": 1.34, "max_Fy_mN": 33.3, "below_min": 732,
             "wall_s": 2377.9}]
    table = format_table(rows)
    assert "WARNING: 1 case(s)" in table and "(C1_release)" in table
    assert "WARNING" not in format_table(rows[:1])


@pytest.mark.mpi
def test_excitation_sweep_under_mpi_writes_and_resumes(tmp_path):
    args = ["-m", "deapull.workflows", "sweep", "--scene", "coin_pull", "--setups", "C1", "--protocols",
            "excitation", "--out", str(tmp_path)]
    for o in (*SHARP, *TINY_MESH, *SHORT):      # the sweep's machinery on the fast mesh
        args += ["--set", o]
    first = mpirun(2, *args)
    assert first.returncode == 0, first.stderr[-3000:]
    for name in PROTOCOL_SETS["excitation"]:
        run = dataset.read(tmp_path / f"C1_{name}.nc", variables=("t", "V"))
        sc = scenes.load("coin_pull", setup="C1", overrides=(*PROTOCOL_SETS["excitation"][name], *SHARP, *TINY_MESH,
                                                              *SHORT))
        expected = [protocol.from_load(sc.load).voltage(t) for t in run.columns["t"]]
        assert run.columns["V"].tolist() == pytest.approx(expected, abs=1e-9), name
        assert run.attrs["load_protocol"] == sc.load.protocol
    assert dataset.read(tmp_path / "C1_release.nc", variables=("V",)).columns["V"][0] == 400.0
    again = mpirun(2, *args)
    assert again.returncode == 0 and "6 already done, 0 to run" in again.stderr, again.stderr[-2000:]
