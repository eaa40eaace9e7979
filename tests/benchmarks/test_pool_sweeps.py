"""Pooling sweeps run on disjoint episode seeds into one table (benchmarks/pool_sweeps.py)."""

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
from pool_sweeps import main, pool


def _row(ckpt, policy, k, n, pc):
    return {"checkpoint": ckpt, "policy": policy, "inference_steps": k, "n_episodes": n, "pc_success": pc}


def test_pool_weights_cells_by_episodes():
    first = [_row("a", "actionflow", 2, 20, 70.0), _row("b", "diffusion", 2, 20, 5.0)]
    more = [_row("a", "actionflow", 2, 30, 90.0), _row("b", "diffusion", 2, 30, 0.0)]
    cells = {r["checkpoint"]: r for r in pool([first, more])}
    assert cells["a"]["n_episodes"] == 50 and cells["a"]["successes"] == 14 + 27
    assert cells["a"]["pc_success"] == pytest.approx(82.0)
    assert cells["b"]["pc_success"] == pytest.approx(2.0)


def test_pool_keeps_inference_steps_apart_and_refuses_a_policy_mismatch():
    rows = pool([[_row("a", "actionflow", 2, 10, 50.0), _row("a", "actionflow", 10, 10, 100.0)]])
    assert sorted(r["pc_success"] for r in rows) == [50.0, 100.0]
    with pytest.raises(ValueError, match="policy"):
        pool([[_row("a", "actionflow", 2, 10, 50.0)], [_row("a", "diffusion", 2, 10, 50.0)]])


def test_cli_reads_both_layouts_and_names_a_malformed_file(tmp_path, capsys):
    sweep = tmp_path / "sweep_results.json"
    sweep.write_text(json.dumps([_row("a", "actionflow", 2, 20, 50.0)]))
    results = tmp_path / "results.json"
    results.write_text(json.dumps({"is_sweep": [_row("a", "actionflow", 2, 30, 100.0)]}))
    out = tmp_path / "pooled.json"
    assert main([str(out), str(sweep), str(results)]) == 0
    assert json.loads(out.read_text())[0]["pc_success"] == pytest.approx(80.0)
    assert "| actionflow | 80 |" in capsys.readouterr().out
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps([{"policy": "actionflow"}]))
    with pytest.raises(ValueError, match=r"bad\.json: row 0 lacks"):
        main([str(out), str(bad)])
