"""Pool inference-step sweeps that evaluated the same checkpoints on disjoint episode seeds.

An evaluation of 50 episodes can be run as 20 episodes (``--seed=1000``) and 30 more later
(``--seed=1020``: LeRobot seeds the envs of batch ``i`` with ``seed + i * batch_size``, so the
two runs cover seeds 1000-1049 once each). Each input is a ``sweep_results.json`` of
``lerobot_actionflow.evaluation.sweep`` (a list of rows) or a ``results.json`` of
``run_results.py`` (its ``is_sweep`` rows). Rows are grouped by (checkpoint, inference steps);
per group the successes ``pc_success * n_episodes / 100`` and the episodes are summed:

    pc_success = 100 * sum_i successes_i / sum_i n_episodes_i

Writes the pooled rows (the same schema, plus ``sources``) and prints a markdown table.

    python benchmarks/pool_sweeps.py pooled.json first/sweep_results.json more/sweep_results.json \
        --plot benchmarks/figures/Lift_is_sweep.png --title "Lift: success vs inference steps"
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from run_results import format_tables, plot_is_sweep


def load_rows(path: Path) -> list[dict]:
    """The sweep rows of a ``sweep_results.json`` (list) or a ``results.json`` (``is_sweep``)."""
    data = json.loads(Path(path).read_text())
    rows = data["is_sweep"] if isinstance(data, dict) else data
    for i, row in enumerate(rows):
        missing = {"checkpoint", "policy", "inference_steps", "n_episodes", "pc_success"} - set(row)
        if missing:
            raise ValueError(f"{path}: row {i} lacks {sorted(missing)}; is it a sweep result?")
    return rows


def pool(row_lists: list[list[dict]]) -> list[dict]:
    """Episode-weighted pooling of rows with the same (checkpoint, inference_steps)."""
    pooled: dict[tuple[str, int], dict] = {}
    for rows in row_lists:
        for row in rows:
            key = (row["checkpoint"], row["inference_steps"])
            cell = pooled.setdefault(
                key,
                {
                    "checkpoint": row["checkpoint"],
                    "policy": row["policy"],
                    "inference_steps": row["inference_steps"],
                    "sampler": row.get("sampler"),
                    "successes": 0.0,
                    "n_episodes": 0,
                    "sources": [],
                },
            )
            if cell["policy"] != row["policy"]:
                raise ValueError(f"{row['checkpoint']}: policy {row['policy']!r} != {cell['policy']!r}")
            cell["successes"] += row["pc_success"] * row["n_episodes"] / 100
            cell["n_episodes"] += row["n_episodes"]
            cell["sources"].append({"n_episodes": row["n_episodes"], "pc_success": row["pc_success"]})
    out = []
    for cell in pooled.values():
        successes = round(cell.pop("successes"))
        out.append({**cell, "successes": successes, "pc_success": 100 * successes / cell["n_episodes"]})
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("output", type=Path, help="pooled rows (JSON) are written here")
    ap.add_argument("inputs", type=Path, nargs="+", help="sweep_results.json or results.json files")
    ap.add_argument("--plot", type=Path, default=None, help="also plot success against IS (PNG)")
    ap.add_argument("--title", default="success vs inference steps")
    args = ap.parse_args(argv)
    rows = pool([load_rows(p) for p in args.inputs])
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(rows, indent=2))
    print(format_tables({"is_sweep": rows}))
    print("episodes per cell: " + ", ".join(sorted({str(r["n_episodes"]) for r in rows})))
    if args.plot is not None:
        plot_is_sweep({"is_sweep": rows}, args.plot, title=args.title)
        print(f"plot: {args.plot}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
