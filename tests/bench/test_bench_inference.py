"""``make bench-inference``: both engines watch the same record and land on the same estimate,
and the compiled engine is the one the bench names so (no timing is checked: tests never time).

Broken once (then restored): the bench's second run given ``engine="torch"`` too; the test
failed ("assert ['torch', 'torch'] == ['torch', 'native']").
"""
from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from deapull.control import native

BENCH = Path(__file__).resolve().parents[2] / "bench" / "bench_inference.py"
pytestmark = pytest.mark.skipif(native.memory_library() is None, reason="no C compiler for the native inference")


def test_the_bench_runs_both_engines_on_one_record(committed, monkeypatch):
    spec = importlib.util.spec_from_file_location("bench_inference", BENCH)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    engines = []
    real = bench.OnlineInference

    def spy(model, config, dt):
        inf = real(model, config, dt)
        engines.append((config.engine, inf.native))
        return inf
    monkeypatch.setattr(bench, "OnlineInference", spy)
    r = bench.bench(committed("f-memory"), rows=120, updates=2, noise=1e-4, seed=0)
    assert [e for e, _ in engines] == ["torch", "native"]
    assert engines[0][1] is None and engines[1][1] is native.memory_predict
    assert r["rows"] == 120 and all(r[k] > 0 for k in ("torch_update_ms", "native_update_ms"))
    assert r["max_rel_diff"] < 1e-9, r
