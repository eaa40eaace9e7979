"""benchmarks/few_step.py: the few-step file holds every candidate cell of the training task and
nothing else, the table gives mean +- std over seeds with the latency beside it, and a missing
task is named."""

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import few_step


def _cell(setting, seed, k, success, eval_task="Lift", spacing="checkpoint", step=3000):
    return {"study": "ablation", "setting": setting, "seed": seed, "step": step, "eval_task": eval_task,
            "inference_steps": k, "time_spacing": spacing, "n_episodes": 50, "eval_seed": 1000,
            "pc_success": success}  # fmt: skip


def test_the_file_keeps_the_candidates_cells_and_the_table_their_seed_statistics(tmp_path):
    cells = [_cell("noise_concentrated", s, 2, v) for s, v in ((0, 90.0), (1, 100.0))]
    cells += [_cell("noise_concentrated", 0, 2, 10.0, step=1000)]  # an earlier checkpoint
    others = [
        _cell("squash_off", 0, 2, 50.0),  # not a few-step candidate
        _cell("default", 0, 2, 60.0, eval_task="Lift_scene"),  # another evaluation task
        _cell("default", 0, 2, 70.0, spacing="exponential"),  # another time grid
    ]
    (tmp_path / "Lift.json").write_text(json.dumps({"task": "Lift", "cells": cells + others}))
    latency = tmp_path / "lat.json"
    latency.write_text(
        json.dumps({"task": "Lift", "latency_batch1": {"noise_concentrated/IS2": {"median_ms": 7.25}}})
    )
    out = few_step.main(["--tasks", "Lift", "--results", str(tmp_path), "--latency", str(latency)])
    assert json.loads((tmp_path / "few_step.json").read_text()) == json.loads(json.dumps(out))
    assert out["tasks"]["Lift"]["cells"] == cells
    (row,) = out["tasks"]["Lift"]["summary"]
    assert (row["setting"], row["last_step"], row["last"], row["last_seeds"]) == (
        "noise_concentrated", 3000, (95.0, 5.0), 2
    )  # fmt: skip
    text = few_step.format_task("Lift", out["tasks"]["Lift"], out["latency"]["Lift"])
    assert "| noise_concentrated | 95 +- 5 (2; 3000) |" in text
    assert "| noise_concentrated | 7.2 |" in text


def test_a_task_without_results_is_named(tmp_path):
    with pytest.raises(SystemExit, match="StackThree_D0"):
        few_step.main(["--tasks", "StackThree_D0", "--results", str(tmp_path)])
