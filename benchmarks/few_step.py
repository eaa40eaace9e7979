"""The few-step study of issue #21 in one file: ``benchmarks/results/few_step.json``.

Collects, from each task's study JSON (``benchmarks/results/<task>.json``, written by
``run_results.py``), the cells evaluated on the training task at the last checkpoint of:

- every few-step candidate (:data:`FEW_STEP`, ``--study ablation``) on the checkpoint's own
  time grid;
- the ``default`` runs on the exponential grid (App. E), the time-grid candidate, a row
  :data:`EXPONENTIAL_ROW` (``--settings default --time-spacings exponential``);
- the reference policies (:data:`REFERENCES`, ``--study comparison``), where they were run.

It summarises them per row and IS (mean +- std over training seeds, :func:`study.summarise`),
checks the issue's target per candidate (:func:`targets`: IS = 2 within
:data:`TARGET_GAP_POINTS` of the candidate's own IS = 10, and at or above each reference at
IS = 2), joins the chunk latency per candidate and IS (``bench_checkpoint_latency.py --json``
reports, one per task), writes the JSON and prints the Markdown tables per task::

    python benchmarks/few_step.py --tasks Lift,StackThree_D0 \\
        --latency benchmarks/results/few_step_latency_Lift.json
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from study import ABLATIONS, format_summary, study_cells, summarise

#: The candidates of issue #21 (study settings) and the baseline they are compared with.
FEW_STEP = (
    "default",
    "time_logit_normal",
    "time_beta_noise",
    "noise_concentrated",
    "noise_sigma_0.05",
    "noise_sigma_0.2",
    "shortcut",
    "solver_midpoint",
)
#: The ``default`` runs sampled on the exponential time grid, as a row of the tables.
EXPONENTIAL_ROW = "default, exponential grid"
#: Policies of ``--study comparison`` that every candidate is held against at IS = 2.
REFERENCES = ("euclidean_flow", "diffusion")
#: The issue's target: IS = 2 at most this many points below the candidate's own IS = 10.
TARGET_GAP_POINTS = 5.0
RESULTS = Path(__file__).resolve().parent / "results"


def collect(task: str, results: Path) -> dict:
    """``{"cells", "summary", "targets"}`` of the few-step candidates, the exponential-grid row
    and the references on ``task`` (its own evaluation task)."""
    data = json.loads((results / f"{task}.json").read_text())
    candidates = [c for c in study_cells(data["cells"], "ablation", task) if c["setting"] in FEW_STEP]
    on_grid = study_cells(data["cells"], "ablation", task, "exponential")
    exponential = [c for c in on_grid if c["setting"] == "default"]
    references = [c for c in study_cells(data["cells"], "comparison", task) if c["setting"] in REFERENCES]
    summary = summarise(candidates, "ablation", task)
    grid_rows = summarise(exponential, "ablation", task, "exponential")
    summary += [dict(r, setting=EXPONENTIAL_ROW) for r in grid_rows]
    summary += summarise(references, "comparison", task)
    return {"cells": candidates + exponential + references, "summary": summary, "targets": targets(summary)}


def targets(summary: list[dict]) -> list[dict]:
    """Per candidate row with IS = 2 and IS = 10 at its last checkpoint: the gap between them
    (points), whether it is within :data:`TARGET_GAP_POINTS`, and, per reference with an IS = 2
    row, whether the candidate's IS = 2 mean is at or above the reference's."""
    last = {(r["setting"], r["inference_steps"]): r["last"][0] for r in summary}
    out = []
    for setting in dict.fromkeys(r["setting"] for r in summary):
        if setting in REFERENCES or (setting, 2) not in last or (setting, 10) not in last:
            continue
        gap = last[setting, 10] - last[setting, 2]
        out.append({
            "setting": setting, "is2": last[setting, 2], "is10": last[setting, 10], "gap": gap,
            "within_gap": gap <= TARGET_GAP_POINTS,
            "at_or_above": {ref: last[setting, 2] >= last[ref, 2] for ref in REFERENCES if (ref, 2) in last},
        })  # fmt: skip
    return out


def format_targets(rows: list[dict], summary: list[dict]) -> str:
    """Markdown: the target check of :func:`targets`, one row per candidate."""
    ref_is2 = {r["setting"]: r["last"][0] for r in summary if r["inference_steps"] == 2}
    refs = [ref for ref in REFERENCES if ref in ref_is2]
    head = ["IS=2", "IS=10", "IS=10 - IS=2", f"within {TARGET_GAP_POINTS:.0f} points"]
    head += [f">= {ref} at IS=2 ({ref_is2[ref]:.0f})" for ref in refs]
    lines = ["| setting | " + " | ".join(head) + " |", "| --- |" + " ---: |" * len(head)]
    for t in rows:
        vals = [f"{t['is2']:.0f}", f"{t['is10']:.0f}", f"{t['gap']:.0f}", "yes" if t["within_gap"] else "no"]
        vals += ["yes" if t["at_or_above"][ref] else "no" for ref in refs]
        lines.append(f"| {t['setting']} | " + " | ".join(vals) + " |")
    return "\n".join(lines)


def latency_row(report: dict | None, setting: str, steps: list[int]) -> list[str]:
    """Median chunk latency (ms) of ``setting`` at each IS, '-' where not measured."""
    cells = (report or {}).get("latency_batch1", {})
    return [
        f"{cells[f'{setting}/IS{k}']['median_ms']:.1f}" if f"{setting}/IS{k}" in cells else "-" for k in steps
    ]


def format_task(task: str, entry: dict, latency: dict | None) -> str:
    """Success (last checkpoint, mean +- std (seeds; step)) per setting and IS, then the latency."""
    order = [*FEW_STEP, EXPONENTIAL_ROW, *REFERENCES]
    rows = sorted(entry["summary"], key=lambda r: (order.index(r["setting"]), r["inference_steps"]))
    steps = sorted({r["inference_steps"] for r in rows})
    lines = [f"#### {task}", "", format_summary(rows, best=False)]
    if entry["targets"]:
        checks = sorted(entry["targets"], key=lambda t: order.index(t["setting"]))
        lines += ["", format_targets(checks, rows)]
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
    args = ap.parse_args(argv)
    latency = {}
    for path in args.latency:
        report = json.loads(path.read_text())
        if report["task"] in latency:
            raise SystemExit(f"--latency: two reports for task {report['task']!r} ({path} is the second)")
        latency[report["task"]] = report
    out = {
        "settings": {s: ABLATIONS[s].why for s in FEW_STEP},
        "target_gap_points": TARGET_GAP_POINTS,
        "tasks": {},
        "latency": latency,
    }
    for task in [t for t in args.tasks.split(",") if t]:
        if not (args.results / f"{task}.json").exists():
            raise SystemExit(
                f"no study results for task {task!r}: {args.results / f'{task}.json'} is missing"
            )
        out["tasks"][task] = collect(task, args.results)
        print(format_task(task, out["tasks"][task], latency.get(task)) + "\n")
    path = args.output or args.results / "few_step.json"
    path.write_text(json.dumps(out, indent=1) + "\n")
    return out


if __name__ == "__main__":
    main()
