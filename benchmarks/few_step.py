"""The few-step study of issue #21 in one file: ``benchmarks/results/few_step.json``.

Collects, from each task's study JSON (``benchmarks/results/<task>.json``, written by
``run_results.py --study ablation``), every cell of the few-step candidates (:data:`FEW_STEP`)
evaluated on the training task with the checkpoint's own time grid, summarises them per setting
and IS (mean +- std over training seeds at the last checkpoint, :func:`study.summarise`), joins
the chunk latency per candidate and IS (``bench_checkpoint_latency.py --json`` reports, one per
task), writes the JSON and prints one Markdown table per task::

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
FEW_STEP = ("default", "time_logit_normal", "noise_concentrated", "shortcut", "solver_midpoint")
RESULTS = Path(__file__).resolve().parent / "results"


def collect(task: str, results: Path) -> dict:
    """``{"cells", "summary"}`` of the few-step candidates on ``task`` (its own evaluation task)."""
    data = json.loads((results / f"{task}.json").read_text())
    cells = [c for c in study_cells(data["cells"], "ablation", task) if c["setting"] in FEW_STEP]
    return {"cells": cells, "summary": summarise(cells, "ablation", task)}


def latency_row(report: dict | None, setting: str, steps: list[int]) -> list[str]:
    """Median chunk latency (ms) of ``setting`` at each IS, '-' where not measured."""
    cells = (report or {}).get("latency_batch1", {})
    return [
        f"{cells[f'{setting}/IS{k}']['median_ms']:.1f}" if f"{setting}/IS{k}" in cells else "-" for k in steps
    ]


def format_task(task: str, entry: dict, latency: dict | None) -> str:
    """Success (last checkpoint, mean +- std (seeds; step)) per setting and IS, then the latency."""
    rows = sorted(entry["summary"], key=lambda r: (FEW_STEP.index(r["setting"]), r["inference_steps"]))
    steps = sorted({r["inference_steps"] for r in rows})
    lines = [f"#### {task}", "", format_summary(rows, best=False)]
    if latency:
        lines += [
            "",
            "| chunk latency, median ms (batch 1) | " + " | ".join(f"IS={k}" for k in steps) + " |",
            "| --- |" + " ---: |" * len(steps),
        ]
        for setting in dict.fromkeys(r["setting"] for r in rows):
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
