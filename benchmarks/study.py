"""The learning study of issue #17: ablations of ActionFlow's defaults and the converged comparison,
several training seeds per setting, every evaluated cell kept in one JSON per task.

A **setting** is a policy type plus ``lerobot-train`` overrides on top of the shared protocol
(:data:`COMMON`, the CPU sizes of :data:`CPU_SIZE`). A **run** is one setting trained with one
seed; it saves a checkpoint every ``eval_every`` steps. A **cell** is one evaluation: a run's
checkpoint at one step, on one evaluation task, at one number of inference steps (IS) and time
grid, over ``n_episodes`` episodes from env seed ``eval_seed`` on, each capped at ``episode_length``
control steps. Cells are the unit of resumption:
:class:`ResultStore` writes the task's JSON after every evaluation (write to a temporary file,
then rename), and a cell already in it is never evaluated again.

Summaries (:func:`summarise`) average a setting's cells over its training seeds and give
``mean +- std`` (population std over seeds; ``n`` = number of seeds), for the last checkpoint
and for the best evaluated one (the checkpoint step with the highest mean over seeds).
"""

from __future__ import annotations

import json
import os
import statistics
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path

from lerobot_actionflow.data.staging import exclusive_lock

#: Protocol shared by every policy of the study (history, horizon, executed actions).
COMMON = ["--policy.n_obs_steps=2", "--policy.horizon=16", "--policy.n_action_steps=8"]
#: Small models that train in minutes on a CPU; the widths are the policies' own knobs.
CPU_SIZE = {
    "actionflow": [
        "--policy.dim=64",
        "--policy.num_layers=2",
        "--policy.num_heads=4",
        "--policy.head_dim=16",
    ],
    "euclidean_flow": ["--policy.backbone=unet", "--policy.down_dims=[64,128,256]"],
    "diffusion": ["--policy.down_dims=[64,128,256]"],
}
PAPER_SIZE = {"actionflow": [], "euclidean_flow": ["--policy.backbone=unet"], "diffusion": []}


@dataclass(frozen=True)
class Setting:
    """One configuration: ``policy`` type and its ``overrides`` (``lerobot-train`` flags, after
    :data:`COMMON` and the size preset, so they win). A sampling-only setting names the setting
    whose runs it evaluates (``trained_as``; its own ``overrides`` are then empty) and adds
    ``sampling`` flags to the evaluation sweep: it costs no training. A setting with both
    ``overrides`` and ``sampling`` trains its own runs and evaluates them with those flags."""

    policy: str
    overrides: tuple[str, ...] = ()
    why: str = ""
    trained_as: str | None = None
    sampling: tuple[str, ...] = ()


#: ActionFlow at the paper's size, which is also the package's default size (ActionFlowConfig):
#: spelled out because the study's ``CPU_SIZE`` flags come first and would otherwise win.
ACTIONFLOW_PAPER_SIZE = (
    "--policy.dim=128",
    "--policy.num_layers=4",
    "--policy.num_heads=8",
    "--policy.head_dim=16",
)

#: The evaluation flag of the package's default sampler: each chunk after the first guided toward
#: the previous chunk's remaining actions.
GUIDED = ("--guide_to_previous_chunk=true",)

#: Ablations of ActionFlow (issue #17, part 1). The time grid and K need no retraining: they
#: are evaluation axes of the ``default`` runs (``--time-spacings``, ``--inference-steps``).
ABLATIONS: dict[str, Setting] = {
    "default": Setting("actionflow", (), "the baseline (BASELINES) at the CPU size"),
    "squash_off": Setting(
        "actionflow", ("--policy.squash_translations=false",), "no tanh, translation scale 10"
    ),
    "scale_3": Setting("actionflow", ("--policy.translation_scale=3",), "tanh(3 d)"),
    "scale_1": Setting("actionflow", ("--policy.translation_scale=1",), "tanh(d)"),
    # The loss measures translation errors in units of 1 / translation_scale metres, so a smaller
    # scale also weights translations less (by the scale squared). This setting restores the
    # weight, (10 / 3)^2, and changes only what the network sees.
    "scale_3_same_loss": Setting(
        "actionflow",
        ("--policy.translation_scale=3", "--policy.loss_weight_translation=11.11111111111111"),
        "tanh(3 d), translation loss weighted as at scale 10",
    ),
    "scale_3_squash_off": Setting(
        "actionflow",
        ("--policy.translation_scale=3", "--policy.squash_translations=false"),
        "3 d, no tanh",
    ),
    "scale_1_squash_off": Setting(
        "actionflow",
        ("--policy.translation_scale=1", "--policy.squash_translations=false"),
        "d, no tanh",
    ),
    "velocity_eef": Setting(
        "actionflow",
        ("--policy.translation_velocity_frame=eef",),
        "translation target in the EEF frame (constant along the path)",
    ),
    "obs_1": Setting("actionflow", ("--policy.n_obs_steps=1",), "one observation step"),
    "size_paper": Setting(
        "actionflow", ACTIONFLOW_PAPER_SIZE, "the paper's size (width 128, 4 IPA layers, 8 heads)"
    ),
    # Few-step accuracy (issue #21).
    "time_logit_normal": Setting(
        "actionflow",
        ("--policy.train_time_distribution=logit_normal",),
        "training times sigmoid(N(0, 1)): more weight mid-path, less at the ends",
    ),
    "noise_concentrated": Setting(
        "actionflow",
        ("--policy.noise_rotation=concentrated",),
        "initial rotations Exp(0.5 eps) around the EEF instead of uniform on SO(3): a less curved flow",
    ),
    "solver_midpoint": Setting(
        "actionflow",
        (),
        "the default runs sampled with SE(3) midpoint steps (2 calls per step: even IS only)",
        trained_as="default",
        sampling=("--solver=midpoint",),
    ),
    "guided": Setting(
        "actionflow",
        (),
        "the noise_concentrated runs, each chunk guided toward the previous one (the package default)",
        trained_as="noise_concentrated",
        sampling=GUIDED,
    ),
    "shortcut": Setting(
        "actionflow",
        ("--policy.few_step_objective=shortcut",),
        "shortcut self-consistency on 1/4 of each batch, step size 1/K at sampling (uniform grid only)",
    ),
    "shortcut_concentrated": Setting(
        "actionflow",
        ("--policy.few_step_objective=shortcut", "--policy.noise_rotation=concentrated"),
        "the shortcut objective with concentrated initial rotations: for one-step sampling",
    ),
    "shortcut_guided": Setting(
        "actionflow",
        (),
        "the shortcut_concentrated runs, each chunk guided toward the previous one",
        trained_as="shortcut_concentrated",
        sampling=GUIDED,
    ),
    "time_beta_noise": Setting(
        "actionflow",
        ("--policy.train_time_distribution=beta", "--policy.train_time_beta=[1.0,1.5]"),
        "training times Beta(1, 1.5): density 1.5 (1 - t)^0.5, more weight near t = 0 (noise)",
    ),
    "noise_sigma_0.05": Setting(
        "actionflow", ("--policy.noise_sigma=0.05",), "initial positions EEF + N(0, 0.05^2 I)"
    ),
    "noise_sigma_0.2": Setting(
        "actionflow", ("--policy.noise_sigma=0.2",), "initial positions EEF + N(0, 0.2^2 I)"
    ),
    # A tighter prior around the EEF than the package default (ActionFlowConfig.noise_sigma and
    # noise_kappa), on top of it and sampled like it: does a narrower start straighten the flow
    # further? The concentrated rotations are repeated because the ablation baseline is uniform.
    "guided_sigma_0.05": Setting(
        "actionflow",
        ("--policy.noise_rotation=concentrated", "--policy.noise_sigma=0.05"),
        "the package default (guided) with initial positions EEF + N(0, 0.05^2 I)",
        sampling=GUIDED,
    ),
    "guided_sigma_0.07": Setting(
        "actionflow",
        ("--policy.noise_rotation=concentrated", "--policy.noise_sigma=0.07"),
        "the package default (guided) with initial positions EEF + N(0, 0.07^2 I)",
        sampling=GUIDED,
    ),
    "shortcut_guided_sigma_0.05": Setting(
        "actionflow",
        (
            "--policy.few_step_objective=shortcut",
            "--policy.noise_rotation=concentrated",
            "--policy.noise_sigma=0.05",
        ),
        "the shortcut objective with the tighter prior of guided_sigma_0.05, sampled like it",
        sampling=GUIDED,
    ),
    # The squash of translations (tanh(10 d)) on top of the package default: the ablation baseline
    # says whether tanh helps with uniform rotations; this says whether it helps the default.
    "guided_squash_off": Setting(
        "actionflow",
        ("--policy.noise_rotation=concentrated", "--policy.squash_translations=false"),
        "the package default (guided) with translations scaled (10 d) but not squashed by tanh",
        sampling=GUIDED,
    ),
    # The package default as a user gets it, at its own size: does the paper's size still pay
    # once the flow is concentrated and guided?
    "guided_size_paper": Setting(
        "actionflow",
        ("--policy.noise_rotation=concentrated", *ACTIONFLOW_PAPER_SIZE),
        "the package default (guided) at the package's size (width 128, 4 IPA layers, 8 heads)",
        sampling=GUIDED,
    ),
    "guided_kappa_0.25": Setting(
        "actionflow",
        ("--policy.noise_rotation=concentrated", "--policy.noise_kappa=0.25"),
        "the package default (guided) with initial rotations Exp(0.25 eps) around the EEF's",
        sampling=GUIDED,
    ),
}

#: The converged comparison (issue #17, part 2): the three policies at the CPU size.
COMPARISON: dict[str, Setting] = {
    "actionflow": Setting("actionflow"),
    "euclidean_flow": Setting("euclidean_flow"),
    "diffusion": Setting("diffusion"),
}

STUDIES = {"ablation": ABLATIONS, "comparison": COMPARISON}

#: The ablation setting that trains the comparison's ``actionflow`` configuration: the package
#: default is the ablation baseline with concentrated initial rotations (the tests check that
#: the two parse to one config). Reports read its runs where a task has no comparison runs of
#: ActionFlow, instead of training the same thing twice.
COMPARISON_ACTIONFLOW_IN_ABLATION = "noise_concentrated"

#: Flags every run of a study gets per policy, before its setting's overrides. The ablations
#: compare settings with one fixed baseline, the configuration of every stored ``ablation`` cell,
#: whatever the package defaults become: ActionFlow with uniform initial rotations. The
#: comparison runs each policy with its package defaults.
BASELINES: dict[str, dict[str, tuple[str, ...]]] = {
    "ablation": {"actionflow": ("--policy.noise_rotation=uniform",)},
    "comparison": {},
}


@dataclass(frozen=True)
class CellKey:
    """What identifies an evaluation cell (see the module docstring)."""

    study: str
    setting: str
    seed: int
    step: int
    eval_task: str
    inference_steps: int
    time_spacing: str  # "checkpoint" = the checkpoint's own grid
    n_episodes: int
    eval_seed: int
    episode_length: int | None  # None = the task's own cap


def cell_key(cell: dict) -> CellKey:
    return CellKey(**{k: cell[k] for k in CellKey.__dataclass_fields__})


class ResultStore:
    """The cells of one task, in ``path`` (a JSON object ``{"task": ..., "cells": [...]}``).

    ``add`` re-reads the file under an exclusive lock (``<path>.lock``), merges the cell
    (replacing one with the same :class:`CellKey`) and rewrites the file atomically (temporary
    file, then rename). Several studies of one task can therefore run side by side, and an
    interrupted one loses at most the evaluation in progress.
    """

    def __init__(self, path: Path, task: str):
        self.path, self.task = Path(path), task
        self.cells: dict[CellKey, dict] = {}
        self._reload()

    def _reload(self) -> None:
        if not self.path.exists():
            return
        data = json.loads(self.path.read_text())
        if data.get("task") != self.task:
            raise ValueError(f"{self.path} holds results of task {data.get('task')!r}, not {self.task!r}")
        for cell in data["cells"]:
            self.cells[cell_key(cell)] = cell

    def __contains__(self, key: CellKey) -> bool:
        return key in self.cells

    def add(self, cell: dict) -> None:
        with exclusive_lock(self.path.with_name(self.path.name + ".lock")):
            self._reload()
            self.cells[cell_key(cell)] = cell
            self._write()

    def _write(self) -> None:
        cells = sorted(self.cells.values(), key=lambda c: tuple(str(v) for v in asdict(cell_key(c)).values()))
        fd, tmp = tempfile.mkstemp(dir=self.path.parent, prefix=f".{self.path.name}.")
        with os.fdopen(fd, "w") as f:
            json.dump({"task": self.task, "cells": cells}, f, indent=1)
            f.write("\n")
        os.replace(tmp, self.path)


#: The study's evaluation cap per task, in control steps (a task not named: its own cap, None).
#: Lift is capped at 200 (10 s at 20 Hz; the expert needs 62 on average) to save evaluation time;
#: it counts a slow success as a failure. Reports read the cells of this cap only.
STUDY_CAPS: dict[str, int | None] = {"Lift": 200}


def scene_task(task: str, scene: str) -> str:
    """The evaluation task of the study cells on ``task``'s initial layouts moved by the scene
    transform ``scene`` (a short name of ``run_results.SCENE_NAMES``: ``objects``, ``robot``)."""
    return f"{task}+scene_{scene}"


def task_files(items: list[str], flag: str) -> dict[str, Path]:
    """``{task: Path}`` of command-line items ``TASK=FILE`` (a task's cells read from another
    store: longer runs, or runs trained again on another machine).

    Raises:
        ValueError: an item that is not ``TASK=FILE``, or a task given twice; it names ``flag``.
    """
    files: dict[str, Path] = {}
    for item in items:
        task, sep, file = item.partition("=")
        if not sep or not task or not file:
            raise ValueError(f"{flag} takes TASK=FILE; got {item!r}")
        if task in files:
            raise ValueError(f"{flag}: task {task!r} is given twice")
        files[task] = Path(file)
    return files


def load_cells(path: Path, task: str, required: bool) -> list[dict]:
    """The cells of the store ``path`` (``run_results.py``'s JSON of ``task``); none if it is
    missing and not ``required``.

    Raises:
        SystemExit: a required store that is missing, or a store of another task; it names both.
    """
    if not path.exists():
        if required:
            raise SystemExit(f"{path}: no such cell store (given for {task})")
        return []
    store = json.loads(path.read_text())
    if store.get("task") != task:
        raise SystemExit(f"{path}: a cell store of task {store.get('task')!r}, not {task!r}")
    return store["cells"]


def with_cap(cells: list[dict], episode_length: int | None) -> list[dict]:
    """The cells evaluated with the episode cap ``episode_length`` (None: the task's own)."""
    return [c for c in cells if c.get("episode_length") == episode_length]


#: Cell fields that make two runs' training comparable (training steps and wall-clock excepted:
#: an equal step count and an equal time budget are both fair).
PROTOCOL = ("demos", "batch_size", "lr", "preset", "cameras", "image_size", "episode_length")


def protocol_of(cells: list[dict]) -> dict | None:
    """The :data:`PROTOCOL` fields that all ``cells`` share, or None if they differ."""
    protocols = [{k: c.get(k) for k in PROTOCOL} for c in cells]
    return protocols[0] if protocols and all(p == protocols[0] for p in protocols) else None


def protocol_mismatch(a: dict | None, b: dict | None, names: tuple[str, str] = ("a", "b")) -> str | None:
    """Why two :func:`protocol_of` results (of the runs ``names``) are not comparable, or None when
    they are equal."""
    mixed = [name for name, p in zip(names, (a, b), strict=True) if p is None]
    if mixed:
        return f"training protocols differ between the seeds of {' and '.join(mixed)}"
    differ = [k for k in PROTOCOL if a[k] != b[k]]
    return f"training protocols differ in {', '.join(differ)}" if differ else None


def mean_std(values: list[float]) -> tuple[float, float]:
    """Mean and population standard deviation (0 for one value)."""
    return statistics.fmean(values), statistics.pstdev(values) if len(values) > 1 else 0.0


def study_cells(
    cells: list[dict], study: str, eval_task: str, time_spacing: str = "checkpoint"
) -> list[dict]:
    """The cells of ``study`` evaluated on ``eval_task`` with ``time_spacing``."""
    return [
        c
        for c in cells
        if c["study"] == study and c["eval_task"] == eval_task and c["time_spacing"] == time_spacing
    ]


def summarise(cells: list[dict], study: str, eval_task: str, time_spacing: str = "checkpoint") -> list[dict]:
    """Per (setting, IS): success mean +- std over seeds at the last checkpoint and at the best
    evaluated step (highest mean over the seeds that have it), with the seeds counted, over
    :func:`study_cells`."""
    rows = []
    chosen = study_cells(cells, study, eval_task, time_spacing)
    caps = {c.get("episode_length") for c in chosen}
    if len(caps) > 1:
        raise ValueError(
            f"the {study} cells on {eval_task} have different episode caps {sorted(caps, key=str)} "
            "(None: the task's own): summarise one cap at a time (study.with_cap)"
        )
    groups: dict[tuple[str, int], list[dict]] = {}
    for c in chosen:
        groups.setdefault((c["setting"], c["inference_steps"]), []).append(c)
    for (setting, k), group in groups.items():
        by_step: dict[int, dict[int, float]] = {}
        for c in group:
            by_step.setdefault(c["step"], {})[c["seed"]] = c["pc_success"]
        last_step = max(by_step)
        best_step = max(by_step, key=lambda s: (statistics.fmean(by_step[s].values()), s))
        last, best = list(by_step[last_step].values()), list(by_step[best_step].values())
        at_last = [c for c in group if c["step"] == last_step]
        rows.append(
            {
                "setting": setting,
                "inference_steps": k,
                "last_step": last_step,
                "last": mean_std(last),
                "last_seeds": len(last),
                "best_step": best_step,
                "best": mean_std(best),
                "best_seeds": len(best),
                "episodes": sorted({c["n_episodes"] for c in group}),
                "protocol": protocol_of(at_last),
            }
        )
    return sorted(rows, key=lambda r: (r["setting"], r["inference_steps"]))


def format_summary(rows: list[dict], best: bool = True) -> str:
    """Markdown: one row per setting, one column per IS, ``mean +- std (n seeds)`` at the last
    checkpoint, and at the best evaluated step when ``best``."""
    settings = list(dict.fromkeys(r["setting"] for r in rows))
    steps = sorted({r["inference_steps"] for r in rows})
    cell = {(r["setting"], r["inference_steps"]): r for r in rows}

    def fmt(r, which):
        if r is None:
            return "-"
        m, s = r[which]
        return f"{m:.0f} +- {s:.0f} ({r[which + '_seeds']}; {r[which + '_step']})"

    head = [f"IS={k} last" for k in steps] + ([f"IS={k} best" for k in steps] if best else [])
    lines = ["| setting | " + " | ".join(head) + " |", "| --- |" + " ---: |" * len(head)]
    for s in settings:
        vals = [fmt(cell.get((s, k)), "last") for k in steps]
        if best:
            vals += [fmt(cell.get((s, k)), "best") for k in steps]
        lines.append(f"| {s} | " + " | ".join(vals) + " |")
    return "\n".join(lines)


def success_curve(
    cells: list[dict],
    study: str,
    setting: str,
    eval_task: str,
    inference_steps: int,
    same_seeds: bool = False,
):
    """``[(step, mean, std, n_seeds)]``: success against training steps (the convergence axis).
    ``same_seeds``: only the seeds evaluated at every step, so that the points differ by the
    step alone (empty when no seed has them all)."""
    by_step: dict[int, dict[int, float]] = {}
    for c in cells:
        if (c["study"], c["setting"], c["eval_task"], c["inference_steps"], c["time_spacing"]) == (
            study,
            setting,
            eval_task,
            inference_steps,
            "checkpoint",
        ):
            by_step.setdefault(c["step"], {})[c["seed"]] = c["pc_success"]
    if same_seeds and by_step:
        common = set.intersection(*(set(v) for v in by_step.values()))
        by_step = {s: {seed: v[seed] for seed in common} for s, v in by_step.items()} if common else {}
    return [(s, *mean_std(list(v.values())), len(v)) for s, v in sorted(by_step.items())]


#: Width (points of success) of the band that :func:`plateau_step` calls flat. A one-run cell
#: of 50 episodes at 80-95 % has a binomial standard error of 3-6 points, a 3-seed mean about
#: 1.7x less: 5 points is 1-3 standard errors, so a slow rise under 5 points goes unseen.
PLATEAU_POINTS = 5.0


def plateau_step(curve: list[tuple], tolerance: float = PLATEAU_POINTS) -> int | None:
    """The training step from which success stays in a band ``tolerance`` points wide up to the
    last checkpoint: the first evaluated step ``s`` such that the means from ``s`` to the end
    differ by at most ``tolerance`` (max - min), with at least two checkpoints in that tail.
    None when the last two checkpoints already differ by more (or there are fewer than two):
    then the run is not shown to have stopped changing. ``curve`` is :func:`success_curve`'s
    ``[(step, mean, ...)]``, sorted by step, from the same seeds at every step."""
    start = len(curve) - 1
    while start > 0:
        tail = [point[1] for point in curve[start - 1 :]]
        if max(tail) - min(tail) > tolerance:
            break
        start -= 1
    return curve[start][0] if start < len(curve) - 1 else None


def format_curves(cells: list[dict], study: str, eval_task: str) -> str:
    """Markdown: success against training steps (mean over the seeds evaluated at every step)
    per setting and IS, for the settings evaluated at more than one checkpoint, and the
    :func:`plateau_step` of each."""
    lines = []
    for row in summarise(cells, study, eval_task):
        curve = success_curve(
            cells, study, row["setting"], eval_task, row["inference_steps"], same_seeds=True
        )
        if len(curve) < 2:
            continue
        plateau = plateau_step(curve)
        points = ", ".join(f"{m:.0f} ({st})" for st, m, _, _ in curve)
        verdict = f"from {plateau}" if plateau is not None else "not reached"
        lines.append(
            f"| {row['setting']} | {row['inference_steps']} | {curve[0][3]} | {points} | {verdict} |"
        )
    if not lines:
        return ""
    head = [
        f"| setting | IS | seeds | success % (step) | flat within {PLATEAU_POINTS:g} points |",
        "| --- | ---: | ---: | --- | ---: |",
    ]
    return "\n".join(head + lines)


def plot_study(cells: list[dict], study: str, eval_task: str, path: Path, title: str) -> None:
    """PNG with two panels: success (mean +- std over seeds) per setting at the last checkpoint,
    one bar per IS; and success against training steps for every setting evaluated at more than
    one checkpoint."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = summarise(cells, study, eval_task)
    settings = list(dict.fromkeys(r["setting"] for r in rows))
    steps = sorted({r["inference_steps"] for r in rows})
    cell = {(r["setting"], r["inference_steps"]): r for r in rows}
    fig, (bars, curves) = plt.subplots(1, 2, figsize=(11, 3.8), dpi=110)
    width = 0.8 / max(len(steps), 1)
    for j, k in enumerate(steps):
        xs = [i + (j - (len(steps) - 1) / 2) * width for i, s in enumerate(settings) if (s, k) in cell]
        ms = [cell[s, k]["last"][0] for s in settings if (s, k) in cell]
        sd = [cell[s, k]["last"][1] for s in settings if (s, k) in cell]
        bars.bar(xs, ms, width, yerr=sd, capsize=2, label=f"IS={k}")
    bars.set_xticks(range(len(settings)), settings, rotation=35, ha="right", fontsize=8)
    bars.set(ylabel="success % (last checkpoint)", ylim=(0, 105), title=title)
    bars.legend(fontsize=8)
    for s in settings:
        for k in steps:
            curve = success_curve(cells, study, s, eval_task, k)
            if len(curve) > 1:
                x, m, sd, _ = zip(*curve, strict=True)
                curves.errorbar(x, m, yerr=sd, marker="o", capsize=2, label=f"{s}, IS={k}")
    curves.set(xlabel="training steps", ylabel="success %", ylim=(0, 105), title="success against steps")
    curves.grid(alpha=0.3)
    if curves.lines:
        curves.legend(fontsize=8)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
