"""The sweep over protocols: one command makes the excitation datasets, named by setup and
protocol, under mpirun, and resumes."""
import pytest

from deapull import dataset, protocol, scene as scenes
from deapull.errors import InputError
from deapull.workflows.sweep import PROTOCOL_SETS, sweep_cases
from tests.conftest import TINY_MESH, mpirun

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


@pytest.mark.mpi
def test_excitation_sweep_under_mpi_writes_and_resumes(tmp_path):
    args = ["-m", "deapull.workflows", "sweep", "--scene", "coin_pull", "--setups", "C1", "--protocols",
            "excitation", "--out", str(tmp_path)]
    for o in (*TINY_MESH, *SHORT):
        args += ["--set", o]
    first = mpirun(2, *args)
    assert first.returncode == 0, first.stderr[-3000:]
    for name in PROTOCOL_SETS["excitation"]:
        run = dataset.read(tmp_path / f"C1_{name}.nc", variables=("t", "V"))
        sc = scenes.load("coin_pull", setup="C1", overrides=(*PROTOCOL_SETS["excitation"][name], *TINY_MESH, *SHORT))
        expected = [protocol.from_load(sc.load).voltage(t) for t in run.columns["t"]]
        assert run.columns["V"].tolist() == pytest.approx(expected, abs=1e-9), name
        assert run.attrs["load_protocol"] == sc.load.protocol
    assert dataset.read(tmp_path / "C1_release.nc", variables=("V",)).columns["V"][0] == 400.0
    again = mpirun(2, *args)
    assert again.returncode == 0 and "6 already done, 0 to run" in again.stderr, again.stderr[-2000:]
