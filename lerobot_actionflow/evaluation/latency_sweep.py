"""Success and smoothness against inference latency, for trained checkpoints (issue: real-time
execution, paper App. G).

For each checkpoint, number of inference steps (optional), mode and latency, the policy is
rolled out with LeRobot's ``eval_policy`` in envs that keep stepping while it infers
(:mod:`lerobot_actionflow.evaluation.latency`): ``plain`` (as trained), ``scheme`` (the paper's
skip + ``m`` actions per chunk + smoothing; flow policies) and ``rtc`` (simulated real-time
chunking; policies with ``supports_rtc``). A cell that a policy cannot run (e.g. ``diffusion``
with ``scheme``) is listed as skipped. Latencies are injected (``--latencies_ms``), so the
results reproduce on any machine; ``--measured=true`` instead uses the wall-clock time of each
chunk's inference (one cell per mode, latency ``measured``).

Every cell uses the same env seeds (``--seed`` onwards) and starts the policy's noise from
torch seed ``--seed``: paired comparisons.

Usage::

    python benchmarks/latency_sweep.py \\
        --checkpoints='[outputs/train/af/checkpoints/last/pretrained_model]' \\
        --env.type=actionflow --env.task=Lift \\
        --latencies_ms='[0,50,100,200,400,800]' --modes='[plain,scheme,rtc]' \\
        --eval.n_episodes=50 --eval.batch_size=10 --output_dir=outputs/latency

Writes ``<output_dir>/latency_results.json`` (every cell, with its per-episode records),
``latency_results.md`` (success and smoothness tables) and, if matplotlib is installed,
``latency_success.png`` (success against latency, one line per checkpoint and mode). With
``--real_latency=<bench_checkpoint_latency.py --json report>`` they also give each series'
success at its own measured latency (:mod:`lerobot_actionflow.evaluation.real_latency`).

The JSON is rewritten after every cell, and a sweep into an ``output_dir`` that holds one resumes
it: cells already there (same checkpoint, inference steps, mode and latency) are kept and not
run again, new ones are added (skipped cells are tried again). So an interrupted sweep continues
where it stopped, and several calls, one after the other (e.g. one per policy, each with its own
``--inference_steps``), build one table. A checkpoint is its resolved path: a ``last`` link is
recorded as the step it points to, and each cell stores the digest of the weights it measured
(:mod:`~lerobot_actionflow.evaluation.provenance`): new cells of a checkpoint whose stored cells
were measured on other weights (a run trained again into the same folder) are refused. The settings
that make cells comparable (the env's config, scheme, seed, episodes per cell, env batch, device)
must match the stored ones; otherwise the sweep refuses and names them. Sweeps may run side by side
into one folder (e.g. one per policy): each cell is merged into the file under a lock, and a cell
that another sweep stored meanwhile is not evaluated again.
"""

from __future__ import annotations

import json
import logging
import math
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import draccus
from lerobot.configs.default import EvalConfig
from lerobot.envs.configs import EnvConfig

from lerobot_actionflow.data.staging import exclusive_lock, write_json_atomic
from lerobot_actionflow.envs.progress import NEAR_JOINT_LIMIT_RAD
from lerobot_actionflow.evaluation.latency import MODES, Scheme
from lerobot_actionflow.evaluation.provenance import DIGEST_KEY, check_same_weights, weights_digest
from lerobot_actionflow.evaluation.real_latency import at_real_latency, format_real_latency, load_real_latency

MEASURED = "measured"
#: Env config fields that change only what is displayed or derived, not a cell's outcome.
ENV_DISPLAY_FIELDS = (
    "features", "features_map", "render_mode", "render_camera", "visualization_height",
    "visualization_width", "max_parallel_tasks", "disable_env_checker",
)  # fmt: skip


@dataclass
class LatencySweepConfig:
    """Command-line configuration (parsed with draccus, like LeRobot's CLIs)."""

    env: EnvConfig
    # Checkpoint directories (…/pretrained_model) of actionflow, euclidean_flow or diffusion.
    checkpoints: list[str] = field(default_factory=list)
    latencies_ms: list[float] = field(default_factory=lambda: [0, 50, 100, 200, 400, 800])
    modes: list[str] = field(default_factory=lambda: list(MODES))
    # Inference steps (K for the flow policies, IS for diffusion); empty: each checkpoint's own.
    inference_steps: list[int] = field(default_factory=list)
    # The paper's scheme: actions executed per chunk (m) and smoothing weight alpha.
    scheme_action_steps: int = 2
    scheme_smoothing: float = 0.5
    # Use the measured wall-clock time of each inference instead of `latencies_ms`.
    measured: bool = False
    # A `bench_checkpoint_latency.py --json` report of these checkpoints: adds each series'
    # success at its own measured latency (`real_latency.at_real_latency`) to the outputs.
    real_latency: Path | None = None
    eval: EvalConfig = field(default_factory=lambda: EvalConfig(n_episodes=50, batch_size=10))
    seed: int = 1000
    device: str | None = None
    output_dir: Path | None = None

    def __post_init__(self):
        bad = [m for m in self.modes if m not in MODES]
        if bad:
            raise ValueError(f"unknown modes {bad}; choose among {MODES}")
        if any(not math.isfinite(x) or x < 0 for x in self.latencies_ms):
            raise ValueError(f"latencies_ms must be finite and >= 0, got {self.latencies_ms}")
        # A checkpoint is its resolved path (a `last` link names the step it points to now), and
        # an entry given twice is one cell.
        self.checkpoints = list(dict.fromkeys(str(Path(c).resolve()) for c in self.checkpoints))
        self.latencies_ms = list(dict.fromkeys(float(x) for x in self.latencies_ms))
        self.modes = list(dict.fromkeys(self.modes))
        self.inference_steps = list(dict.fromkeys(self.inference_steps))


def control_period_s(cfg: LatencySweepConfig) -> float:
    """Seconds per control step of the swept env."""
    return 1.0 / cfg.env.fps


def _latency_ms(latency_s: float | None) -> float | str:
    return MEASURED if latency_s is None else 1000.0 * latency_s


def cell_key(row: dict) -> tuple:
    """What identifies a cell of a sweep: ``(checkpoint, inference_steps, mode, latency_ms)``."""
    return row["checkpoint"], row["inference_steps"], row["mode"], row["latency_ms"]


def _cells(cfg: LatencySweepConfig, checkpoint: str, done: set[tuple]):
    """The ``(inference_steps, mode, latency_s)`` of ``checkpoint``'s cells not in ``done``."""
    latencies = [None] if cfg.measured else [x / 1000.0 for x in cfg.latencies_ms]
    for num_steps in cfg.inference_steps or [None]:
        for mode in cfg.modes:
            for latency_s in latencies:
                if (checkpoint, num_steps, mode, _latency_ms(latency_s)) not in done:
                    yield num_steps, mode, latency_s


def _evaluate_checkpoint(
    cfg: LatencySweepConfig,
    checkpoint: str,
    on_row: Callable[[dict], None],
    stored: list[dict],
    stored_since: Callable[[tuple], bool] = lambda key: False,
) -> None:
    """Evaluate every cell of ``checkpoint`` not in ``stored`` (by :func:`cell_key`), and not
    ``stored_since(key)`` (by another sweep, asked just before the cell); ``on_row(row)`` as each
    is done (or skipped). Loads nothing when all are done, and nothing when the stored cells of
    ``checkpoint`` were measured on other weights
    (:func:`~lerobot_actionflow.evaluation.provenance.check_same_weights` raises)."""
    done = {cell_key(r) for r in stored}
    todo = list(_cells(cfg, checkpoint, done))
    if not todo:
        return
    digest = weights_digest(checkpoint)
    check_same_weights(
        (r for r in stored if r["checkpoint"] == checkpoint), digest, checkpoint,
        f"Evaluate it into another --output_dir, or move {cfg.output_dir}/latency_results.json away.",
    )  # fmt: skip
    import torch
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.envs.factory import make_env_pre_post_processors
    from lerobot.policies.factory import make_policy, make_pre_post_processors

    from lerobot_actionflow.evaluation.latency import configure_execution, evaluate_with_latency
    from lerobot_actionflow.evaluation.latency_hold import make_latency_envs
    from lerobot_actionflow.evaluation.sweep import set_inference_steps

    policy_cfg = PreTrainedConfig.from_pretrained(checkpoint)
    policy_cfg.pretrained_path = Path(checkpoint)
    if cfg.device is not None:
        policy_cfg.device = cfg.device
    policy = make_policy(cfg=policy_cfg, env_cfg=cfg.env)
    policy.eval()
    preprocessor, postprocessor = make_pre_post_processors(
        policy_cfg=policy_cfg,
        pretrained_path=checkpoint,
        preprocessor_overrides={"device_processor": {"device": str(policy.config.device)}},
    )
    env_pre, env_post = make_env_pre_post_processors(env_cfg=cfg.env, policy_cfg=policy_cfg)
    period = control_period_s(cfg)
    trained_m = policy.config.n_action_steps
    scheme = Scheme(cfg.scheme_action_steps, cfg.scheme_smoothing)
    vec_env = make_latency_envs(cfg.env, cfg.eval.batch_size, cfg.eval.use_async_envs)
    try:
        for num_steps, mode, latency_s in todo:
            row = {
                "checkpoint": checkpoint,
                "policy": policy_cfg.type,
                "inference_steps": num_steps,
                "mode": mode,
                "latency_ms": _latency_ms(latency_s),
                DIGEST_KEY: digest,
            }
            if stored_since(cell_key(row)):
                logging.info("latency sweep: %s was stored by another sweep meanwhile", cell_key(row))
                continue
            try:
                if num_steps is not None:
                    set_inference_steps(policy, num_steps)
                configure_execution(policy, mode, latency_s, period, scheme, trained_m)
            except ValueError as e:
                on_row({**row, "skipped": str(e)})
                continue
            torch.manual_seed(cfg.seed)  # the same policy noise draws in every cell
            start = time.perf_counter()
            result = evaluate_with_latency(
                policy, vec_env, env_pre, env_post, preprocessor, postprocessor,
                control_period_s=period, latency_s=latency_s, rtc=mode == "rtc",
                n_episodes=cfg.eval.n_episodes, start_seed=cfg.seed,
            )  # fmt: skip
            on_row({**row, **result, "eval_s": time.perf_counter() - start})
    finally:
        vec_env.close()


def checkpoint_label(checkpoint: str) -> str:
    """``run/train/step`` of ``…/run/train/checkpoints/step/pretrained_model``, else the path."""
    parts = Path(checkpoint).parts
    if "checkpoints" not in parts:
        return checkpoint
    i = len(parts) - 1 - parts[::-1].index("checkpoints")
    return "/".join(parts[max(0, i - 2) : i] + parts[i + 1 : i + 2])


def _series(row: dict) -> str:
    steps = "" if row["inference_steps"] is None else f" K/IS={row['inference_steps']}"
    return f"{checkpoint_label(row['checkpoint'])} ({row['policy']}{steps}) {row['mode']}"


def _success_cell(row: dict | None) -> str:
    return "–" if row is None else f"{row['pc_success']:.0f} ({row['n_episodes']})"


def format_tables(rows: list[dict]) -> str:
    """Markdown: success % per series (checkpoint, policy, K/IS, mode) and latency; then the
    smoothness of every cell (largest jumps, jerk); then, for cells with it, how far the episodes
    got (:func:`~lerobot_actionflow.evaluation.latency.summarize_progress`)."""
    done = [r for r in rows if "skipped" not in r]
    latencies = sorted({r["latency_ms"] for r in done}, key=lambda x: (isinstance(x, str), x))
    series: dict[str, dict] = {}
    for r in done:
        series.setdefault(_series(r), {})[r["latency_ms"]] = r
    head = " | ".join(f"{x:g} ms" if not isinstance(x, str) else x for x in latencies)
    lines = [
        "Success % (episodes) against inference latency",
        "",
        f"| series | {head} |",
        "| --- |" + " ---: |" * len(latencies),
    ]
    for name, cells in series.items():
        vals = [_success_cell(cells.get(x)) for x in latencies]
        lines.append(f"| {name} | " + " | ".join(vals) + " |")
    lines += [
        "",
        "Smoothness of the commanded target (mean over episodes of each episode's largest jump; "
        "jerk: mean squared third difference of positions per step)",
        "",
        "| series | latency | held steps / chunk | max jump pos (mm) | max jump rot (deg) | jerk (mm²) |",
        "| --- | ---: | ---: | ---: | ---: | ---: |",
    ]
    for r in done:
        lat = r["latency_ms"] if isinstance(r["latency_ms"], str) else f"{r['latency_ms']:g} ms"
        lines.append(
            f"| {_series(r)} | {lat} | {r['held_steps_per_chunk']:.1f} | "
            f"{1e3 * r['mean_max_position_jump_m']:.1f} | "
            f"{math.degrees(r['mean_max_rotation_jump_rad']):.1f} | {1e6 * r['mean_jerk_m2']:.2f} |"
        )
    lines += _progress_table(done)
    skipped = [r for r in rows if "skipped" in r]
    if skipped:
        lines += ["", "Skipped: " + "; ".join(f"{_series(r)}: {r['skipped']}" for r in skipped)]
    return "\n".join(lines)


def _progress_table(done: list[dict]) -> list[str]:
    with_progress = [r for r in done if r.get("pc_subgoals") is not None]
    if not with_progress:
        return []
    names = list(with_progress[0]["pc_subgoals"])
    lines = [
        "",
        "Progress: % of episodes that reached each sub-goal (in task order: each counts once the "
        "earlier ones are reached); % of "
        f"episodes with an arm joint within {NEAR_JOINT_LIMIT_RAD} rad of its limit, of all and of the "
        "failed ones; the mean of the episodes' smallest joint margins",
        "",
        "| series | latency | success | " + " | ".join(names) + " | near limit | near limit, failed | "
        "min margin (rad) |",
        "| --- | ---: | ---: |" + " ---: |" * (len(names) + 3),
    ]
    for r in with_progress:
        lat = r["latency_ms"] if isinstance(r["latency_ms"], str) else f"{r['latency_ms']:g} ms"
        reached = " | ".join(f"{r['pc_subgoals'].get(n, float('nan')):.0f}" for n in names)
        lines.append(
            f"| {_series(r)} | {lat} | {r['pc_success']:.0f} | {reached} | {r['pc_near_joint_limit']:.0f} | "
            f"{r['pc_near_joint_limit_failed']:.0f} | {r['mean_min_joint_margin_rad']:.3f} |"
        )
    return lines


#: Line style of each execution mode in the plot; the colour tells the checkpoint and K/IS.
MODE_LINESTYLES = {"plain": "-", "scheme": "--", "rtc": ":"}


def plot_success(rows: list[dict], path: Path, at_real: list[dict] = ()) -> Path | None:
    """Success against injected latency, one line per series (a colour per checkpoint and K/IS,
    a line style per mode, :data:`MODE_LINESTYLES`), and a star per ``at_real`` entry
    (:func:`~lerobot_actionflow.evaluation.real_latency.at_real_latency`) at the series' measured
    latency; None without matplotlib."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    series: dict[str, list[tuple[float, float]]] = {}
    group_of: dict[str, tuple[str, int | None]] = {}
    for r in rows:
        if "skipped" not in r and not isinstance(r["latency_ms"], str):
            series.setdefault(_series(r), []).append((r["latency_ms"], r["pc_success"]))
            group_of[_series(r)] = (r["checkpoint"], r["inference_steps"])
    if not series:
        return None
    groups = list(dict.fromkeys(group_of.values()))
    palette = plt.get_cmap("tab10" if len(groups) <= 10 else "tab20").colors
    colour = {g: palette[i % len(palette)] for i, g in enumerate(groups)}
    fig, ax = plt.subplots(figsize=(8, 5))
    for name, pts in series.items():
        pts.sort()
        mode = name.rsplit(" ", 1)[-1]
        ax.plot([p[0] for p in pts], [p[1] for p in pts], marker="o", markersize=4, label=name,
                color=colour[group_of[name]], linestyle=MODE_LINESTYLES.get(mode, "-"))  # fmt: skip
    for e in at_real:
        if e["success_at_real"] is not None and _series(e) in group_of:
            ax.plot(e["real_ms"], e["success_at_real"], marker="*", markersize=14,
                    color=colour[group_of[_series(e)]], mec="k")  # fmt: skip
    ax.set_xlabel("injected inference latency (ms); stars: each series at its measured latency")
    ax.set_ylabel("success (%)")
    ax.set_ylim(-2, 102)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _settings(cfg: LatencySweepConfig) -> dict:
    """What makes the cells of one results file comparable (``complete`` is added on writing): the
    env's config (less :data:`ENV_DISPLAY_FIELDS`), the scheme, seed, episodes, env batch and
    device (the policy's noise is drawn per batch)."""
    env = {k: v for k, v in draccus.encode(cfg.env).items() if k not in ENV_DISPLAY_FIELDS}
    return {
        "env_type": cfg.env.type,
        "env": env,
        "control_period_s": control_period_s(cfg),
        "scheme": asdict(Scheme(cfg.scheme_action_steps, cfg.scheme_smoothing)),
        "seed": cfg.seed,
        "n_episodes": cfg.eval.n_episodes,
        "batch_size": cfg.eval.batch_size,
        "device": cfg.device,
    }


def _results_path(cfg: LatencySweepConfig) -> Path:
    return Path(cfg.output_dir) / "latency_results.json"


def _load_results(cfg: LatencySweepConfig) -> dict | None:
    path = _results_path(cfg)
    if not path.exists():
        return None
    try:
        saved = json.loads(path.read_text())
        if not isinstance(saved["settings"], dict) or not isinstance(saved["cells"], list):
            raise TypeError("settings must be an object and cells a list")
    except (json.JSONDecodeError, KeyError, TypeError) as e:
        raise ValueError(
            f"{path} is not a latency sweep's results ({e!r}): move it or choose another --output_dir"
        ) from e
    return saved


def stored_cells(cfg: LatencySweepConfig) -> list[dict]:
    """Every cell of the sweep stored in ``cfg.output_dir``, skipped ones included (none without
    a file there).

    Raises:
        ValueError: the stored sweep has other settings (:func:`_settings`), or is not a sweep.
    """
    saved = _load_results(cfg)
    if saved is None:
        return []
    stored = saved["settings"]
    mine = json.loads(json.dumps(_settings(cfg)))  # as the JSON stores them (tuples -> lists)
    differ = {k: (stored.get(k), v) for k, v in mine.items() if stored.get(k) != v}
    if differ:
        said = ", ".join(f"{k}: stored {a!r}, now {b!r}" for k, (a, b) in differ.items())
        raise ValueError(
            f"{_results_path(cfg)} holds a sweep with other settings ({said}); resume it with its "
            "settings, or choose another --output_dir"
        )
    return saved["cells"]


def load_previous(cfg: LatencySweepConfig) -> list[dict]:
    """The evaluated cells of :func:`stored_cells`: skipped cells are left out, so that they are
    tried again."""
    return [c for c in stored_cells(cfg) if "skipped" not in c]


def real_latency_report(cfg: LatencySweepConfig) -> Path | None:
    """``--real_latency``, else the report an earlier call on ``output_dir`` joined."""
    if cfg.real_latency is not None or cfg.output_dir is None:
        return cfg.real_latency
    saved = _load_results(cfg)
    stored = None if saved is None else saved.get("real_latency")
    return None if stored is None else Path(stored)


def report_text(rows: list[dict], at_real: list[dict] | None = None) -> str:
    """:func:`format_tables`, then each series at its own latency where ``at_real`` is given."""
    text = format_tables(rows)
    return text if at_real is None else text + "\n\n" + format_real_latency(at_real, _series)


def sweep_report(cfg: LatencySweepConfig, rows: list[dict]) -> tuple[list[dict] | None, str]:
    """The join with the real latencies (:func:`real_latency_report`; None without one) and the
    Markdown of ``rows``."""
    report = real_latency_report(cfg)
    at_real = (
        None if report is None else at_real_latency(rows, load_real_latency(report), control_period_s(cfg))
    )
    return at_real, report_text(rows, at_real)


def _write(cfg: LatencySweepConfig, rows: list[dict], final: bool) -> None:
    out = Path(cfg.output_dir)
    results = {"settings": {**_settings(cfg), "complete": final}, "cells": rows}
    at_real, text = sweep_report(cfg, rows)
    if at_real is not None:
        results["real_latency"] = str(Path(real_latency_report(cfg)).resolve())
        results["at_real_latency"] = at_real
    write_json_atomic(out / "latency_results.json", results)  # a crash leaves the last whole file
    (out / "latency_results.md").write_text(text + "\n")
    if final:
        plot_success(rows, out / "latency_success.png", at_real or [])


def run_latency_sweep(cfg: LatencySweepConfig) -> list[dict]:
    """Evaluate every cell that ``output_dir`` does not hold yet (:func:`load_previous`). With an
    ``output_dir``, merges each cell into its JSON and rewrites the markdown (``settings.complete``
    False), and at the end writes them with ``complete`` True (with sweeps side by side: the
    last one to write had finished), and the plot; returns all the
    folder's cells then (the stored ones first, including those other sweeps added meanwhile).
    Without, returns this call's cells."""
    if not cfg.checkpoints:
        raise ValueError("no checkpoints given: pass --checkpoints='[path/to/pretrained_model, ...]'")
    if cfg.real_latency is not None:
        load_real_latency(cfg.real_latency)  # a bad report fails before any evaluation
    if cfg.output_dir is None:
        rows: list[dict] = []

        def keep(row: dict) -> None:
            _log_row(row)
            rows.append(row)

        for ckpt in cfg.checkpoints:
            _evaluate_checkpoint(cfg, ckpt, keep, [])
        return rows
    with _folder_lock(cfg):
        stored = load_previous(cfg)  # other settings fail here, before any evaluation

    def on_row(row: dict) -> None:
        _log_row(row)
        with _folder_lock(cfg):
            _write(cfg, _merged(cfg, row), final=False)

    def stored_since(key: tuple) -> bool:
        with _folder_lock(cfg):
            return key in {cell_key(r) for r in load_previous(cfg)}

    for ckpt in cfg.checkpoints:
        _evaluate_checkpoint(cfg, ckpt, on_row, stored, stored_since)
    with _folder_lock(cfg):
        rows = _merged(cfg)
        _write(cfg, rows, final=True)
    return rows


def _log_row(row: dict) -> None:
    logging.info("latency sweep: %s", {k: v for k, v in row.items() if k != "episodes"})


def _folder_lock(cfg: LatencySweepConfig):
    """The lock that makes reading and rewriting ``output_dir``'s files one step (it waits)."""
    return exclusive_lock(Path(cfg.output_dir) / ".latency_sweep.lock")


def _merged(cfg: LatencySweepConfig, row: dict | None = None) -> list[dict]:
    """The folder's cells as stored now (skipped ones included), with ``row`` added in place of a
    stored cell with its :func:`cell_key`. Call it holding :func:`_folder_lock`."""
    cells = stored_cells(cfg)
    if row is None:
        return cells
    return [c for c in cells if cell_key(c) != cell_key(row)] + [row]


def main(argv: list[str] | None = None) -> list[dict]:
    """CLI entry point (``python benchmarks/latency_sweep.py --help``)."""
    from lerobot.utils.import_utils import register_third_party_plugins

    logging.basicConfig(level=logging.INFO, force=True)
    register_third_party_plugins()  # our policy and env types, like lerobot-eval
    cfg = draccus.parse(LatencySweepConfig, args=sys.argv[1:] if argv is None else argv)
    rows = run_latency_sweep(cfg)
    print(sweep_report(cfg, rows)[1])
    return rows


if __name__ == "__main__":
    main()
