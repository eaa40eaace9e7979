"""Each policy at its own latency: a latency sweep's cells joined with measured chunk latencies.

A latency sweep (:mod:`lerobot_actionflow.evaluation.latency_sweep`) injects latencies ``L``; the
env sees only the held steps ``k = ceil(L / dt)`` (:func:`~lerobot_actionflow.evaluation.latency.
hold_steps`), so every ``L`` with the same ``k`` gives the same cell. A policy's *real* latency is
the median batch-1 chunk time that ``benchmarks/bench_checkpoint_latency.py --json`` measures per
checkpoint and IS, for a plain chunk (:data:`TIMED_MODES`). For each such series of the sweep
(checkpoint, K/IS, mode), :func:`at_real_latency` finds the cell whose held steps equal the real
latency's, so "success at its real latency" is read from an evaluated cell, never interpolated;
a series whose ``k`` was not swept, or that the report does not time, says so.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable
from pathlib import Path

from lerobot_actionflow.evaluation.latency import hold_steps


def load_real_latency(path: Path) -> dict[tuple[str, int], float]:
    """``(resolved checkpoint path, IS) -> median ms`` of a ``bench_checkpoint_latency.py`` report.

    Raises:
        ValueError: the file is not such a report.
    """
    try:
        report = json.loads(Path(path).read_text())
        names, cells = report["checkpoints"], report["latency_batch1"]
        out = {}
        for cell, figures in cells.items():
            name, _, steps = cell.rpartition("/IS")
            checkpoint = Path(names[name]).resolve()
            if "last" in checkpoint.parts and not checkpoint.exists():
                logging.warning(
                    "%s times %s, a `last` link that does not exist here: it cannot be resolved to "
                    "its step, so no swept checkpoint matches it", path, checkpoint,
                )  # fmt: skip
            out[str(checkpoint), int(steps)] = float(figures["median_ms"])
    except (OSError, json.JSONDecodeError, KeyError, TypeError, ValueError) as e:
        raise ValueError(
            f"{path} is not a bench_checkpoint_latency.py --json report "
            f"(checkpoints, latency_batch1 '<name>/IS<n>' -> median_ms): {e!r}"
        ) from e
    return out


#: Modes whose chunk costs what the benchmark times (one plain ``predict_action_chunk``); the
#: guided sampling of ``rtc`` costs more and is not timed by it.
TIMED_MODES = ("plain", "scheme")


def at_real_latency(
    rows: list[dict], real: dict[tuple[str, int], float], control_period_s: float
) -> list[dict]:
    """Per series of ``rows`` (injected-latency cells, not skipped, of :data:`TIMED_MODES`): its
    ``real_ms`` (None, with ``why``, if the report has no figure for it), the ``held_steps`` that
    latency means, the success with no latency (``success_at_0``, None if not swept) and at those
    held steps (``success_at_real`` and the ``cell_latency_ms`` it was read from, None if no cell
    has them)."""
    series: dict[tuple, dict[int, dict]] = {}
    for r in rows:
        if "skipped" in r or isinstance(r["latency_ms"], str) or r["mode"] not in TIMED_MODES:
            continue
        key = (r["checkpoint"], r["inference_steps"], r["mode"])
        k = hold_steps(r["latency_ms"] / 1000.0, control_period_s)
        series.setdefault(key, {}).setdefault(k, r)  # equal k: the same cell
    out = []
    for (checkpoint, steps, mode), by_hold in series.items():
        entry = {
            "checkpoint": checkpoint, "policy": next(iter(by_hold.values()))["policy"],
            "inference_steps": steps, "mode": mode, "real_ms": None, "held_steps": None,
            "success_at_0": None if 0 not in by_hold else by_hold[0]["pc_success"],
            "success_at_real": None, "cell_latency_ms": None,
        }  # fmt: skip
        real_ms = None if steps is None else real.get((str(Path(checkpoint).resolve()), steps))
        if real_ms is None:
            entry["why"] = (
                "swept at the checkpoint's own K/IS: give --inference_steps"
                if steps is None
                else "not in the latency report"
            )
        else:
            k = hold_steps(real_ms / 1000.0, control_period_s)
            cell = by_hold.get(k)
            entry.update(real_ms=real_ms, held_steps=k)
            if cell is not None:
                entry.update(success_at_real=cell["pc_success"], cell_latency_ms=cell["latency_ms"])
        out.append(entry)
    return out


def format_real_latency(entries: list[dict], series_name: Callable[[dict], str]) -> str:
    """Markdown: one row per :func:`at_real_latency` entry, named by ``series_name(entry)``."""
    lines = [
        "Success at each policy's own measured latency (batch 1; the cell with the same held steps)",
        "",
        "| series | real latency (ms) | held steps | success at 0 ms | success at its latency (cell) |",
        "| --- | ---: | ---: | ---: | ---: |",
    ]
    for e in entries:
        at_0 = "-" if e["success_at_0"] is None else f"{e['success_at_0']:.0f}"
        if e["real_ms"] is None:
            lines.append(f"| {series_name(e)} | - | - | {at_0} | {e['why']} |")
            continue
        at_real = (
            f"not swept (add a latency with {e['held_steps']} held steps)"
            if e["success_at_real"] is None
            else f"{e['success_at_real']:.0f} ({e['cell_latency_ms']:g} ms)"
        )
        lines.append(f"| {series_name(e)} | {e['real_ms']:.1f} | {e['held_steps']} | {at_0} | {at_real} |")
    return "\n".join(lines)
