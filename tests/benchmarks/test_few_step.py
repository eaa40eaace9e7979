"""benchmarks/few_step.py: the few-step file holds every candidate cell of the training task, the
default's exponential-grid cells and the reference policies' cells, and nothing else; the table
gives mean +- std over seeds with the latency beside it; the target check compares IS = 2 with
the candidate's own IS = 10 and with the references; a missing task is named."""

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import few_step


def _cell(
    setting, seed, k, success, eval_task="Lift", spacing="checkpoint", step=3000, study="ablation", cap=200
):
    return {"study": study, "setting": setting, "seed": seed, "step": step, "eval_task": eval_task,
            "inference_steps": k, "time_spacing": spacing, "n_episodes": 50, "eval_seed": 1000,
            "episode_length": cap, "pc_success": success}  # fmt: skip


def test_the_file_keeps_the_candidates_cells_and_the_table_their_seed_statistics(tmp_path):
    cells = [_cell("noise_concentrated", s, 2, v) for s, v in ((0, 90.0), (1, 100.0))]
    cells += [_cell("noise_concentrated", s, 10, 100.0) for s in (0, 1)]
    cells += [_cell("noise_concentrated", 0, 2, 10.0, step=1000)]  # an earlier checkpoint
    grid = [_cell("default", 0, 2, 70.0, spacing="exponential")]  # the time-grid row
    reference = [_cell("euclidean_flow", 0, 2, 80.0, study="comparison")]
    others = [
        _cell("squash_off", 0, 2, 50.0),  # not a few-step candidate
        _cell("default", 0, 2, 60.0, eval_task="Lift_scene"),  # another evaluation task
        _cell("squash_off", 0, 2, 20.0, spacing="exponential"),  # not the default on that grid
        _cell("actionflow", 0, 2, 30.0, study="comparison"),  # not a reference policy
        _cell("euclidean_flow", 1, 2, 95.0, study="comparison", cap=None),  # not the study's Lift cap
    ]
    stored = {"task": "Lift", "cells": cells + grid + reference + others}
    (tmp_path / "Lift.json").write_text(json.dumps(stored))
    latency = tmp_path / "lat.json"
    latency.write_text(
        json.dumps({"task": "Lift", "latency_batch1": {"noise_concentrated/IS2": {"median_ms": 7.25}}})
    )
    out = few_step.main(["--tasks", "Lift", "--results", str(tmp_path), "--latency", str(latency)])
    assert json.loads((tmp_path / "few_step.json").read_text()) == json.loads(json.dumps(out))
    assert out["tasks"]["Lift"]["cells"] == cells + grid + reference
    rows = {(r["setting"], r["inference_steps"]): r for r in out["tasks"]["Lift"]["summary"]}
    assert {s for s, _ in rows} == {"noise_concentrated", few_step.EXPONENTIAL_ROW, "euclidean_flow"}
    row = rows["noise_concentrated", 2]
    assert (row["last_step"], row["last"], row["last_seeds"]) == (3000, (95.0, 5.0), 2)
    assert rows[few_step.EXPONENTIAL_ROW, 2]["last"] == (70.0, 0.0)
    text = few_step.format_task("Lift", out["tasks"]["Lift"], out["latency"]["Lift"])
    assert "| noise_concentrated | 95 +- 5 (2; 3000) | 100 +- 0 (2; 3000) |" in text
    assert f"| {few_step.EXPONENTIAL_ROW} | 70 +- 0 (1; 3000) |" in text
    assert "| euclidean_flow | 80 +- 0 (1; 3000) |" in text
    assert "| noise_concentrated | 7.2 | - |" in text
    (check,) = out["tasks"]["Lift"]["targets"]  # the only row with IS = 2 and 10
    assert (check["setting"], check["gap"], check["within_gap"]) == ("noise_concentrated", 5.0, True)
    assert check["references"] == {
        "euclidean_flow": {"success": 80.0, "seeds": 1, "step": 3000, "why": None, "at_or_above": True}
    }
    assert "| noise_concentrated (2; 3000) | 95 | 100 | 5.0 | yes | yes |" in text
    assert "no verdict against them): diffusion." in text


def test_a_task_with_no_few_step_cells_is_named(tmp_path):
    stored = {"task": "Lift", "cells": [_cell("squash_off", 0, 2, 50.0)]}
    (tmp_path / "Lift.json").write_text(json.dumps(stored))
    with pytest.raises(SystemExit, match="no few-step cells of task 'Lift'"):
        few_step.main(["--tasks", "Lift", "--results", str(tmp_path)])


PROTOCOL = {"demos": 100, "batch_size": 64, "lr": 1e-3, "preset": "cpu", "cameras": None, "image_size": None,
            "episode_length": 200}  # fmt: skip


def _summary_row(setting, k, mean, step=3000, protocol=PROTOCOL):
    return {"setting": setting, "inference_steps": k, "last": (mean, 0.0), "last_step": step, "last_seeds": 3,
            "protocol": protocol}  # fmt: skip


@pytest.mark.parametrize(
    ("few", "full", "reference", "within", "above"),
    [
        (95.0, 100.0, 95.0, True, True),  # the target's edges: 5 points, equal to the reference
        (94.0, 100.0, 95.0, False, False),  # controls: one point past each edge
        (90.0, 90.0, 99.0, True, False),
    ],
)
def test_target_is_a_gap_of_5_points_or_less_and_the_reference_or_more(few, full, reference, within, above):
    summary = [_summary_row("noise_concentrated", 2, few), _summary_row("noise_concentrated", 10, full),
               _summary_row("noise_concentrated", 1, 0.0), _summary_row("diffusion", 2, reference),
               _summary_row("diffusion", 10, 100.0), _summary_row("shortcut", 2, 99.0)]  # fmt: skip
    (check,) = few_step.target_checks(summary)  # shortcut has no IS = 10 row; diffusion is a reference
    assert (check["setting"], check["gap"], check["within_gap"]) == ("noise_concentrated", full - few, within)
    assert check["references"]["diffusion"]["at_or_above"] is above
    table = few_step.format_targets([check])
    assert f">= diffusion at IS=2 ({reference:.0f}; 3 seeds; 3000)" in table
    assert f"| {'yes' if within else 'no'} | {'yes' if above else 'no'} |" in table


def test_rows_of_different_checkpoint_steps_get_no_verdict():
    summary = [_summary_row("default", 2, 90.0), _summary_row("default", 10, 99.0, step=1000),
               _summary_row("euclidean_flow", 2, 50.0, step=20000)]  # fmt: skip
    (check,) = few_step.target_checks(summary)
    assert check["within_gap"] is None and check["references"]["euclidean_flow"]["at_or_above"] is None
    assert "| 9.0 | step differs | step differs |" in few_step.format_targets([check])
    same = [dict(r, last_step=3000) for r in summary]  # control: the same rows at one step
    (check,) = few_step.target_checks(same)
    assert (check["within_gap"], check["references"]["euclidean_flow"]["at_or_above"]) == (False, True)


def test_a_reference_trained_on_another_protocol_gets_no_verdict():
    other = dict(PROTOCOL, lr=1e-4, batch_size=32)
    summary = [_summary_row("default", 2, 90.0), _summary_row("default", 10, 92.0),
               _summary_row("euclidean_flow", 2, 50.0, protocol=other)]  # fmt: skip
    (check,) = few_step.target_checks(summary)
    assert check["within_gap"] is True and check["references"]["euclidean_flow"]["at_or_above"] is None
    assert "| yes | training protocols differ in batch_size, lr |" in few_step.format_targets([check])
    same = [dict(r, protocol=PROTOCOL) for r in summary]  # control: one protocol
    (check,) = few_step.target_checks(same)
    assert check["references"]["euclidean_flow"]["at_or_above"] is True
    mixed = [*summary[:2], dict(summary[2], protocol=None)]  # its seeds were trained differently
    (check,) = few_step.target_checks(mixed)
    assert (
        check["references"]["euclidean_flow"]["why"]
        == "training protocols differ between the seeds of euclidean_flow"
    )


def test_a_task_without_results_is_named(tmp_path):
    with pytest.raises(SystemExit, match="StackThree_D0"):
        few_step.main(["--tasks", "StackThree_D0", "--results", str(tmp_path)])


def test_a_guided_setting_reads_its_runs_guided_latency():
    report = {"latency_batch1": {"noise_concentrated/IS2": {"median_ms": 13.0},
                                 "noise_concentrated+guided/IS2": {"median_ms": 20.0}}}  # fmt: skip
    assert few_step.latency_row(report, "guided", [2, 10]) == ["20.0", "-"]
    assert few_step.latency_row(report, "noise_concentrated", [2]) == ["13.0"]
    # a setting that trains its own runs and samples them guided: timed as its own guided chunks
    report["latency_batch1"]["guided_sigma_0.05+guided/IS2"] = {"median_ms": 21.0}
    assert few_step.latency_row(report, "guided_sigma_0.05", [2]) == ["21.0"]


def test_candidates_from_another_store_are_held_against_the_tasks_own_references(tmp_path):
    own = [_cell("guided", 0, 2, 40.0), _cell("guided", 0, 10, 90.0)]  # the task's own runs
    reference = [_cell("euclidean_flow", 0, 2, 50.0, study="comparison")]
    (tmp_path / "Lift.json").write_text(json.dumps({"task": "Lift", "cells": own + reference}))
    retrained = [_cell("guided", 0, 2, 88.0), _cell("guided", 0, 10, 90.0)]
    other = tmp_path / "Lift_other_machine.json"
    other.write_text(json.dumps({"task": "Lift", "cells": retrained}))
    out = few_step.main(
        ["--tasks", "Lift", "--results", str(tmp_path), "--candidates-results", f"Lift={other}"]
    )
    assert out["tasks"]["Lift"]["cells"] == retrained + reference  # not the task file's guided runs
    (check,) = out["tasks"]["Lift"]["targets"]
    assert (check["gap"], check["references"]["euclidean_flow"]["at_or_above"]) == (2.0, True)
    control = few_step.main(["--tasks", "Lift", "--results", str(tmp_path)])
    assert control["tasks"]["Lift"]["targets"][0]["gap"] == 50.0


def _lift_store(tmp_path):
    cells = [_cell("guided", 0, 2, 40.0), _cell("guided", 0, 10, 90.0)]
    (tmp_path / "Lift.json").write_text(json.dumps({"task": "Lift", "cells": cells}))
    few_step.main(["--tasks", "Lift", "--results", str(tmp_path)])  # the control: this store is valid


@pytest.mark.parametrize("item", ["Lift", "=x.json", "Lift="])
def test_a_store_item_that_is_not_task_equals_file_is_refused(tmp_path, capsys, item):
    _lift_store(tmp_path)
    with pytest.raises(SystemExit) as e:
        few_step.main(["--tasks", "Lift", "--results", str(tmp_path), "--candidates-results", item])
    assert e.value.code == 2 and "--candidates-results takes TASK=FILE" in capsys.readouterr().err


def test_a_candidates_store_that_is_missing_of_another_task_or_without_candidates_is_refused(tmp_path):
    _lift_store(tmp_path)
    other = tmp_path / "other.json"

    def run(task="Lift"):
        argv = ["--tasks", "Lift", "--results", str(tmp_path), "--candidates-results", f"{task}={other}"]
        with pytest.raises(SystemExit) as e:
            few_step.main(argv)
        return str(e.value)

    assert "no such cell store" in run() and str(other) in run()
    other.write_text(json.dumps({"task": "Square", "cells": [_cell("guided", 0, 2, 60.0)]}))
    assert "a cell store of task 'Square', not 'Lift'" in run()
    reference = _cell("euclidean_flow", 0, 2, 50.0, study="comparison")
    other.write_text(json.dumps({"task": "Lift", "cells": [reference]}))  # no candidate
    assert "has no few-step candidate cells" in run()


def test_a_candidates_store_for_a_task_not_asked_for_is_refused(tmp_path, capsys):
    _lift_store(tmp_path)
    other = tmp_path / "Square_other.json"
    other.write_text(json.dumps({"task": "Square", "cells": [_cell("guided", 0, 2, 60.0)]}))
    argv = ["--tasks", "Lift", "--results", str(tmp_path), "--candidates-results", f"Square={other}"]
    with pytest.raises(SystemExit) as e:
        few_step.main(argv)
    assert e.value.code == 2 and "names tasks not in --tasks ['Lift']: ['Square']" in capsys.readouterr().err


def test_added_stores_join_their_seeds_and_candidates_and_a_seed_in_two_stores_is_refused(tmp_path):
    own = [_cell("solver_midpoint", 2, 2, 30.0), _cell("solver_midpoint", 2, 10, 100.0)]
    (tmp_path / "Lift.json").write_text(json.dumps({"task": "Lift", "cells": own}))
    more = [_cell("solver_midpoint", s, k, v) for s, k, v in ((0, 2, 40.0), (1, 2, 50.0), (0, 10, 90.0))]
    more += [_cell("time_beta_noise", 0, 2, 70.0), _cell("squash_off", 0, 2, 10.0)]  # one not a candidate
    added = tmp_path / "Lift_epyc.json"
    added.write_text(json.dumps({"task": "Lift", "cells": more}))
    argv = ["--tasks", "Lift", "--results", str(tmp_path), "--output", str(tmp_path / "f.json")]
    out = few_step.main([*argv, "--add-candidates", f"Lift={added}"])
    assert out["tasks"]["Lift"]["cells"] == own + more[:4]
    rows = {(r["setting"], r["inference_steps"]): r for r in out["tasks"]["Lift"]["summary"]}
    midpoint = rows["solver_midpoint", 2]
    assert midpoint["last"] == pytest.approx((40.0, 8.165), abs=1e-3) and midpoint["last_seeds"] == 3
    assert rows["time_beta_noise", 2]["last"] == (70.0, 0.0)
    # the control passes; the same seed of a setting in a second store is refused, naming both
    clash = tmp_path / "Lift_clash.json"
    clash.write_text(json.dumps({"task": "Lift", "cells": [_cell("solver_midpoint", 2, 4, 90.0)]}))
    with pytest.raises(SystemExit) as e:
        few_step.main([*argv, "--add-candidates", f"Lift={added}", f"Lift={clash}"])
    assert "solver_midpoint seed 2" in str(e.value)
    assert str(clash) in str(e.value) and str(tmp_path / "Lift.json") in str(e.value)
    empty = tmp_path / "Lift_empty.json"
    empty.write_text(json.dumps({"task": "Lift", "cells": [_cell("squash_off", 0, 2, 10.0)]}))
    with pytest.raises(SystemExit, match="has no few-step candidate cells"):
        few_step.main([*argv, "--add-candidates", f"Lift={empty}"])
