"""Voltage protocols: each validated like every scene key, each V(t) against its definition."""
import math

import numpy as np
import pytest

from deapull import protocol, scene as scenes
from deapull.scene import SceneError


def load(*sets):
    return scenes.load("coin_pull", overrides=sets)


def V(sc, t):
    return protocol.from_load(sc.load).voltage(t)


def test_ramp_is_the_shipped_formula_bit_for_bit():
    sc = load("load.ramp_time_s=0.7", "load.end_time_s=1.0")
    for t in np.linspace(0, 1, 97):
        assert V(sc, t) == sc.load.voltage_max_V * min(t / 0.7, 1.0)


def test_ramp_hold_ramp_release_triangle_sine_by_hand():
    rhr = load("load.protocol='ramp_hold_ramp'", "load.ramp_time_s=0.4", "load.hold_time_s=0.2",
               "load.voltage_end_V=100", "load.ramp_down_time_s=0.3", "load.end_time_s=1.2")
    assert [V(rhr, t) for t in (0.0, 0.2, 0.4, 0.5, 0.6, 0.75, 0.9, 1.2)] == pytest.approx(
        [0, 200, 400, 400, 400, 250, 100, 100])
    rel = load("load.protocol='release'", "load.ramp_time_s=0.5")
    assert [V(rel, t) for t in (0.0, 0.25, 0.5, 1.0)] == pytest.approx([400, 200, 0, 0])
    tri = load("load.protocol='triangle'", "load.ramp_time_s=0.5", "load.end_time_s=2.0")
    assert [V(tri, t) for t in (0.0, 0.25, 0.5, 0.75, 1.0, 1.5, 1.9)] == pytest.approx([0, 200, 400, 200, 0, 400, 80])
    assert list(protocol.from_load(tri.load).kinks()) == [0.5, 1.0, 1.5]
    sine = load("load.protocol='sine'", "load.period_s=0.8")
    assert [V(sine, t) for t in (0.0, 0.2, 0.4, 0.8)] == pytest.approx([0, 200, 400, 0], abs=1e-9)


def test_table_inline_and_from_csv(tmp_path):
    sc = load("load.protocol='table'", "load.table_t_s=[0, 0.5, 1.0]", "load.table_V=[0, 300, 100]")
    assert [V(sc, t) for t in (0.25, 0.5, 0.75, 2.0)] == pytest.approx([150, 300, 200, 100])
    csv = tmp_path / "v.csv"
    csv.write_text("t_s,V\n0,0\n0.5,300\n1.0,100\n")
    text = scenes.resolve_path("coin_pull").read_text().replace('protocol = "ramp"', 'protocol = "table"')
    text = text.replace("ramp_time_s = 1.0\n", 'table_csv = "v.csv"\n')
    (tmp_path / "scene.toml").write_text(text)
    from_file = scenes.load(tmp_path / "scene.toml")            # relative to the scene file
    assert from_file.load.table_t_s == (0.0, 0.5, 1.0) and from_file.load.table_V == (0.0, 300.0, 100.0)
    again = scenes.from_dict(__import__("tomllib").loads(from_file.to_toml()))   # the points travel with it
    assert again.load == from_file.load


def test_random_is_seeded_bounded_and_rate_limited():
    sets = ("load.protocol='random'", "load.rate_max_V_s=2000", "load.end_time_s=2.0")
    a, b, c = load(*sets, "load.seed=3"), load(*sets, "load.seed=3"), load(*sets, "load.seed=4")
    pa, pb, pc = (protocol.from_load(s.load) for s in (a, b, c))
    assert pa.knots_t == pb.knots_t and pa.knots_V == pb.knots_V
    assert pa.knots_V != pc.knots_V
    t, v = pa.sample(1e-3)
    assert v.min() >= 0 and v.max() <= 400 and v.max() > 100            # it moves, within the bounds
    assert np.max(np.abs(np.diff(v) / np.diff(t))) <= 2000 * (1 + 1e-9)
    assert pa.knots_t[-1] >= 2.0 and np.all(np.diff(pa.knots_t) > 0)


@pytest.mark.parametrize("sets, words", [
    (("load.period_s=0.5",), "load.period_s: not a key of load.protocol = 'ramp'"),
    (("load.protocol='sine'", "load.ramp_time_s=0.5"), "load.ramp_time_s: not a key of load.protocol = 'sine'"),
    (("load.protocol='pulse'",), "load.protocol = 'pulse': expected one of 'ramp'"),
    (("load.protocol='random'", "load.rate_max_V_s=50"), "load.rate_max_V_s = 50"),
    (("load.protocol='random'", "load.segment_min_s=0.5", "load.segment_max_s=0.1"), "load.segment_min_s = 0.5"),
    (("load.protocol='ramp_hold_ramp'", "load.voltage_end_V=500"), "load.voltage_end_V = 500.0: must be <="),
    (("load.protocol='table'", "load.table_t_s=[0, 1]", "load.table_V=[0, 500]"), "load.table_V[1] = 500.0"),
    (("load.protocol='table'", "load.table_t_s=[0, 1, 1]", "load.table_V=[0, 1, 2]"), "increase strictly"),
    (("load.protocol='table'", "load.table_t_s=[0.1, 1]", "load.table_V=[0, 1]"), "must start at 0"),
    (("load.protocol='table'", "load.table_t_s=[0, nan]", "load.table_V=[0, 1]"), "load.table_t_s = "),
    (("load.protocol='table'", "load.table_t_s=[0, 1]"), "load.table_t_s / load.table_V"),
    (("load.protocol='table'",), "load.table_t_s: missing"),
    (("load.protocol='table'", "load.table_csv='nowhere.csv'"), "load.table_csv = 'nowhere.csv': no such file"),
    (("load.protocol='table'", "load.table_csv='x.csv'", "load.table_V=[0]"), "either load.table_csv"),
    (("load.voltage_max_V=nan",), "load.voltage_max_V = nan"),
])
def test_bad_protocol_input_names_the_key(sets, words):
    with pytest.raises(SceneError) as err:
        load(*sets)
    assert words in str(err.value)


def test_every_protocol_round_trips_and_keeps_only_its_keys():
    cases = {"ramp": (), "release": (), "triangle": (), "sine": ("load.period_s=0.5",),
             "ramp_hold_ramp": ("load.hold_time_s=0.1",), "random": ("load.seed=7",),
             "table": ("load.table_t_s=[0, 1]", "load.table_V=[0, 1]")}
    assert set(cases) == set(protocol.NAMES)
    for name, extra in cases.items():
        sc = load(f"load.protocol='{name}'", *extra)
        toml = sc.to_toml()
        again = scenes.from_dict(__import__("tomllib").loads(toml))
        assert again.load == sc.load, name
        written = set(sc.to_dict()["load"])
        assert written <= set(sc.load.keys()) and "protocol" in written, (name, written)
        assert math.isfinite(protocol.from_load(sc.load).max_rate())
