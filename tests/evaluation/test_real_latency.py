"""evaluation/real_latency.py: each series is read at the cell with its real latency's held steps,
never interpolated; a latency whose held steps were not swept is said to be missing; a file that
is not a latency report is refused by name; a sweep writes the join with its tables."""

import json

import pytest
from lerobot.configs.default import EvalConfig

from lerobot_actionflow.envs.configuration import ActionFlowEnvConfig
from lerobot_actionflow.evaluation import latency_sweep
from lerobot_actionflow.evaluation.latency_sweep import LatencySweepConfig, run_latency_sweep
from lerobot_actionflow.evaluation.real_latency import at_real_latency, load_real_latency

PERIOD = 0.05  # s per control step: 50 ms -> 1 held step, 150 ms -> 3


def _row(checkpoint, steps, latency_ms, success, mode="plain", policy="actionflow"):
    smoothness = dict.fromkeys(
        ("held_steps_per_chunk", "mean_max_position_jump_m", "mean_max_rotation_jump_rad", "mean_jerk_m2"),
        0.0,
    )
    return {"checkpoint": checkpoint, "policy": policy, "inference_steps": steps, "mode": mode,
            "latency_ms": latency_ms, "pc_success": success, "n_episodes": 20, **smoothness}  # fmt: skip


def _report(tmp_path, checkpoints: dict, cells: dict):
    path = tmp_path / "latency.json"
    timed = {k: {"median_ms": v, "p90_ms": v} for k, v in cells.items()}
    path.write_text(json.dumps({"checkpoints": checkpoints, "latency_batch1": timed}))
    return path


def test_a_series_is_read_at_the_cell_with_its_real_latencys_held_steps(tmp_path):
    fast, slow = str(tmp_path / "fast"), str(tmp_path / "slow")
    rows = [_row(fast, 2, 0.0, 90.0), _row(fast, 2, 50.0, 88.0), _row(fast, 2, 200.0, 40.0),
            _row(slow, 10, 0.0, 95.0), _row(slow, 10, 50.0, 94.0), _row(slow, 10, 200.0, 30.0),
            _row(slow, 10, 0.0, 0.0, mode="scheme") | {"skipped": "no scheme"}]  # fmt: skip
    real = load_real_latency(
        _report(tmp_path, {"a": fast, "b": slow}, {"a/IS2": 9.3, "b/IS10": 131.7, "b/IS2": 25})
    )
    assert real == {(fast, 2): 9.3, (slow, 10): 131.7, (slow, 2): 25.0}
    by = {(e["checkpoint"], e["mode"]): e for e in at_real_latency(rows, real, PERIOD)}
    assert set(by) == {(fast, "plain"), (slow, "plain")}  # the skipped cell is no series
    assert (by[fast, "plain"]["held_steps"], by[fast, "plain"]["success_at_real"]) == (
        1,
        88.0,
    )  # the 50 ms cell
    assert by[fast, "plain"]["cell_latency_ms"] == 50.0 and by[fast, "plain"]["success_at_0"] == 90.0
    e = by[slow, "plain"]
    assert (e["held_steps"], e["success_at_real"], e["success_at_0"]) == (3, None, 95.0)  # 150 ms not swept
    (e,) = [
        e
        for e in at_real_latency([*rows, _row(slow, 10, 150.0, 61.0)], real, PERIOD)
        if e["checkpoint"] == slow
    ]
    assert (e["success_at_real"], e["cell_latency_ms"]) == (61.0, 150.0)  # control: now it is
    own, absent = _row(slow, None, 0.0, 50.0), _row(str(tmp_path / "other"), 2, 0.0, 70.0)
    rtc = _row(fast, 2, 50.0, 80.0, mode="rtc")  # its guided chunk is not what the report times
    extra = {
        (e["checkpoint"], e["inference_steps"], e["mode"]): e
        for e in at_real_latency([own, absent, rtc], real, PERIOD)
    }
    assert set(extra) == {(slow, None, "plain"), (str(tmp_path / "other"), 2, "plain")}
    assert "give --inference_steps" in extra[slow, None, "plain"]["why"]
    assert extra[str(tmp_path / "other"), 2, "plain"]["why"] == "not in the latency report"
    text = latency_sweep.report_text(rows, at_real_latency(rows, real, PERIOD))
    assert "| 131.7 | 3 | 95 | not swept (add a latency with 3 held steps) |" in text
    assert "| 9.3 | 1 | 90 | 88 (50 ms) |" in text


def test_a_report_naming_a_last_link_that_is_not_here_says_so(tmp_path, caplog):
    """On another machine a report's ``last`` link cannot be resolved to its step: the log says
    why no swept checkpoint will match it, where the join would otherwise be silent."""
    step = tmp_path / "run" / "checkpoints" / "000010" / "pretrained_model"
    step.mkdir(parents=True)
    (tmp_path / "run" / "checkpoints" / "last").symlink_to("000010")
    gone = tmp_path / "gone" / "checkpoints" / "last" / "pretrained_model"
    here = str(tmp_path / "run" / "checkpoints" / "last" / "pretrained_model")
    real = load_real_latency(_report(tmp_path, {"a": here, "b": str(gone)}, {"a/IS2": 9.0, "b/IS2": 8.0}))
    assert real == {(str(step), 2): 9.0, (str(gone), 2): 8.0}  # the link here is read as its step
    assert "gone/checkpoints/last/pretrained_model, a `last` link that does not exist here" in caplog.text
    assert str(step) not in caplog.text  # control: the link that exists is not reported


def test_a_file_that_is_not_a_latency_report_is_refused(tmp_path):
    path = tmp_path / "other.json"
    path.write_text(json.dumps({"cells": []}))
    with pytest.raises(ValueError, match=r"other\.json is not a bench_checkpoint_latency\.py --json report"):
        load_real_latency(path)


def test_a_sweep_writes_each_series_at_its_real_latency(tmp_path):
    checkpoint = str(tmp_path / "ckpt")
    cfg = LatencySweepConfig(env=ActionFlowEnvConfig(task="Lift"), checkpoints=[checkpoint],
                             latencies_ms=[0, 50], modes=["plain"], inference_steps=[2],
                             eval=EvalConfig(n_episodes=20, batch_size=10), output_dir=tmp_path / "out",
                             real_latency=_report(tmp_path, {"a": checkpoint}, {"a/IS2": 30.0}))  # fmt: skip
    stored = [_row(checkpoint, 2, 0.0, 90.0), _row(checkpoint, 2, 50.0, 70.0)]
    settings = json.loads(json.dumps(latency_sweep._settings(cfg)))
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "latency_results.json").write_text(
        json.dumps({"settings": settings, "cells": stored})
    )
    run_latency_sweep(cfg)  # every cell is stored: nothing runs, the outputs are rewritten
    saved = json.loads((tmp_path / "out" / "latency_results.json").read_text())
    (entry,) = saved["at_real_latency"]
    assert (entry["real_ms"], entry["held_steps"], entry["success_at_real"]) == (30.0, 1, 70.0)
    assert "| 30.0 | 1 | 90 | 70 (50 ms) |" in (tmp_path / "out" / "latency_results.md").read_text()
