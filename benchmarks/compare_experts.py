"""Compare two runs of ``bench_experts.py --actions-out``, e.g. before and after a change.

    python benchmarks/compare_experts.py --before b.json b.npz --after a.json a.npz [more pairs...]

Each ``--before`` / ``--after`` takes the JSON the benchmark printed and the ``.npz`` it saved
(several pairs each for runs split over processes). Prints a Markdown table, one row per task of
both runs: successes and mean episode length before and after, how many seeds have bit-identical
actions, the first step at which any seed's actions differ, and the failed seeds.
"""

from __future__ import annotations

import argparse
import json

import numpy as np


def _load(paths: list[str]) -> tuple[dict[str, dict], dict[str, np.ndarray]]:
    if len(paths) % 2:
        raise SystemExit(f"expected JSON / NPZ pairs, got {paths}")
    results, actions = {}, {}
    for js, npz in zip(paths[::2], paths[1::2], strict=True):
        for row in json.load(open(js))["results"]:
            results[row["task"]] = row
        actions.update(dict(np.load(npz)))
    return results, actions


def _first_difference(x: np.ndarray, y: np.ndarray) -> int | None:
    """First step where two action sequences ``(T, 10)`` differ (``None`` if they are equal)."""
    n = min(len(x), len(y))
    diff = np.flatnonzero((x[:n] != y[:n]).any(axis=1))
    if diff.size:
        return int(diff[0])
    return None if len(x) == len(y) else n


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", nargs="+", required=True, help="JSON NPZ [JSON NPZ ...]")
    ap.add_argument("--after", nargs="+", required=True, help="JSON NPZ [JSON NPZ ...]")
    args = ap.parse_args(argv)
    before, acts_b = _load(args.before)
    after, acts_a = _load(args.after)
    print(
        "| task | successes before | after | mean steps before | after | seeds with identical actions "
        "| first differing step | failed seeds before / after |"
    )
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | --- |")
    for task in (t for t in before if t in after):
        b, a = before[task], after[task]
        keys = [k for k in acts_b if k.startswith(f"{task}/") and k in acts_a]
        firsts = [f for k in keys if (f := _first_difference(acts_b[k], acts_a[k])) is not None]
        same = len(keys) - len(firsts)
        failed = " / ".join(", ".join(map(str, r["failed_seeds"])) or "-" for r in (b, a))
        print(
            f"| {task} | {b['successes']}/{b['seeds']} | {a['successes']}/{a['seeds']} | {b['mean_steps']} "
            f"| {a['mean_steps']} | {same}/{len(keys)} | {min(firsts) if firsts else '-'} | {failed} |"
        )


if __name__ == "__main__":
    main()
