"""The learning study's cell store and summaries (benchmarks/study.py)."""

import sys
import time
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
from study import (
    ABLATIONS,
    BASELINES,
    COMMON,
    COMPARISON,
    COMPARISON_ACTIONFLOW_IN_ABLATION,
    CPU_SIZE,
    ResultStore,
    cell_key,
    format_curves,
    mean_std,
    plateau_step,
    summarise,
)


def _cell(setting, seed, step, k, pc, study="ablation", task="Lift", spacing="checkpoint", cap=None):
    return {
        "study": study, "setting": setting, "seed": seed, "step": step, "eval_task": task,
        "inference_steps": k, "time_spacing": spacing, "n_episodes": 50, "eval_seed": 1000,
        "episode_length": cap, "pc_success": pc,
    }  # fmt: skip


def test_two_stores_of_one_task_merge_their_cells(tmp_path):
    """Two studies writing the same file side by side keep each other's cells."""
    path = tmp_path / "Lift.json"
    a, b = ResultStore(path, "Lift"), ResultStore(path, "Lift")
    a.add(_cell("default", 0, 1000, 2, 80.0))
    b.add(_cell("squash_off", 0, 1000, 2, 60.0))
    a.add(_cell("default", 1, 1000, 2, 90.0))
    again = ResultStore(path, "Lift")
    assert len(again.cells) == 3
    assert cell_key(_cell("squash_off", 0, 1000, 2, 0.0)) in again
    assert not list(tmp_path.glob(".Lift.json.*")), "a temporary file was left behind"


def test_a_cell_with_the_same_key_is_replaced(tmp_path):
    store = ResultStore(tmp_path / "Lift.json", "Lift")
    store.add(_cell("default", 0, 1000, 2, 10.0))
    store.add(_cell("default", 0, 1000, 2, 30.0))
    assert [c["pc_success"] for c in ResultStore(tmp_path / "Lift.json", "Lift").cells.values()] == [30.0]


def test_a_store_of_another_task_is_refused(tmp_path):
    ResultStore(tmp_path / "r.json", "Lift").add(_cell("default", 0, 1000, 2, 10.0))
    with pytest.raises(ValueError, match="'Lift', not 'Square'"):
        ResultStore(tmp_path / "r.json", "Square")


def test_summary_gives_last_and_best_step_over_seeds():
    cells = [
        _cell("default", 0, 1000, 2, 60.0), _cell("default", 1, 1000, 2, 80.0),
        _cell("default", 0, 2000, 2, 90.0), _cell("default", 1, 2000, 2, 100.0),
        _cell("default", 0, 3000, 2, 70.0), _cell("default", 1, 3000, 2, 90.0),
        _cell("default", 0, 3000, 2, 0.0, task="Lift_D1"),  # another task: not pooled
        _cell("default", 0, 3000, 2, 0.0, spacing="exponential"),  # another grid: not pooled
    ]  # fmt: skip
    (row,) = summarise(cells, "ablation", "Lift")
    assert row["last_step"] == 3000 and row["last"] == pytest.approx((80.0, 10.0))
    assert row["best_step"] == 2000 and row["best"] == pytest.approx((95.0, 5.0))
    assert row["last_seeds"] == row["best_seeds"] == 2


def test_an_episode_cap_is_part_of_a_cells_identity_and_caps_are_not_averaged(tmp_path):
    """A rerun with another episode cap evaluates again instead of reusing the stored cell, and a
    summary refuses to pool the two caps (a cap changes the success rate)."""
    store = ResultStore(tmp_path / "Lift.json", "Lift")
    store.add(_cell("default", 0, 1000, 2, 50.0, cap=200))
    assert cell_key(_cell("default", 0, 1000, 2, 0.0, cap=400)) not in store
    store.add(_cell("default", 0, 1000, 2, 90.0, cap=400))
    cells = list(ResultStore(tmp_path / "Lift.json", "Lift").cells.values())
    assert len(cells) == 2
    with pytest.raises(
        ValueError, match=r"the ablation cells on Lift have different episode caps \[200, 400\]"
    ):
        summarise(cells, "ablation", "Lift")
    (row,) = summarise(cells[:1], "ablation", "Lift")  # one cap: summarised
    assert row["last"] == (50.0, 0.0)


def test_mean_std_is_the_population_spread():
    assert mean_std([50.0]) == (50.0, 0.0)
    assert mean_std([40.0, 60.0, 80.0]) == pytest.approx((60.0, (800 / 3) ** 0.5))


def test_ablation_settings_parse_as_actionflow_configs():
    """Every override names a real ActionFlow config field with a valid value, parsed as
    ``lerobot-train`` parses it (draccus) after the CPU size preset and the study's baseline,
    and a setting's overrides change the config that those alone give (``default`` has none)."""
    import draccus

    from lerobot_actionflow.policies.actionflow.configuration_actionflow import ActionflowConfig

    def parse(flags):
        flags = (*COMMON, *CPU_SIZE["actionflow"], *BASELINES["ablation"]["actionflow"], *flags)
        args = ["--device=cpu", *(f.replace("--policy.", "--", 1) for f in flags)]
        return draccus.parse(ActionflowConfig, args=args)  # raises on an unknown field or a refused value

    base = parse([])
    for name, setting in ABLATIONS.items():
        assert setting.policy == "actionflow", name
        config = parse(setting.overrides)
        assert (config != base) == bool(setting.overrides), name


def test_plot_study_writes_a_png(tmp_path):
    from study import plot_study

    cells = [_cell(s, seed, step, k, 50.0 + seed) for s in ("default", "squash_off") for seed in (0, 1)
             for step in (1000, 2000) for k in (2, 10)]  # fmt: skip
    plot_study(cells, "ablation", "Lift", tmp_path / "p.png", "t")
    assert (tmp_path / "p.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def _fake_checkpoint(run, weights: bytes):
    """The pretrained_model folder of step 10 of ``run`` (kept if it exists, like a trained run)."""
    ckpt = run / "checkpoints" / "000010" / "pretrained_model"
    if not ckpt.exists():
        ckpt.mkdir(parents=True)
        (ckpt / "model.safetensors").write_bytes(weights)
    return ckpt


def _fake_sweep(checkpoints, task, steps, extra, out, *a, **k):
    return [
        {"inference_steps": s, "sampler": "x", "n_episodes": 2, "pc_success": 50.0, "eval_s": 1.0}
        for s in steps
    ]


def _study_args(tmp_path, results) -> list[str]:
    """run_results.py's arguments for a one-seed, one-checkpoint ablation into ``tmp_path``, whose
    demonstrations are marked as recorded (no collection)."""
    (tmp_path / "data" / "meta").mkdir(parents=True)
    (tmp_path / "data" / "meta" / "info.json").write_text("{}")
    return ["--output", str(tmp_path), "--results", str(results), "--study", "ablation", "--seeds", "0",
            "--steps", "10", "--eval-every", "10", "--eval-episodes", "2"]  # fmt: skip


def test_cells_are_not_added_beside_cells_of_other_weights_of_the_same_run(tmp_path, monkeypatch):
    """A run trained again into its folder (a fresh machine) gets new cells only if its weights are
    the ones its stored cells measured."""
    import run_results

    from lerobot_actionflow.evaluation.provenance import DIGEST_KEY, weights_digest

    monkeypatch.setattr(run_results, "_train", lambda run, *a, **k: _fake_checkpoint(run, b"first"))
    monkeypatch.setattr(run_results, "_sweep", _fake_sweep)
    results = tmp_path / "cells.json"
    common = [*_study_args(tmp_path, results), "--settings", "default"]
    assert run_results.main([*common, "--inference-steps", "2"]) == 0
    ckpt = tmp_path / "ablation" / "default" / "seed0" / "checkpoints" / "000010" / "pretrained_model"
    (cell,) = ResultStore(results, "Lift").cells.values()
    assert cell[DIGEST_KEY] == weights_digest(ckpt)
    assert run_results.main([*common, "--inference-steps", "2,4"]) == 0  # control: the same weights
    (ckpt / "model.safetensors").write_bytes(b"trained again")
    with pytest.raises(ValueError, match="trained again"):
        run_results.main([*common, "--inference-steps", "2,4,10"])
    assert sorted(c["inference_steps"] for c in ResultStore(results, "Lift").cells.values()) == [2, 4]


def test_a_sampling_only_setting_evaluates_the_runs_it_names_without_training(tmp_path, monkeypatch):
    import run_results

    trained, swept = [], []

    def fake_train(run, policy, overrides, seed, *a, **k):
        trained.append((run, tuple(overrides)))  # the real _train skips a run already trained
        _fake_checkpoint(run, b"weights")

    def fake_sweep(checkpoints, task, steps, extra, out, *a, **k):
        swept.append((checkpoints[0], tuple(extra), out))
        return _fake_sweep(checkpoints, task, steps, extra, out)

    monkeypatch.setattr(run_results, "_train", fake_train)
    monkeypatch.setattr(run_results, "_sweep", fake_sweep)
    results = tmp_path / "cells.json"
    common = [*_study_args(tmp_path, results), "--inference-steps", "2,4"]
    assert run_results.main([*common, "--settings", "default,solver_midpoint,squash_off"]) == 0

    runs = [(run.relative_to(tmp_path).as_posix(), overrides) for run, overrides in trained]
    uniform = "--policy.noise_rotation=uniform"  # the ablations' baseline, whatever the package default
    squash_off = (uniform, "--policy.squash_translations=false")
    assert runs == [
        ("ablation/default/seed0", (uniform,)),
        ("ablation/default/seed0", (uniform,)),
        ("ablation/squash_off/seed0", squash_off),
    ]
    (default_eval, midpoint_eval, _) = swept
    assert default_eval[0] == midpoint_eval[0], "solver_midpoint must evaluate default's checkpoint"
    assert "--solver=midpoint" in midpoint_eval[1] and "--solver=midpoint" not in default_eval[1]
    assert default_eval[2] != midpoint_eval[2], "the two evaluations must not share a folder"
    store = ResultStore(results, "Lift")
    midpoint = [c for c in store.cells.values() if c["setting"] == "solver_midpoint"]
    assert len(midpoint) == 2 and all(c["trained_as"] == "default" and c["overrides"] == [] for c in midpoint)
    # another episode cap is another evaluation, in its own folder (the first one's is kept)
    assert run_results.main([*common, "--settings", "default", "--episode-length", "7"]) == 0
    assert swept[-1][0] == default_eval[0] and swept[-1][2] != default_eval[2]
    capped = [c for c in ResultStore(results, "Lift").cells.values() if c["episode_length"] == 7]
    assert len(capped) == 2


def test_scene_transformed_layouts_are_cells_of_their_own(tmp_path, monkeypatch):
    """``--scenes robot`` evaluates the task's env with the scene and the robot moved, into cells
    of evaluation task ``<task>+scene_robot`` beside the task's own."""
    import run_results

    swept = []

    def fake_sweep(checkpoints, task, steps, extra, out, *a, **k):
        swept.append((task, tuple(extra)))
        return _fake_sweep(checkpoints, task, steps, extra, out)

    monkeypatch.setattr(run_results, "_train", lambda run, *a, **k: _fake_checkpoint(run, b"w"))
    monkeypatch.setattr(run_results, "_sweep", fake_sweep)
    results = tmp_path / "cells.json"
    common = [*_study_args(tmp_path, results), "--settings", "default", "--inference-steps", "2"]
    assert run_results.main([*common, "--scenes", "robot"]) == 0
    (plain, moved) = swept
    assert plain[0] == moved[0] == "Lift"
    assert "--env.scene_move_robot=true" in moved[1] and not any("scene" in e for e in plain[1])
    tasks = sorted(c["eval_task"] for c in ResultStore(results, "Lift").cells.values())
    assert tasks == ["Lift", "Lift+scene_robot"]
    with pytest.raises(SystemExit, match="unknown --scenes"):
        run_results.main([*common, "--scenes", "robots"])


@pytest.mark.parametrize(
    ("means", "plateau"),
    [
        ([83.0, 81.0, 86.0], 1000),  # flat within 5 points from the first checkpoint
        ([20.0, 70.0, 74.0, 72.0], 2000),  # rose, then flat
        ([70.0, 72.0, 74.0, 76.0, 78.0, 80.0], 4000),  # a slow rise: flat only over its last 4 points
        ([20.0, 40.0, 60.0], None),  # control: still rising at the end
        ([90.0, 50.0, 90.0], None),  # control: moved by 40 points at the end
        ([60.0, 66.0], None),  # control: 6 points is past the tolerance
        ([90.0], None),  # one checkpoint shows nothing
    ],
)
def test_plateau_is_the_first_step_of_a_flat_tail(means, plateau):
    curve = [(1000 * (i + 1), m, 0.0, 3) for i, m in enumerate(means)]
    assert plateau_step(curve) == plateau


def test_curves_table_lists_multi_checkpoint_settings_with_their_plateau():
    cells = [_cell("default", seed, step, 2, m + seed) for seed in (0, 2)
             for step, m in ((1000, 40.0), (2000, 80.0), (3000, 82.0))]  # fmt: skip
    cells += [_cell("default", 1, 3000, 2, 0.0)]  # a seed with the last step only: not in the curve
    cells += [_cell("squash_off", 0, step, 2, m) for step, m in ((1000, 20.0), (2000, 60.0))]  # rising
    cells += [_cell("velocity_eef", 0, 3000, 2, 50.0)]  # one checkpoint: no curve
    assert format_curves(cells, "ablation", "Lift").splitlines()[2:] == [
        "| default | 2 | 2 | 41 (1000), 81 (2000), 83 (3000) | from 2000 |",
        "| squash_off | 2 | 1 | 20 (1000), 60 (2000) | not reached |",
    ]


def test_the_comparisons_actionflow_is_the_ablation_setting_reports_read_in_its_place():
    """``COMPARISON_ACTIONFLOW_IN_ABLATION`` trains the comparison's ActionFlow configuration:
    both parse to one config (each study's baseline and overrides on the shared protocol), and
    the ablation's own baseline does not (control)."""
    import draccus

    from lerobot_actionflow.policies.actionflow.configuration_actionflow import ActionflowConfig

    def parse(study, overrides):
        flags = (*COMMON, *CPU_SIZE["actionflow"], *BASELINES[study].get("actionflow", ()), *overrides)
        return draccus.parse(ActionflowConfig, args=[f.replace("--policy.", "--", 1) for f in flags])

    comparison = parse("comparison", COMPARISON["actionflow"].overrides)
    assert parse("ablation", ABLATIONS[COMPARISON_ACTIONFLOW_IN_ABLATION].overrides) == comparison
    assert parse("ablation", ABLATIONS["default"].overrides) != comparison


def test_record_once_lets_one_of_two_side_by_side_studies_record(tmp_path):
    """Two studies of one task on one output: the second waits for the first's collection and
    then finds the dataset, so it is recorded once; a finished dataset is never recorded again."""
    import threading

    import run_results

    data = tmp_path / "data"
    calls, started = [], threading.Event()

    def slow_record():
        calls.append(threading.current_thread().name)
        started.set()
        time.sleep(0.3)  # the second thread reaches the lock while this one records
        (data / "meta").mkdir(parents=True)
        (data / "meta" / "info.json").write_text("{}")

    first = threading.Thread(target=run_results.record_once, args=(data, slow_record), name="first")
    first.start()
    assert started.wait(5)
    outcome = {}

    def second_study():
        outcome["recorded"] = run_results.record_once(data, slow_record)

    second = threading.Thread(target=second_study, name="second")
    second.start()
    first.join(5)
    second.join(5)
    assert calls == ["first"] and outcome == {"recorded": False}
    # Control: without the dataset, the call does record.
    assert run_results.record_once(tmp_path / "other", lambda: calls.append("other")) is True
    assert calls[-1] == "other"


def test_task_files_map_each_task_to_its_store_and_name_the_flag_on_bad_items():
    from study import task_files

    assert task_files(["Square=results/Square_36k.json", "Lift=b.json"], "--x") == {
        "Square": Path("results/Square_36k.json"),
        "Lift": Path("b.json"),
    }
    with pytest.raises(ValueError, match="--x takes TASK=FILE; got 'Square'"):
        task_files(["Square"], "--x")
    with pytest.raises(ValueError, match="--x: task 'Lift' is given twice"):
        task_files(["Lift=a.json", "Lift=b.json"], "--x")
