"""benchmarks/fig12_mug_hang.py: finished stages are not run again, the table has one row per
policy and one column per hanger placement, and the point-cloud policies get their options."""

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import fig12_mug_hang as fig12


def _finished_run(out: Path) -> None:
    (out / "data" / "meta").mkdir(parents=True)
    (out / "data" / "meta" / "info.json").write_text("{}")
    cells = {}
    for i, name in enumerate(("actionflow_pose", "actionflow_pc", "euclidean_flow_pc")):
        fig12.final_checkpoint(out / "train" / name, 20000).mkdir(parents=True)  # the default --steps
        cells[name] = {
            v: {"pc_success": 10.0 * i + j, "n_episodes": 50} for j, v in enumerate(fig12.VARIANTS)
        }
    (out / "fig12_results.json").write_text(json.dumps({"timings": {"collect_s": 1.0}, "cells": cells}))


def test_a_finished_run_only_writes_the_table(tmp_path, monkeypatch):
    _finished_run(tmp_path)

    def no_subprocess(*a, **k):
        raise AssertionError(f"a finished stage ran again: {a}")

    monkeypatch.setattr(fig12, "run_logged", no_subprocess)
    monkeypatch.setattr(fig12, "train_run", no_subprocess)
    assert fig12.main(["--output", str(tmp_path)]) == 0
    table = (tmp_path / "fig12_table.md").read_text()
    assert "| policy | MugHang_D0 | MugHang_Moved |" in table
    assert "| euclidean_flow_pc | 20 (50) | 21 (50) |" in table
    assert json.loads((tmp_path / "fig12_results.json").read_text())["timings"]["collect_s"] == 1.0


def test_point_cloud_policies_read_the_cloud_and_not_the_object_poses(tmp_path):
    specs = fig12.policies(fig12.argparse.Namespace(tiny_models=True, groups=8, group_size=4))
    assert not specs["actionflow_pose"]["point_cloud"]
    assert not any("point_cloud" in a for a in specs["actionflow_pose"]["args"])
    for name in ("actionflow_pc", "euclidean_flow_pc"):
        assert specs[name]["point_cloud"]
        assert "--policy.point_cloud_key=observation.point_cloud" in specs[name]["args"]
    assert "--policy.pose_entities=[0]" in specs["actionflow_pc"]["args"]
    assert "--policy.use_environment_state=false" in specs["euclidean_flow_pc"]["args"]
    with pytest.raises(SystemExit, match="unknown policies"):
        _finished_run(tmp_path)
        fig12.main(["--output", str(tmp_path), "--policies", "diffusion"])


def test_runs_of_different_policies_on_one_output_keep_each_others_cells(tmp_path):
    path = tmp_path / "fig12_results.json"
    first = {
        "args": {},
        "timings": {"collect_s": 1.0},
        "cells": {"actionflow_pose": {"MugHang_D0": {"pc_success": 90}}},
    }
    # A second run started before the first saved: its view holds none of the first's cells.
    second = {
        "args": {},
        "timings": {"train_actionflow_pc_s": 2.0},
        "cells": {"actionflow_pc": {"MugHang_D0": {"pc_success": 70}}},
    }
    fig12.merge_save(path, first)
    merged = fig12.merge_save(path, second)
    assert merged["cells"] == {
        "actionflow_pose": {"MugHang_D0": {"pc_success": 90}},
        "actionflow_pc": {"MugHang_D0": {"pc_success": 70}},
    }
    assert merged["timings"] == {"collect_s": 1.0, "train_actionflow_pc_s": 2.0}
    assert json.loads(path.read_text()) == merged
    assert not list(tmp_path.glob(".fig12_results.json.*")), "the temporary file was left behind"


def test_point_token_ablations_change_only_their_own_knob():
    specs = fig12.policies(fig12.argparse.Namespace(tiny_models=True, groups=32, group_size=16))
    base = specs["actionflow_pc"]["args"]
    for name, changed in {
        "actionflow_pc_g16": "--policy.point_cloud_groups=16",
        "actionflow_pc_g64": "--policy.point_cloud_groups=64",
        "actionflow_pc_k1": "--policy.point_cloud_group_size=1",
        "actionflow_pc_k32": "--policy.point_cloud_group_size=32",
        "actionflow_pc_m128": "--policy.point_cloud_prefix=128",
    }.items():
        args = specs[name]["args"]
        assert changed in args and changed not in base
        knobs = {a.split("=")[0] for a in set(args) ^ set(base)}
        assert knobs == {changed.split("=")[0]}, f"{name} differs from actionflow_pc in {knobs}"


def test_variants_limits_the_evaluations_and_refuses_unknown_tasks(tmp_path, monkeypatch):
    _finished_run(tmp_path)
    fig12.final_checkpoint(tmp_path / "train" / "actionflow_pc_k1", 20000).mkdir(parents=True)
    evaluated = []

    def fake_eval(cmd, env, log, append=False):
        task = next(a.split("=", 1)[1] for a in cmd if a.startswith("--env.task="))
        out = Path(next(a.split("=", 1)[1] for a in cmd if a.startswith("--output_dir=")))
        out.mkdir(parents=True)
        (out / "sweep_results.json").write_text(json.dumps([{"pc_success": 40.0, "n_episodes": 50}]))
        evaluated.append(task)
        return 1.0

    monkeypatch.setattr(fig12, "run_logged", fake_eval)
    args = ["--output", str(tmp_path), "--policies", "actionflow_pc_k1"]
    assert fig12.main([*args, "--variants", "MugHang_D0"]) == 0
    assert evaluated == ["MugHang_D0"]
    assert "| actionflow_pc_k1 | 40 (50) | - |" in (tmp_path / "fig12_table.md").read_text()
    with pytest.raises(SystemExit, match=r"unknown tasks \['MugHang_Far'\]"):
        fig12.main([*args, "--variants", "MugHang_D0,MugHang_Far"])
    with pytest.raises(SystemExit, match="needs --points > 128, got 128"):
        fig12.main(["--output", str(tmp_path), "--policies", "actionflow_pc_m128", "--points", "128"])
