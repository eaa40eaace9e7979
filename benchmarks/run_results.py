"""The results table of issue #7 for one task: three policies, one dataset, IS sweep, generalisation.

Stages (each skipped when its output exists, so an interrupted run continues):

1. ``actionflow-collect``: ``--episodes`` expert demonstrations of ``--task`` (seed ``--seed``);
2. ``actionflow-train`` (``lerobot-train``'s loop, the dataset served from RAM, no loader
   workers) of ``actionflow``, ``euclidean_flow`` (the diffusion UNet backbone, so that it
   differs from Diffusion Policy only by the flow) and LeRobot's ``diffusion`` on that dataset,
   the same steps, batch, history, horizon and executed actions for all three;
3. ``lerobot_actionflow.evaluation.sweep``: success against inference steps IS on the training
   distribution, the same evaluation seeds for every cell;
4. the same sweep at one IS (``--generalisation-is``) on other evaluation envs: the task's D1/D2
   variants (mimicgen tasks) and scene-transformed layouts (``--env.scene_*``), with and without
   the robot moved along.

Writes ``<output>/results.json`` and prints markdown tables. ``--preset cpu`` is the small
configuration measured on a 2-core CPU (see benchmarks/RESULTS.md); ``--preset paper`` keeps
each policy's default size for a GPU.

    python benchmarks/run_results.py --task Lift --output outputs/results/Lift

**Studies with several training seeds** (issue #17; :mod:`study` holds the settings, the cell
store and the summaries): ``--study ablation`` (ActionFlow's defaults) or ``--study comparison``
(actionflow, euclidean_flow, diffusion) trains every chosen setting with every seed in
``--seeds``, saving a checkpoint every ``--eval-every`` steps, and evaluates the checkpoints
(all of them, or the last with ``--eval-checkpoints last``) on the task and ``--variants``, at
every IS of ``--inference-steps`` and every grid of ``--time-spacings``, and with ``--scenes
objects,robot`` on the task's scene-transformed layouts (cells of evaluation task
``<task>+scene_objects`` / ``<task>+scene_robot``). Each evaluation is one
cell of ``--results`` (default ``benchmarks/results/<task>.json``), written as it finishes; a
rerun skips the cells and the training runs that exist. Prints mean +- std over seeds, and for
runs evaluated at several checkpoints the success against steps with the step from which it
stays in a narrow band (:func:`study.plateau_step`).
``--report`` prints the tables (and writes ``--plot``) from the stored cells without training or
evaluating anything. ``--cameras wrist,agentview --image-size 80`` records a second dataset with
those cameras and trains and evaluates every setting on it (setting names get
``[cameras@size]``).

    python benchmarks/run_results.py --task Lift --study ablation --settings default,squash_off \
        --seeds 0,1,2 --steps 3000 --eval-every 1000 --inference-steps 2,10 --output /work/study/Lift
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

from study import (
    BASELINES,
    COMMON,
    CPU_SIZE,
    PAPER_SIZE,
    STUDIES,
    CellKey,
    ResultStore,
    format_curves,
    format_summary,
    plot_study,
    scene_task,
    summarise,
    with_cap,
)
from train_runs import run_logged, train_run

from lerobot_actionflow.data.staging import exclusive_lock
from lerobot_actionflow.evaluation.provenance import (
    DIGEST_KEY,
    MACHINE_KEY,
    check_same_weights,
    machine_description,
    weights_digest,
)

POLICIES = ("actionflow", "euclidean_flow", "diffusion")
REPO = Path(__file__).resolve().parents[1]
#: With cameras, Diffusion Policy's ResNet18 starts from scratch like ActionFlow's (nothing is
#: downloaded), with group norm as in its paper, and a random 72x72 crop of the 80x80 images (the
#: 90 % ratio of its paper's 76 of 84).
IMAGE_OVERRIDES = {
    "diffusion": [
        "--policy.pretrained_backbone_weights=null",
        "--policy.use_group_norm=true",
        "--policy.crop_shape=[72,72]",
    ]
}
# Scene transforms of the generalisation table: name -> env overrides.
SCENES = {
    "shift+yaw, objects only": [
        "--env.scene_yaw=[-0.785,0.785]",
        "--env.scene_x=[-0.1,0.1]",
        "--env.scene_y=[-0.1,0.1]",
    ],
    "shift+yaw, robot moved too": [
        "--env.scene_yaw=[-0.785,0.785]",
        "--env.scene_x=[-0.1,0.1]",
        "--env.scene_y=[-0.1,0.1]",
        "--env.scene_move_robot=true",
    ],
}
#: Short names of the scene transforms for ``--scenes`` (study mode); a study's cells of a scene
#: have the evaluation task ``<task>+scene_<short name>``.
SCENE_NAMES = dict(zip(("objects", "robot"), SCENES, strict=True))


def _bin(name: str) -> str:
    return str(Path(sys.executable).with_name(name))


def _sweep(
    checkpoints: list[Path], task: str, steps: list[int], extra: list[str], out: Path, args, env
) -> list:
    result = out / "sweep_results.json"
    if not result.exists():
        run_logged(
            [sys.executable, "-m", "lerobot_actionflow.evaluation.sweep",
             f"--checkpoints=[{','.join(str(c) for c in checkpoints)}]",
             "--env.type=actionflow", f"--env.task={task}", *_camera_env(args),
             # the protocol of every stored cell: unguided chunks unless a setting's flags say so
             "--guide_to_previous_chunk=false", *extra,
             *([f"--env.episode_length={args.episode_length}"] if args.episode_length else []),
             f"--inference_steps=[{','.join(map(str, steps))}]",
             f"--eval.n_episodes={args.eval_episodes}", f"--eval.batch_size={args.eval_batch_size}",
             f"--eval.use_async_envs={str(args.eval_async).lower()}",
             f"--seed={args.eval_seed}", "--device=cpu", f"--output_dir={out}"],
            env, out / "sweep.log",
        )  # fmt: skip
    return json.loads(result.read_text())


def _camera_env(args) -> list[str]:
    """The evaluation env's camera flags matching the recorded dataset (none without cameras)."""
    if not getattr(args, "cameras", ""):
        return []
    size = args.image_size
    return [
        f"--env.cameras={args.cameras}",
        f"--env.observation_height={size}",
        f"--env.observation_width={size}",
    ]


def _train(run: Path, policy: str, overrides: list[str], seed: int, save_freq: int, data, repo_id, args, env):
    """Train one run into ``run`` to its final checkpoint (:func:`train_runs.train_run`: resumed
    after an interruption); returns this call's wall time in seconds, or None when it was there."""
    sizes = CPU_SIZE if args.preset == "cpu" else PAPER_SIZE
    resumed = (run / "checkpoints" / "last").exists()
    wall = train_run(
        run,
        [f"--policy.type={policy}", f"--policy.device={args.device}",
         "--policy.push_to_hub=false", f"--dataset.repo_id={repo_id}", f"--dataset.root={data}",
         f"--output_dir={run}", f"--steps={args.steps}", f"--save_freq={save_freq}",
         f"--batch_size={args.batch_size}", "--num_workers=0", "--log_freq=100",
         "--wandb.enable=false", f"--seed={seed}", f"--policy.optimizer_lr={args.lr}",
         "--policy.scheduler_warmup_steps=100", *COMMON, *sizes[policy], *overrides],
        args.steps, run.parent / f"train_{run.name}.log", env,
    )  # fmt: skip
    if wall is not None:  # a resumed run's wall time is unknown (null): only its last part ran here
        (run / "train_wall_s.json").write_text(json.dumps({"train_wall_s": None if resumed else wall}))
    return wall


def _checkpoints(run: Path) -> dict[int, Path]:
    """``{step: pretrained_model dir}`` of a training run's numbered checkpoints."""
    found = {}
    for d in (run / "checkpoints").iterdir():
        if d.name.isdigit() and (d / "pretrained_model").exists():
            found[int(d.name)] = d / "pretrained_model"
    return found


def _folder(setting: str, camera_suffix: str) -> str:
    """A setting's folder name: ``default``, or ``default_wrist_agentview_80`` with cameras
    (sampling-only settings train nothing: their runs are those of the setting they name)."""
    return (setting + camera_suffix).replace("[", "_").replace("@", "_").replace("]", "").replace(",", "_")


def record_once(data: Path, record: Callable[[], object]) -> bool:
    """Call ``record()`` to write the LeRobotDataset ``data`` unless it exists (its
    ``meta/info.json``); whether it was called. Studies of one task may run side by side on one
    ``--output``: a blocking lock beside ``data`` makes the first record and the others wait,
    then find the dataset, instead of starting a second collection into the same folder."""
    with exclusive_lock(data.parent / f".{data.name}.lock"):
        if (data / "meta" / "info.json").exists():
            return False
        record()
        return True


def run_study(args, env: dict, data: Path, repo_id: str, collect) -> int:
    """Train and evaluate the settings of ``args.study`` (see the module docstring); ``collect()``
    records the demonstrations the first time a run has to be trained."""
    settings = STUDIES[args.study]
    names = [n for n in args.settings.split(",") if n] or list(settings)
    unknown = sorted(set(names) - set(settings))
    if unknown:
        raise SystemExit(f"unknown {args.study} settings {unknown}; known: {sorted(settings)}")
    seeds = [int(s) for s in args.seeds.split(",")]
    steps = [int(k) for k in args.inference_steps.split(",")]
    spacings = [s for s in args.time_spacings.split(",") if s]
    scenes = [n for n in args.scenes.split(",") if n]
    if unknown := sorted(set(scenes) - set(SCENE_NAMES)):
        raise SystemExit(f"unknown --scenes {unknown}; known: {sorted(SCENE_NAMES)}")
    # evaluation task of the cells -> (env task, env overrides)
    targets = {t: (t, []) for t in [args.task, *[v for v in args.variants.split(",") if v]]}
    targets |= {scene_task(args.task, n): (args.task, SCENES[SCENE_NAMES[n]]) for n in scenes}
    eval_tasks = list(targets)
    store = ResultStore(args.results or REPO / "benchmarks" / "results" / f"{args.task}.json", args.task)
    machine = machine_description(args.device)
    out = args.output.resolve()
    for base in [] if args.report else names:
        setting = settings[base]
        trained = settings[setting.trained_as] if setting.trained_as else setting
        camera_suffix = f"[{args.cameras}@{args.image_size}]" if args.cameras else ""
        name = base + camera_suffix
        for seed in seeds:
            run = out / args.study / _folder(setting.trained_as or base, camera_suffix) / f"seed{seed}"
            overrides = [*BASELINES[args.study].get(setting.policy, ()), *trained.overrides]
            if args.cameras:
                overrides += IMAGE_OVERRIDES.get(setting.policy, [])
            saved = sorted({*range(args.eval_every, args.steps + 1, args.eval_every), args.steps})
            chosen = saved if args.eval_checkpoints == "all" else [args.steps]

            def missing(step, eval_task, spacing, name=name, seed=seed, policy=setting.policy):
                if spacing != "checkpoint" and policy == "diffusion":
                    return []  # the time grid is a flow option
                return [
                    k for k in steps
                    if CellKey(args.study, name, seed, step, eval_task, k, spacing,
                               args.eval_episodes, args.eval_seed, args.episode_length) not in store
                ]  # fmt: skip

            grid = [(st, task, sp) for st in chosen for task in eval_tasks for sp in spacings]
            if not any(missing(*cell) for cell in grid):
                continue  # every cell of this run is stored: no need for its checkpoints
            collect()
            _train(run, setting.policy, overrides, seed, args.eval_every, data, repo_id, args, env)
            info = run / "train_wall_s.json"
            train_wall = json.loads(info.read_text())["train_wall_s"] if info.exists() else None
            ckpts = _checkpoints(run)
            digests = {}
            for step in chosen:
                digests[step] = weights_digest(ckpts[step])
                this_run = (args.study, setting.trained_as or base, seed, step, args.cameras)
                same_checkpoint = [
                    c for c in store.cells.values()
                    if (c["study"], c.get("trained_as", c["setting"]), c["seed"], c["step"],
                        c.get("cameras", "")) == this_run
                ]  # fmt: skip
                check_same_weights(
                    same_checkpoint, digests[step], str(ckpts[step]),
                    "Evaluate it into another --results file, or remove those cells.",
                )  # fmt: skip
            for step, eval_task, spacing in grid:
                todo = missing(step, eval_task, spacing)
                if not todo:
                    continue
                where = (
                    out / "eval" / args.study / _folder(base, camera_suffix) / f"seed{seed}" / f"step{step}"
                )
                cap = "" if args.episode_length is None else f"_cap{args.episode_length}"
                where = where / eval_task / (spacing + cap)  # a folder per evaluation protocol
                if where.exists():
                    import shutil

                    shutil.rmtree(where)  # an evaluation that did not finish
                extra = [
                    *([] if spacing == "checkpoint" else [f"--time_spacing={spacing}"]),
                    *setting.sampling,
                ]
                env_task, scene = targets[eval_task]
                for row in _sweep([ckpts[step]], env_task, todo, [*extra, *scene], where, args, env):
                    store.add(
                        {
                            "study": args.study, "setting": name, "policy": setting.policy,
                            "overrides": list(trained.overrides), "sampling": list(setting.sampling),
                            "baseline": list(BASELINES[args.study].get(setting.policy, ())),
                            "trained_as": setting.trained_as or base, "seed": seed, "step": step,
                            "eval_task": eval_task, "inference_steps": row["inference_steps"],
                            "time_spacing": spacing, "sampler": row["sampler"],
                            "n_episodes": row["n_episodes"], "eval_seed": args.eval_seed,
                            "pc_success": row["pc_success"], "eval_s": row["eval_s"],
                            "train_steps": args.steps, "batch_size": args.batch_size, "lr": args.lr,
                            "preset": args.preset, "train_wall_s": train_wall,
                            "demos": args.episodes, "cameras": args.cameras,
                            "image_size": args.image_size if args.cameras else None,
                            "episode_length": args.episode_length,
                            "date": time.strftime("%Y-%m-%d", time.gmtime()),
                            DIGEST_KEY: digests[step], MACHINE_KEY: machine,
                        }
                    )  # fmt: skip
    cells = with_cap(list(store.cells.values()), args.episode_length)
    other_caps = {c.get("episode_length") for c in store.cells.values()} - {args.episode_length}
    if other_caps:
        print(f"(cells of other episode caps not shown: {sorted(other_caps, key=str)}; --episode-length)")
    for eval_task in eval_tasks:
        for spacing in spacings:
            rows = summarise(cells, args.study, eval_task, spacing)
            if rows:
                print(f"\n{args.study} on {eval_task} (time grid: {spacing}); mean +- std over seeds "
                      "(seeds; checkpoint step)")  # fmt: skip
                print(format_summary(rows))
                curves = format_curves(cells, args.study, eval_task) if spacing == "checkpoint" else ""
                if curves:
                    print(f"\nsuccess against training steps on {eval_task}\n{curves}")
        if args.plot is not None and "checkpoint" in spacings:
            path = args.plot.with_name(f"{args.plot.stem}_{eval_task}{args.plot.suffix}")
            plot_study(cells, args.study, eval_task, path, f"{args.study}: {eval_task}")
            print(f"plot: {path}")
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--task", default="Lift")
    ap.add_argument("--output", type=Path, required=True)
    ap.add_argument("--episodes", type=int, default=50, help="expert demonstrations")
    ap.add_argument("--seed", type=int, default=0, help="collection and training seed")
    ap.add_argument("--steps", type=int, default=2000, help="training steps, every policy")
    ap.add_argument("--batch-size", type=int, default=32)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--device", default="cpu", help="training device")
    ap.add_argument("--preset", choices=("cpu", "paper"), default="cpu")
    ap.add_argument("--policies", default=",".join(POLICIES))
    ap.add_argument("--inference-steps", default="2,5,10,20,100")
    ap.add_argument("--generalisation-is", type=int, default=10)
    ap.add_argument(
        "--variants", default="", help="other task names to evaluate on, e.g. Threading_D1,Threading_D2"
    )
    ap.add_argument("--no-scenes", action="store_true", help="skip the scene-transform evaluation")
    ap.add_argument("--eval-episodes", type=int, default=50)
    ap.add_argument("--eval-batch-size", type=int, default=10)
    ap.add_argument("--eval-seed", type=int, default=1000)
    ap.add_argument(
        "--eval-async",
        action=argparse.BooleanOptionalAction,
        default=False,
        help="one process per evaluation env (about 1 GB each) instead of all envs in one process",
    )
    ap.add_argument(
        "--episode-length", type=int, default=None, help="evaluation episode cap (default: the task's)"
    )
    ap.add_argument("--plot", type=Path, default=None, help="write the IS sweep as a PNG here")
    study = ap.add_argument_group("studies with several seeds (issue #17)")
    study.add_argument("--study", choices=sorted(STUDIES), default=None)
    study.add_argument("--settings", default="", help="comma-separated setting names (default: all)")
    study.add_argument("--seeds", default="0,1,2", help="training seeds")
    study.add_argument("--eval-every", type=int, default=1000, help="checkpoint interval (steps)")
    study.add_argument("--eval-checkpoints", choices=("all", "last"), default="all")
    study.add_argument(
        "--time-spacings", default="checkpoint", help="time grids to evaluate: checkpoint,uniform,exponential"
    )
    study.add_argument(
        "--results", type=Path, default=None, help="cell store (default benchmarks/results/<task>.json)"
    )
    study.add_argument(
        "--scenes",
        default="",
        help="also evaluate on the scene-transformed layouts (yaw +-45 deg, shift +-0.1 m): "
        "objects (the objects moved), robot (the objects and the robot moved together)",
    )
    study.add_argument(
        "--cameras", default="", help="record, train and evaluate with these cameras (e.g. wrist,agentview)"
    )
    study.add_argument("--image-size", type=int, default=80, help="square camera images (pixels)")
    study.add_argument(
        "--report", action="store_true", help="only print the tables (and --plot) of the cells already stored"
    )
    args = ap.parse_args(argv)

    out = args.output.resolve()
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled", "OMP_NUM_THREADS": "1"}
    env.setdefault("MUJOCO_GL", "egl")
    data, repo_id = out / "data", f"local/{args.task.lower()}_results"
    images = []
    if args.cameras:
        tag = f"{args.cameras.replace(',', '_')}_{args.image_size}"
        data, repo_id = out / f"data_{tag}", f"{repo_id}_{tag}"
        images = ["--images", "--cameras", args.cameras, "--image-size", str(args.image_size)]
    timings: dict[str, float] = {}

    def collect() -> None:
        """Record the demonstrations unless they are there."""
        start = time.perf_counter()
        recorded = record_once(
            data,
            lambda: run_logged(
                [_bin("actionflow-collect"), "--task", args.task, "--episodes", str(args.episodes),
                 "--root", str(data), "--repo-id", repo_id, "--seed", str(args.seed), *images],
                env, out / "logs" / f"collect{'_' + tag if images else ''}.log",
            ),
        )  # fmt: skip
        if recorded:
            timings["collect_s"] = time.perf_counter() - start

    if args.study is not None:
        return run_study(args, env, data, repo_id, collect)
    collect()

    checkpoints = []
    for policy in args.policies.split(","):
        run = out / "train" / policy
        wall = _train(run, policy, [], args.seed, args.steps, data, repo_id, args, env)
        if wall is not None:
            timings[f"train_{policy}_s"] = wall
        checkpoints.append(run / "checkpoints" / "last" / "pretrained_model")

    steps = [int(s) for s in args.inference_steps.split(",")]
    results = {"args": {k: str(v) for k, v in vars(args).items()}, "timings": timings}
    results["is_sweep"] = _sweep(checkpoints, args.task, steps, [], out / "sweep", args, env)
    gen = {}
    for variant in [v for v in args.variants.split(",") if v]:
        gen[variant] = _sweep(
            checkpoints, variant, [args.generalisation_is], [], out / "gen" / variant, args, env
        )
    if not args.no_scenes:
        for i, (name, extra) in enumerate(SCENES.items()):
            gen[name] = _sweep(
                checkpoints, args.task, [args.generalisation_is], extra, out / "gen" / f"scene{i}", args, env
            )
    results["generalisation"] = gen
    (out / "results.json").write_text(json.dumps(results, indent=2))
    print(format_tables(results))
    if args.plot is not None:
        plot_is_sweep(results, args.plot, title=f"{args.task}: success vs inference steps")
        print(f"plot: {args.plot}")
    return 0


def plot_is_sweep(results: dict, path: Path, title: str) -> None:
    """PNG of success rate against IS (log axis), one line per policy."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = results["is_sweep"]
    fig, ax = plt.subplots(figsize=(5, 3.4), dpi=120)
    for policy in dict.fromkeys(r["policy"] for r in rows):
        pts = sorted((r["inference_steps"], r["pc_success"]) for r in rows if r["policy"] == policy)
        ax.plot(*zip(*pts, strict=True), marker="o", label=policy)
    ax.set_xscale("log")
    ax.set_xticks(sorted({r["inference_steps"] for r in rows}))
    ax.get_xaxis().set_major_formatter(matplotlib.ticker.ScalarFormatter())
    ax.set(xlabel="inference steps IS", ylabel="success %", ylim=(-3, 103), title=title)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)


def format_tables(results: dict) -> str:
    """Markdown: success % per policy x IS, then per policy x evaluation env."""
    rows = results["is_sweep"]
    policies = list(dict.fromkeys(r["policy"] for r in rows))
    steps = sorted({r["inference_steps"] for r in rows})
    cell = {(r["policy"], r["inference_steps"]): r for r in rows}
    lines = ["| policy | " + " | ".join(f"IS={s}" for s in steps) + " |", "| --- |" + " ---: |" * len(steps)]
    for p in policies:
        lines.append(f"| {p} | " + " | ".join(f"{cell[p, s]['pc_success']:.0f}" for s in steps) + " |")
    gen = results.get("generalisation", {})
    if gen:
        names = list(gen)
        gcell = {(name, r["policy"]): r for name in names for r in gen[name]}
        lines += ["", "| policy | " + " | ".join(names) + " |", "| --- |" + " ---: |" * len(names)]
        for p in policies:
            lines.append(f"| {p} | " + " | ".join(f"{gcell[n, p]['pc_success']:.0f}" for n in names) + " |")
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
