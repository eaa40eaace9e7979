"""The hypotheses of issue #17, checked against the stored study cells.

Reads each task's ``benchmarks/results/<task>.json`` (written by ``run_results.py --study``) and
prints one Markdown table per hypothesis, with a verdict per task (``yes``, ``no``, or why there
is none) and the figures behind it::

    python benchmarks/hypotheses.py --tasks Lift,Square,StackThree_D0,Threading_D0,Coffee_D0

- **H1, H2**: ActionFlow >= ``diffusion`` (H1) and >= ``euclidean_flow`` (H2) at IS =
  :data:`FEW_IS`, on the task itself: mean success over training seeds at each policy's last
  checkpoint. No verdict where the two differ in their training protocol (:data:`study.PROTOCOL`:
  demonstrations, batch, learning rate, size preset, cameras, episode cap); their training steps
  and wall-clock may differ (an equal budget is either), and both are printed.
- **H3**: ActionFlow keeps >= :data:`KEPT_FRACTION` of its D0 success on the D1 and D2
  variants: the D0 runs' checkpoints evaluated on ``<name>_D1`` and ``<name>_D2`` (the variant's
  last evaluated step), per IS, over the seeds evaluated on both at that step. Beside it, why:
  the same setting trained on the variant's own demonstrations (``<variant>.json``, written by
  ``run_results.py --task <variant>``), and the D0 runs on scene-transformed D0 layouts
  (``run_results.py --scenes robot,objects``): a rigid motion of the whole scene, which an
  equivariant policy should not notice, and the objects moved together relative to the robot.
- **H4**: ActionFlow reaches >= :data:`TARGET_SUCCESS` % within :data:`BUDGET_S` of training on
  :data:`H4_TASKS`: among the checkpoints whose training time (the run's ``train_wall_s`` times
  ``step / train_steps``: one CPU core per run here) is within the budget, the best mean over
  seeds at any evaluated IS. "No" needs the first checkpoint past the budget below the target
  too; runs that stop before the budget get no verdict.

Only the cells of the study's episode cap of each task are read (:data:`study.STUDY_CAPS`).
ActionFlow's cells are those of ``--study comparison --settings actionflow``; a task without
them uses the ablation's runs of the same configuration
(:data:`study.COMPARISON_ACTIONFLOW_IN_ABLATION`), and the tables say which. ``--actionflow
ablation/guided`` reads another setting's cells instead: those runs evaluated with each chunk
guided toward the previous one, the package's default sampling (the study pins it off
elsewhere, and in the references' cells). ``--actionflow-results TASK=FILE`` reads a task's
ActionFlow cells from another cell store (runs trained longer, or again on another machine),
the references' from the task's own.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from few_step import FEW_IS, RESULTS
from study import (
    COMPARISON_ACTIONFLOW_IN_ABLATION,
    STUDY_CAPS,
    load_cells,
    mean_std,
    protocol_mismatch,
    protocol_of,
    scene_task,
    study_cells,
    task_files,
    with_cap,
)

TASKS = ("Lift", "Square", "StackThree_D0", "Threading_D0", "Coffee_D0")
#: The comparison's setting ActionFlow is held against, per hypothesis.
REFERENCES = {"h1": "diffusion", "h2": "euclidean_flow"}
H4_TASKS = ("StackThree_D0", "Threading_D0", "Square")
KEPT_FRACTION = 0.9
TARGET_SUCCESS, BUDGET_S = 80.0, 3600.0


def actionflow_cells(cells: list[dict], eval_task: str, source: str | None = None) -> tuple[list[dict], str]:
    """ActionFlow's cells on ``eval_task`` (checkpoint grid) and where they come from
    (``study/setting``): ``source`` if given, else the comparison's runs, else the ablation's."""
    if source is None:
        own = actionflow_cells(cells, eval_task, "comparison/actionflow")
        return (
            own
            if own[0]
            else actionflow_cells(cells, eval_task, f"ablation/{COMPARISON_ACTIONFLOW_IN_ABLATION}")
        )
    study, setting = source.split("/")
    return [c for c in study_cells(cells, study, eval_task) if c["setting"] == setting], source


def _per_seed(group: list[dict]) -> list[dict]:
    """``group`` (one step and IS), refused if a seed has two cells (e.g. two episode counts)."""
    seeds = [c["seed"] for c in group]
    if len(seeds) != len(set(seeds)):
        c = group[0]
        raise ValueError(
            f"{c['study']}/{c['setting']} on {c['eval_task']} at step {c['step']}, "
            f"IS={c['inference_steps']}: a seed has several cells (seeds {sorted(seeds)}; "
            "different n_episodes or eval_seed?)"
        )
    return group


def last_checkpoint(cells: list[dict], inference_steps: int) -> dict | None:
    """Mean +- std over seeds at the last evaluated step at ``inference_steps``, with that step,
    the seeds, the mean training wall-clock (s) and the protocol (None if the seeds' differ);
    None without such cells."""
    chosen = [c for c in cells if c["inference_steps"] == inference_steps]
    if not chosen:
        return None
    step = max(c["step"] for c in chosen)
    at = _per_seed([c for c in chosen if c["step"] == step])
    walls = [c["train_wall_s"] * step / c["train_steps"] for c in at if c.get("train_wall_s")]
    return {
        "step": step,
        "success": mean_std([c["pc_success"] for c in at]),
        "seeds": sorted(c["seed"] for c in at),
        "train_wall_s": statistics.fmean(walls) if walls else None,
        "protocol": protocol_of(at),
    }


def check_reference(cells: list[dict], task: str, reference: str, source: str | None = None) -> dict:
    """H1 / H2 on one task: ActionFlow's IS = ``FEW_IS`` mean (its cells from ``source``, see
    :func:`actionflow_cells`) against ``reference``'s."""
    af_cells, source = actionflow_cells(cells, task, source)
    ref_cells = [c for c in study_cells(cells, "comparison", task) if c["setting"] == reference]
    af, ref = last_checkpoint(af_cells, FEW_IS), last_checkpoint(ref_cells, FEW_IS)
    out = {"task": task, "source": source, "actionflow": af, "reference": ref, "holds": None}
    if af is None or ref is None:
        missing = [name for name, row in (("actionflow", af), (reference, ref)) if row is None]
        out["why"] = f"not run at IS={FEW_IS}: {', '.join(missing)}"
    elif mismatch := protocol_mismatch(af["protocol"], ref["protocol"], ("actionflow", reference)):
        out["why"] = mismatch
    else:
        out["holds"] = af["success"][0] >= ref["success"][0]
    return out


def _kept_row(d0_cells: list[dict], moved_cells: list[dict], k: int, step: int) -> dict:
    """Success on moved layouts as a fraction of D0 success (``kept``), both the mean over the
    seeds evaluated on both at IS ``k`` and ``step``; ``why`` where there is no fraction."""
    at = (k, step)
    d0 = {c["seed"]: c["pc_success"] for c in d0_cells if (c["inference_steps"], c["step"]) == at}
    on = {c["seed"]: c["pc_success"] for c in moved_cells if (c["inference_steps"], c["step"]) == at}
    seeds = sorted(set(d0) & set(on))
    row = {"inference_steps": k, "step": step, "seeds": seeds, "kept": None}
    if not seeds:
        row["why"] = f"D0 not evaluated with these seeds at step {step}"
        return row
    base, moved = statistics.fmean(d0[s] for s in seeds), statistics.fmean(on[s] for s in seeds)
    row.update(d0=base, success=moved)
    if base > 0:
        row["kept"] = moved / base
    else:
        row["why"] = "D0 is 0 %"
    return row


def trained_on_variant(cells: list[dict], variant: str, k: int, source: str | None, d0_protocol) -> dict:
    """ActionFlow's runs trained on ``variant``'s own demonstrations (``cells``: the variant's
    cell store), evaluated there at IS ``k``: :func:`last_checkpoint`, or ``why`` not."""
    own = last_checkpoint(actionflow_cells(cells, variant, source)[0], k)
    if own is None:
        return {"why": f"not trained on {variant}" if not cells else f"not evaluated at IS={k}"}
    if mismatch := protocol_mismatch(d0_protocol, own["protocol"], ("the D0 runs", f"the {variant} runs")):
        return {"why": mismatch}
    return own


def check_variants(
    cells: list[dict],
    task: str,
    source: str | None = None,
    variant_stores: dict[str, list[dict]] | None = None,
) -> list[dict]:
    """H3 on a ``<name>_D0`` task: per variant and IS, ActionFlow's D1/D2 success as a fraction
    of its D0 success, at the variant's last evaluated checkpoint, over the seeds evaluated on
    both. The variant's cells come from the same runs (study and setting) as the D0 cells.
    ``variant_stores`` (variant -> its own cell store) adds each row's ``trained_on_variant``:
    the same setting trained on the variant's demonstrations and evaluated there, which tells a
    harder task from one whose layouts the D0 demonstrations do not cover."""
    if not task.endswith("_D0"):
        return []
    rows = []
    d0_cells, source = actionflow_cells(cells, task, source)
    for variant in (task[:-1] + "1", task[:-1] + "2"):
        var_cells, _ = actionflow_cells(cells, variant, source)
        for k in sorted({c["inference_steps"] for c in var_cells}):
            step = last_checkpoint(var_cells, k)["step"]
            row = {"task": task, "variant": variant, "source": source, "holds": None}
            row |= _kept_row(d0_cells, var_cells, k, step)
            if row["kept"] is not None:
                row["holds"] = row["kept"] >= KEPT_FRACTION
            own_store = (variant_stores or {}).get(variant, [])
            row["trained_on_variant"] = trained_on_variant(
                own_store, variant, k, source, protocol_of(d0_cells)
            )
            rows.append(row)
    return rows


def check_scenes(cells: list[dict], task: str, source: str | None = None) -> list[dict]:
    """H3's control: per scene transform and IS, ActionFlow's success on ``task``'s layouts moved
    by the transform (cells of :func:`study.scene_task`, the same runs as the D0 cells) as a
    fraction of its D0 success over common seeds. With the robot moved too, the initial state is
    a rigid motion of a D0 state, so an equivariant policy keeps its success up to the arm's
    reach and joint limits; with the objects only, the objects keep their relative poses but meet
    the robot at poses the D0 demonstrations do not show."""
    rows = []
    d0_cells, source = actionflow_cells(cells, task, source)
    prefix = scene_task(task, "")
    for eval_task in sorted({c["eval_task"] for c in cells if c["eval_task"].startswith(prefix)}):
        moved, _ = actionflow_cells(cells, eval_task, source)
        for k in sorted({c["inference_steps"] for c in moved}):
            row = {"task": task, "scene": eval_task.removeprefix(prefix), "source": source}
            rows.append(row | _kept_row(d0_cells, moved, k, last_checkpoint(moved, k)["step"]))
    return rows


def check_budget(cells: list[dict], task: str, source: str | None = None) -> dict:
    """H4 on one task: the best mean over seeds, at any evaluated IS, among the checkpoints
    trained within ``BUDGET_S``. Below the target, "no" needs the first checkpoint past the
    budget to be below it too (else success could cross it in between, unmeasured)."""
    af_cells, source = actionflow_cells(cells, task, source)
    out = {"task": task, "source": source, "best": None, "holds": None}
    groups: dict[tuple[int, int], list[dict]] = {}
    for c in af_cells:
        if c.get("train_wall_s"):
            groups.setdefault((c["step"], c["inference_steps"]), []).append(c)
    if not groups:
        out["why"] = "no training time stored" if af_cells else "no cells"
        return out
    points = []  # (wall s, mean success, step, IS, seeds, std)
    for (step, k), group in groups.items():
        group = _per_seed(group)
        wall = statistics.fmean(c["train_wall_s"] * step / c["train_steps"] for c in group)
        mean, std = mean_std([c["pc_success"] for c in group])
        points.append((wall, mean, step, k, sorted(c["seed"] for c in group), std))
    within = [p for p in points if p[0] <= BUDGET_S]
    past = [p for p in points if p[0] > BUDGET_S]
    if within:
        wall, mean, step, k, seeds, std = max(within, key=lambda p: (p[1], -p[0]))
        out["best"] = {"step": step, "inference_steps": k, "train_wall_s": wall, "success": (mean, std),
                       "seeds": seeds}  # fmt: skip
    if out["best"] is not None and out["best"]["success"][0] >= TARGET_SUCCESS:
        out["holds"] = True
        return out
    if past:
        first = min(p[0] for p in past)
        reached = max(p[1] for p in past if p[0] == first)
        if reached < TARGET_SUCCESS:
            out["holds"] = False
        else:
            out["why"] = f"{reached:.0f} % at {first / 60:.0f} min, past the budget; not evaluated in between"
    elif within:
        trained = max(p[0] for p in within)
        out["why"] = f"not reached in the {trained / 60:.0f} min trained (budget not covered)"
    return out


def _verdict(check: dict) -> str:
    return check.get("why", "no cells") if check["holds"] is None else "yes" if check["holds"] else "no"


def _fmt(row: dict | None) -> str:
    if row is None:
        return "-"
    (m, s), wall = row["success"], row["train_wall_s"]
    minutes = f", {wall / 60:.0f} min" if wall else ""
    return f"{m:.0f} +- {s:.0f} (n={len(row['seeds'])}, step {row['step']}{minutes})"


def _kept_columns(row: dict) -> tuple[str, str, str]:
    """D0 %, moved %, kept fraction of a :func:`_kept_row`, '-' where missing."""
    d0, on = (f"{row[k]:.0f}" if k in row else "-" for k in ("d0", "success"))
    return d0, on, "-" if row["kept"] is None else f"{row['kept']:.0%}"


def _row(*values) -> str:
    return "| " + " | ".join(str(v) for v in values) + " |"


def format_report(report: dict) -> str:
    caps = ", ".join(f"{task} {cap} control steps" for task, cap in STUDY_CAPS.items() if cap)
    lines = [f"Cells of the study's episode caps only ({caps}; other tasks: their own).", ""]
    for key, reference in REFERENCES.items():
        lines += [
            f"{key.upper()}: ActionFlow >= {reference} at IS={FEW_IS} on every task "
            "(last checkpoint, mean +- std over seeds)",
            "",
            _row("task", "ActionFlow", reference, "holds", "ActionFlow's runs"),
            _row("---", "---", "---", "---", "---"),
        ]
        lines += [
            _row(c["task"], _fmt(c["actionflow"]), _fmt(c["reference"]), _verdict(c), c["source"])
            for c in report[key]
        ]
        tested = [c for c in report[key] if c["holds"] is not None]
        held = [c["task"] for c in tested if c["holds"]]
        untested = [c["task"] for c in report[key] if c["holds"] is None]
        summary = f"Holds on {len(held)} of {len(tested)} tasks with a verdict" if tested else "No verdict"
        lines += ["", summary + (f"; none on {', '.join(untested)}." if untested else "."), ""]
    lines += [f"H3: ActionFlow keeps >= {KEPT_FRACTION:.0%} of its D0 success on D1 and D2 (last checkpoint)"]
    lines.append("")
    if report["h3"]:
        lines += [
            _row(
                "task",
                "variant",
                "IS",
                "seeds",
                "D0 %",
                "variant %",
                "kept",
                "holds",
                "trained on the variant",
            ),
            _row("---", "---", "---:", "---:", "---:", "---:", "---:", "---", "---"),
        ]
    else:
        lines.append("No D1/D2 evaluations are stored.")
    for r in report["h3"]:
        d0, on, kept = _kept_columns(r)
        own = r["trained_on_variant"]
        own = own["why"] if "why" in own else _fmt(own)
        lines.append(
            _row(
                r["task"], r["variant"], r["inference_steps"], len(r["seeds"]), d0, on, kept, _verdict(r), own
            )
        )
    if report["h3_scenes"]:
        lines += [
            "",
            "H3's control: the D0 runs on scene-transformed D0 layouts (robot: the whole scene moved "
            "rigidly, robot included; objects: the objects moved together, the robot not)",
            "",
            _row("task", "scene", "IS", "seeds", "D0 %", "scene %", "kept"),
            _row("---", "---", "---:", "---:", "---:", "---:", "---:"),
        ]
    for r in report["h3_scenes"]:
        lines.append(_row(r["task"], r["scene"], r["inference_steps"], len(r["seeds"]), *_kept_columns(r)))
    lines += [
        "",
        f"H4: ActionFlow >= {TARGET_SUCCESS:.0f} % within {BUDGET_S / 60:.0f} minutes of CPU training "
        "(the best checkpoint and IS within the budget)",
        "",
        _row("task", "best checkpoint within the budget", "IS", "holds", "ActionFlow's runs"),
        _row("---", "---", "---:", "---", "---"),
    ]
    for c in report["h4"]:
        best = c["best"]
        k = "-" if best is None else best["inference_steps"]
        lines.append(_row(c["task"], _fmt(best), k, _verdict(c), c["source"]))
    return "\n".join(lines)


def plot_report(report: dict, path: Path) -> None:
    """PNG with three panels: per task, success at IS = ``FEW_IS`` (mean +- std over seeds, last
    checkpoint) of ActionFlow and each reference (H1, H2; a missing policy has no bar); per
    Mimicgen-style task and IS, ActionFlow's mean success on D0, D1 and D2 over the seeds
    evaluated on both, and hatched that of the runs trained on the variant (H3); and per task,
    scene transform and IS, the D0 runs on D0 and on the moved layouts (H3's control)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tasks = [c["task"] for c in report["h1"]]
    policies = {"actionflow": {c["task"]: c["actionflow"] for c in report["h1"]}}
    for key, reference in REFERENCES.items():
        policies[reference] = {c["task"]: c["reference"] for c in report[key]}
    fig, (bars, variants, control) = plt.subplots(1, 3, figsize=(15, 3.8), dpi=110)
    width = 0.8 / len(policies)
    for j, (policy, rows) in enumerate(policies.items()):
        at = [(i, rows[t]["success"]) for i, t in enumerate(tasks) if rows.get(t) is not None]
        xs = [i + (j - (len(policies) - 1) / 2) * width for i, _ in at]
        bars.bar(xs, [m for _, (m, _) in at], width, yerr=[sd for _, (_, sd) in at], capsize=2, label=policy)
    bars.set_xticks(range(len(tasks)), tasks, rotation=20, ha="right", fontsize=8)
    bars.set(ylabel=f"success % at IS={FEW_IS} (last checkpoint)", ylim=(0, 105), title="H1, H2")
    bars.legend(fontsize=8)
    groups: dict[tuple[str, int], dict[str, float]] = {}
    for r in report["h3"]:
        if "d0" in r:
            group = groups.setdefault((r["task"].removesuffix("_D0"), r["inference_steps"]), {})
            group["D0"], group[r["variant"][-2:]] = r["d0"], r["success"]
            if "success" in r["trained_on_variant"]:
                group[f"{r['variant'][-2:]}, trained there"] = r["trained_on_variant"]["success"][0]
    _grouped_bars(variants, groups, ("D0", "D1", "D2", "D1, trained there", "D2, trained there"))
    variants.set(
        ylabel="success % (mean over seeds)",
        ylim=(0, 105),
        title="H3: D0 runs on D1, D2 (hatched: trained there)",
    )
    scenes: dict[tuple[str, int], dict[str, float]] = {}
    for r in report["h3_scenes"]:
        if "d0" in r:
            scenes[(f"{r['task']} {r['scene']}", r["inference_steps"])] = {
                "D0, the same seeds": r["d0"],
                "moved layouts": r["success"],
            }
    _grouped_bars(control, scenes, ("D0, the same seeds", "moved layouts"))
    control.set(ylabel="success % (mean over seeds)", ylim=(0, 105), title="H3's control: scene transforms")
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)


def _grouped_bars(ax, groups: dict[tuple[str, int], dict[str, float]], names) -> None:
    """One bar per name present in each ``(task, IS)`` group, groups side by side on ``ax``."""
    width = 0.8 / max(len(names), 1)
    for j, name in enumerate(names):
        at = [(i, g[name]) for i, g in enumerate(groups.values()) if name in g]
        xs = [i + (j - (len(names) - 1) / 2) * width for i, _ in at]
        ax.bar(xs, [v for _, v in at], width, label=name, hatch="//" if "trained there" in name else None)
    ax.set_xticks(
        range(len(groups)), [f"{task}, IS={k}" for task, k in groups], rotation=20, ha="right", fontsize=8
    )
    if groups:
        ax.legend(fontsize=7)


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tasks", default=",".join(TASKS))
    ap.add_argument("--results", type=Path, default=RESULTS, help="folder of the <task>.json study files")
    ap.add_argument(
        "--actionflow",
        default=None,
        metavar="STUDY/SETTING",
        help="read ActionFlow's cells from these runs, e.g. ablation/guided (default: the comparison's "
        f"actionflow runs, else ablation/{COMPARISON_ACTIONFLOW_IN_ABLATION})",
    )
    ap.add_argument(
        "--actionflow-results",
        nargs="+",
        default=[],
        metavar="TASK=FILE",
        help="read TASK's ActionFlow cells from FILE (a cell store of other runs, e.g. longer or "
        "retrained ones); the references' cells still come from the task's own file",
    )
    ap.add_argument("--plot", type=Path, default=None, help="also write the H1-H3 figures as a PNG here")
    args = ap.parse_args(argv)
    if args.actionflow is not None and args.actionflow.count("/") != 1:
        ap.error(f"--actionflow takes STUDY/SETTING, e.g. ablation/guided; got {args.actionflow!r}")
    try:
        af_files = task_files(args.actionflow_results, "--actionflow-results")
    except ValueError as e:
        ap.error(str(e))
    report = {"h1": [], "h2": [], "h3": [], "h3_scenes": [], "h4": []}
    for task in [t for t in args.tasks.split(",") if t]:
        cells = load_cells(args.results / f"{task}.json", task, required=False)
        if task in af_files:
            refs = [c for c in cells if c["study"] == "comparison" and c["setting"] in REFERENCES.values()]
            cells = refs + load_cells(af_files[task], task, required=True)
        cells = with_cap(cells, STUDY_CAPS.get(task))
        for key, reference in REFERENCES.items():
            report[key].append(check_reference(cells, task, reference, args.actionflow))
        variants = [task[:-1] + d for d in "12"] if task.endswith("_D0") else []
        own = {
            v: with_cap(load_cells(args.results / f"{v}.json", v, required=False), STUDY_CAPS.get(v))
            for v in variants
        }
        report["h3"] += check_variants(cells, task, args.actionflow, own)
        report["h3_scenes"] += check_scenes(cells, task, args.actionflow)
        if task in H4_TASKS:
            report["h4"].append(check_budget(cells, task, args.actionflow))
    print(format_report(report))
    if args.plot is not None:
        plot_report(report, args.plot)
        print(f"plot: {args.plot}")
    return report


if __name__ == "__main__":
    main()
