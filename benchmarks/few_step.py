"""The few-step study of issue #21 in one file: ``benchmarks/results/few_step.json``.

Collects, from each task's study JSON (``benchmarks/results/<task>.json``, written by
``run_results.py``), the cells evaluated on the training task with the study's episode cap
(:data:`study.STUDY_CAPS`), at every evaluated checkpoint, of:

- every few-step candidate (:data:`FEW_STEP`, ``--study ablation``) on the checkpoint's own
  time grid;
- the ``default`` runs on the exponential grid (App. E), the time-grid candidate, a row
  :data:`EXPONENTIAL_ROW` (``--settings default --time-spacings exponential``);
- the reference policies (:data:`REFERENCES`, ``--study comparison``), where they were run.

``--candidates-results TASK=FILE`` reads a task's candidates from another store instead, and
``--add-candidates TASK=FILE`` adds a store's candidate cells (more seeds, or candidates trained on
another machine) to them; each (setting, seed) must come from one store.

It summarises them per row and IS at the last checkpoint (mean +- std over training seeds,
:func:`study.summarise`), checks the issue's target per candidate (:func:`target_checks`),
joins the chunk latency per candidate and IS (``bench_checkpoint_latency.py --json`` reports,
one per task), writes the JSON and prints the Markdown tables per task::

    python benchmarks/few_step.py --tasks Lift,StackThree_D0 \\
        --latency benchmarks/results/few_step_latency_Lift.json
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from study import (
    ABLATIONS,
    COMPARISON,
    GUIDED,
    STUDY_CAPS,
    format_summary,
    load_cells,
    protocol_mismatch,
    study_cells,
    summarise,
    task_files,
    with_cap,
)

#: The candidates of issue #21 (study settings) and the baseline they are compared with.
FEW_STEP = (
    "default",
    "time_logit_normal",
    "time_beta_noise",
    "noise_concentrated",
    "guided",
    "noise_sigma_0.05",
    "noise_sigma_0.2",
    "shortcut",
    "shortcut_concentrated",
    "shortcut_guided",
    "guided_sigma_0.05",
    "guided_sigma_0.07",
    "shortcut_guided_sigma_0.05",
    "guided_kappa_0.25",
    "solver_midpoint",
)
#: The ``default`` runs sampled on the exponential time grid, as a row of the tables.
EXPONENTIAL_ROW = "default, exponential grid"
#: Policies of ``--study comparison`` that every candidate is held against.
REFERENCES = tuple(name for name in COMPARISON if name != "actionflow")
#: The issue's target: at ``FEW_IS`` inference steps, at most ``TARGET_GAP_POINTS`` below the
#: candidate's own success at ``FULL_IS``, and at or above every reference at ``FEW_IS``.
FEW_IS, FULL_IS, TARGET_GAP_POINTS = 2, 10, 5.0
RESULTS = Path(__file__).resolve().parent / "results"


def _candidate_cells(cells: list[dict], task: str) -> tuple[list[dict], list[dict]]:
    """The few-step candidates' cells and the ``default`` runs' exponential-grid cells of a store."""
    candidates = [c for c in study_cells(cells, "ablation", task) if c["setting"] in FEW_STEP]
    on_grid = study_cells(cells, "ablation", task, "exponential")
    return candidates, [c for c in on_grid if c["setting"] == "default"]


def collect(
    task: str, results: Path, candidates_file: Path | None = None, added: tuple[Path, ...] = ()
) -> dict:
    """``{"cells", "summary", "targets"}`` of the few-step candidates, the exponential-grid row
    and the references on ``task`` (its own evaluation task). The references come from the task's
    file in ``results``; the candidates and the grid row too, or from ``candidates_file``, plus
    those of each store in ``added`` (more seeds or candidates, e.g. trained on another machine).

    Raises:
        SystemExit: a store without candidate cells; or a run (setting, seed, time grid) found in
            two stores, which would mix two trainings under one seed; both name the store.
    """
    path = results / f"{task}.json"
    cap = STUDY_CAPS.get(task)
    stored = with_cap(load_cells(path, task, required=True), cap)
    if candidates_file is not None:
        path = candidates_file
        own = with_cap(load_cells(path, task, required=True), cap)
    else:
        own = stored
    candidates, exponential = _candidate_cells(own, task)
    if candidates_file is not None and not candidates + exponential:
        raise SystemExit(
            f"--candidates-results {task}={candidates_file} has no few-step candidate cells: none of "
            f"the settings {list(FEW_STEP)} evaluated on {task} with the study's episode cap {cap}"
        )

    def run_of(c: dict) -> tuple:
        return c["setting"], c["seed"], c["time_spacing"]

    source = {run_of(c): path for c in candidates + exponential}
    for extra in added:
        more, more_grid = _candidate_cells(with_cap(load_cells(extra, task, required=True), cap), task)
        if not more + more_grid:
            raise SystemExit(
                f"--add-candidates {task}={extra} has no few-step candidate cells: none of the "
                f"settings {list(FEW_STEP)} evaluated on {task} with the study's episode cap {cap}"
            )
        for run in sorted({run_of(c) for c in more + more_grid}, key=str):
            if run in source:
                setting, seed, spacing = run
                raise SystemExit(
                    f"--add-candidates {task}={extra}: {setting} seed {seed} ({spacing} grid) is "
                    f"also in {source[run]}; a seed's cells must come from one training"
                )
            source[run] = extra
        candidates, exponential = candidates + more, exponential + more_grid
    references = [c for c in study_cells(stored, "comparison", task) if c["setting"] in REFERENCES]
    if not candidates + exponential + references:
        raise SystemExit(
            f"{path} has no few-step cells of task {task!r}: none of the settings {list(FEW_STEP)} "
            f"evaluated on the task itself with the study's episode cap {STUDY_CAPS.get(task)} "
            "(settings with cameras are not collected)"
        )
    summary = summarise(candidates, "ablation", task)
    grid_rows = summarise(exponential, "ablation", task, "exponential")
    summary += [dict(r, setting=EXPONENTIAL_ROW) for r in grid_rows]
    summary += summarise(references, "comparison", task)
    return {
        "cells": candidates + exponential + references,
        "summary": summary,
        "targets": target_checks(summary),
    }


def target_checks(summary: list[dict]) -> list[dict]:
    """Per candidate row with ``FEW_IS`` and ``FULL_IS`` summaries: their last-checkpoint means,
    ``gap = full - few`` (points) and ``within_gap`` (gap <= :data:`TARGET_GAP_POINTS`), and per
    reference with a ``FEW_IS`` summary, its mean, step and ``at_or_above`` (the candidate's
    ``FEW_IS`` mean >= the reference's). A verdict is None where the rows are not comparable, and
    ``why`` says how: their last checkpoint steps differ, or their training protocols
    (:data:`study.PROTOCOL`)."""
    rows = {(r["setting"], r["inference_steps"]): r for r in summary}
    refs = {ref: rows[ref, FEW_IS] for ref in REFERENCES if (ref, FEW_IS) in rows}

    def mismatch(a: dict, b: dict) -> str | None:
        if a["last_step"] != b["last_step"]:
            return "step differs"
        return protocol_mismatch(a["protocol"], b["protocol"], (a["setting"], b["setting"]))

    checks = []
    for setting in dict.fromkeys(r["setting"] for r in summary):
        few, full = rows.get((setting, FEW_IS)), rows.get((setting, FULL_IS))
        if setting in REFERENCES or few is None or full is None:
            continue
        gap, gap_why = full["last"][0] - few["last"][0], mismatch(few, full)
        references = {}
        for ref, r in refs.items():
            why = mismatch(few, r)
            references[ref] = {
                "success": r["last"][0], "seeds": r["last_seeds"], "step": r["last_step"], "why": why,
                "at_or_above": None if why else few["last"][0] >= r["last"][0],
            }  # fmt: skip
        checks.append({
            "setting": setting, "step": few["last_step"], "seeds": few["last_seeds"],
            "few": few["last"][0], "full": full["last"][0], "gap": gap, "gap_why": gap_why,
            "within_gap": None if gap_why else gap <= TARGET_GAP_POINTS,
            "references": references,
        })  # fmt: skip
    return checks


def format_targets(checks: list[dict]) -> str:
    """Markdown: :func:`target_checks`, one row per candidate, and which references were not run."""
    refs = {ref: c["references"][ref] for c in checks for ref in c["references"]}

    def verdict(value: bool | None, why: str | None) -> str:
        return why if value is None else "yes" if value else "no"

    head = [f"IS={FEW_IS}", f"IS={FULL_IS}", "gap", f"within {TARGET_GAP_POINTS:g} points"]
    head += [
        f">= {ref} at IS={FEW_IS} ({r['success']:.0f}; {r['seeds']} seeds; {r['step']})"
        for ref, r in refs.items()
    ]
    lines = ["| setting (seeds; step) | " + " | ".join(head) + " |", "| --- |" + " ---: |" * len(head)]
    for c in checks:
        vals = [
            f"{c['few']:.0f}",
            f"{c['full']:.0f}",
            f"{c['gap']:.1f}",
            verdict(c["within_gap"], c["gap_why"]),
        ]
        vals += [verdict(c["references"][ref]["at_or_above"], c["references"][ref]["why"]) for ref in refs]
        lines.append(f"| {c['setting']} ({c['seeds']}; {c['step']}) | " + " | ".join(vals) + " |")
    missing = [ref for ref in REFERENCES if ref not in refs]
    if missing:
        lines += [
            "",
            f"Not run at IS={FEW_IS} (no verdict against them): {', '.join(missing)}.",
        ]
    return "\n".join(lines)


def latency_name(setting: str) -> str:
    """The name of ``setting``'s cells in a latency report: a setting that guides each chunk
    toward the previous one is timed as its runs' guided chunks (``bench_checkpoint_latency.py
    --guided <runs>``: ``<runs>+guided``, the runs being ``trained_as`` or the setting's own)."""
    spec = ABLATIONS.get(setting)
    if spec is not None and set(GUIDED) <= set(spec.sampling):
        return f"{spec.trained_as or setting}+guided"
    return setting


def latency_row(report: dict | None, setting: str, steps: list[int]) -> list[str]:
    """Median chunk latency (ms) of ``setting`` at each IS, '-' where not measured."""
    cells = (report or {}).get("latency_batch1", {})
    name = latency_name(setting)
    return [f"{cells[f'{name}/IS{k}']['median_ms']:.1f}" if f"{name}/IS{k}" in cells else "-" for k in steps]


def format_task(task: str, entry: dict, latency: dict | None) -> str:
    """Success (last checkpoint, mean +- std (seeds; step)) per setting and IS, then the latency."""
    order = [*FEW_STEP, EXPONENTIAL_ROW, *REFERENCES]
    rows = sorted(entry["summary"], key=lambda r: (order.index(r["setting"]), r["inference_steps"]))
    steps = sorted({r["inference_steps"] for r in rows})
    lines = [f"#### {task}", "", format_summary(rows, best=False)]
    if entry["targets"]:
        checks = sorted(entry["targets"], key=lambda t: order.index(t["setting"]))
        lines += ["", format_targets(checks)]
    if latency:
        lines += [
            "",
            "| chunk latency, median ms (batch 1) | " + " | ".join(f"IS={k}" for k in steps) + " |",
            "| --- |" + " ---: |" * len(steps),
        ]
        for setting in dict.fromkeys(r["setting"] for r in rows if r["setting"] != EXPONENTIAL_ROW):
            lines.append(f"| {setting} | " + " | ".join(latency_row(latency, setting, steps)) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tasks", default="Lift,StackThree_D0")
    ap.add_argument("--results", type=Path, default=RESULTS, help="folder of the <task>.json study files")
    ap.add_argument("--latency", type=Path, nargs="*", default=[], help="bench_checkpoint_latency.py reports")
    ap.add_argument("--output", type=Path, default=None, help="default: <results>/few_step.json")
    ap.add_argument(
        "--candidates-results",
        nargs="+",
        default=[],
        metavar="TASK=FILE",
        help="read TASK's candidate cells from FILE (e.g. runs trained again on another machine); "
        "the references' cells still come from the task's own file",
    )
    ap.add_argument(
        "--add-candidates",
        nargs="+",
        default=[],
        metavar="TASK=FILE",
        help="add the candidate cells of FILE to TASK's (more seeds or candidates from another "
        "store); a task may be named more than once, a (setting, seed) only in one store",
    )
    args = ap.parse_args(argv)
    try:
        candidate_files = task_files(args.candidates_results, "--candidates-results")
        added: dict[str, list[Path]] = {}
        for item in args.add_candidates:
            # task_files refuses a task given twice; here each item is its own one-task mapping
            ((task, file),) = task_files([item], "--add-candidates").items()
            added.setdefault(task, []).append(file)
    except ValueError as e:
        ap.error(str(e))
    tasks = [t for t in args.tasks.split(",") if t]
    for flag, named in (("--candidates-results", candidate_files), ("--add-candidates", added)):
        if unused := sorted(set(named) - set(tasks)):
            ap.error(f"{flag} names tasks not in --tasks {tasks}: {unused}")
    latency = {}
    for path in args.latency:
        report = json.loads(path.read_text())
        if report["task"] in latency:
            raise SystemExit(f"--latency: two reports for task {report['task']!r} ({path} is the second)")
        latency[report["task"]] = report
    out = {
        "settings": {s: ABLATIONS[s].why for s in FEW_STEP},
        "target": {"few_is": FEW_IS, "full_is": FULL_IS, "gap_points": TARGET_GAP_POINTS},
        "tasks": {},
        "latency": latency,
    }
    for task in tasks:
        if not (args.results / f"{task}.json").exists():
            raise SystemExit(
                f"no study results for task {task!r}: {args.results / f'{task}.json'} is missing"
            )
        more = tuple(added.get(task, ()))
        out["tasks"][task] = collect(task, args.results, candidate_files.get(task), more)
        print(format_task(task, out["tasks"][task], latency.get(task)) + "\n")
    path = args.output or args.results / "few_step.json"
    path.write_text(json.dumps(out, indent=1) + "\n")
    return out


if __name__ == "__main__":
    main()
