"""``actionflow-collect``: scripted-expert demonstrations into a LeRobotDataset.

    actionflow-collect --task Lift --episodes 100 --root data/lift [--images] [--seed 0]
                       [--repo-id local/lift] [--cameras wrist,agentview] [--image-size 84]
                       [--image-format video|image] [--max-attempts K]
                       [--point-cloud] [--point-cloud-points 512] [--point-cloud-dtype float16]
                       [--point-cloud-cameras CAM,CAM] [--point-cloud-image-size 128]

Semantics:

- ``--episodes`` is the **target total** of successful episodes in the dataset. Only
  successful rollouts are saved; failures are counted and reported.
- Attempt ``i`` (0, 1, 2, ...) uses seed ``seed + i`` for the env reset and for the expert's
  random choices, so a dataset is reproducible from its metadata.
- Crash safety (:mod:`.staging`): ``--root`` is never written in place. Each kept episode is
  staged in ``<root>.collect-staging/`` when it ends; at the end of the run (also after a signal
  or an error) the staged episodes are appended to a copy of the dataset, which is loaded back,
  checked and renamed over ``--root``. ``kill -9`` at any instant costs at most the episode in
  progress.
- Re-running the same command **resumes**: it finishes or undoes a commit a crash interrupted,
  checks that the dataset at ``--root`` is whole (else exit 2 with what to do) and matches task,
  images, seed and features, takes the staged episodes, and continues from the next unused
  attempt index until the total reaches ``--episodes`` (nothing happens if it already does). A
  larger ``--episodes`` thus extends a dataset. Success is reported only after the result loads.
- Ctrl-C / SIGINT / SIGTERM: the episode in progress is discarded, the saved ones are merged,
  and the command exits with status 130; with nothing saved, no folder is created.
- ``meta/actionflow_collect.json`` records task, variant, expert class and version, base seed,
  the seeds kept and failed, attempts, successes and the success rate; it is rewritten after
  every run (the staged ``state.json`` after every attempt).
- ``--point-cloud`` adds ``observation.point_cloud`` ``(M, 3)`` (world/base frame, metres;
  :mod:`lerobot_actionflow.envs.point_cloud`), stored as float16 by default
  (:func:`~lerobot_actionflow.data.features.schema_features`); its settings are recorded under
  ``point_cloud`` in the metadata, and a resumed run must ask for the same.
- fps is the env's control frequency (:data:`~lerobot_actionflow.envs.tasks.CONTROL_FREQ`). Each
  frame holds the observation the expert saw and the action it took on it (``action[t]`` is the
  absolute EEF target sent at step ``t``).
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import datetime as _dt
import json
import signal
import sys
from pathlib import Path
from typing import Any

from lerobot_actionflow.data.staging import META_FILE, InconsistentDataset, Staging, check_dataset, read_json
from lerobot_actionflow.schema import DEFAULT_POINT_CLOUD_POINTS, POINT_CLOUD_DTYPES

__all__ = ["META_FILE", "collect", "main", "read_collect_meta"]

EXIT_INTERRUPTED = 130


def read_collect_meta(root: str | Path) -> dict[str, Any] | None:
    """The collection metadata of a dataset, or ``None`` if it has none."""
    return read_json(Path(root) / "meta" / META_FILE)


def _stamp(meta: dict[str, Any]) -> dict[str, Any]:
    meta["success_rate"] = meta["successes"] / meta["attempts"] if meta["attempts"] else None
    meta["updated"] = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
    return meta


class _StopFlag:
    """SIGINT/SIGTERM set a flag instead of raising, so that no write is cut in half; a second
    signal raises ``KeyboardInterrupt`` at once."""

    def __init__(self):
        self.stop = False
        self._old: dict[int, Any] = {}

    def _handler(self, signum, frame):
        if self.stop:
            raise KeyboardInterrupt
        self.stop = True

    def __enter__(self):
        for sig in (signal.SIGINT, signal.SIGTERM):
            with contextlib.suppress(ValueError):  # not the main thread
                self._old[sig] = signal.signal(sig, self._handler)
        return self

    def __exit__(self, *exc):
        for sig, old in self._old.items():
            signal.signal(sig, old)

    def __call__(self) -> bool:
        return self.stop


def _settings_differ(meta: dict[str, Any], spec, cams, seed: int, pc: dict | None) -> bool:
    return (
        meta["task"] != spec.name
        or meta["images"] != bool(cams)
        or meta["base_seed"] != seed
        or meta.get("point_cloud") != pc
    )


def _target_meta(root: Path) -> dict[str, Any] | None:
    return read_collect_meta(root) if (root / "meta" / "info.json").is_file() else None


def _check_target(
    root: Path, repo_id: str, spec, cams, seed: int, features: dict, pc: dict | None
) -> dict[str, Any] | None:
    """The collection metadata of the dataset at ``root`` after checking that it is whole and
    matches the request; ``None`` when there is no dataset yet.

    Raises:
        ValueError: ``root`` is no folder, holds something else, another collection, or an
            inconsistent dataset (with what to do about it).
    """
    if root.exists() and not root.is_dir():
        raise ValueError(f"--root {root} is a file, not a dataset folder: choose a folder")
    if not (root / "meta" / "info.json").is_file():
        if root.exists() and any(root.iterdir()):
            raise ValueError(f"{root} exists and is not a LeRobotDataset: refusing to write into it")
        return None
    meta = read_collect_meta(root)
    if meta is None:
        raise ValueError(f"{root} holds a dataset without {META_FILE}; not written by actionflow-collect")
    if _settings_differ(meta, spec, cams, seed, pc):
        raise ValueError(
            f"{root} holds a {meta['task']} dataset (images={meta['images']}, seed={meta['base_seed']}, "
            f"point_cloud={meta.get('point_cloud')}); asked for {spec.name} (images={bool(cams)}, "
            f"seed={seed}, point_cloud={pc}): use another --root"
        )
    try:
        check_dataset(root, repo_id, meta)
    except InconsistentDataset as e:
        raise ValueError(
            f"{e}. An interrupted run of an older actionflow-collect (which wrote in place) leaves such a "
            f"folder. Collection is deterministic per seed: move it aside (mv {root} {root}.broken) and "
            "run the same command again to recreate it."
        ) from None
    have = json.loads((root / "meta" / "info.json").read_text())["features"]
    have = {k: (v["dtype"], tuple(v["shape"])) for k, v in have.items() if k in features}
    want = {k: (v["dtype"], tuple(v["shape"])) for k, v in features.items()}
    if have != want:
        raise ValueError(f"{root}: existing features {have} differ from the requested {want}")
    return meta


def _run_meta(
    staging: Staging, target: dict[str, Any] | None, spec, cls, cams, seed: int, pc: dict | None
) -> dict[str, Any]:
    """The metadata this run continues from: the staged state (an earlier run's unmerged work),
    else the dataset's, else a fresh one; staged episodes it does not list yet are added."""
    from lerobot_actionflow.envs.tasks import CONTROL_FREQ

    state = staging.read_state()
    if state is not None and _settings_differ(state, spec, cams, seed, pc):
        raise ValueError(
            f"{staging.dir} holds an unfinished {state['task']} collection (images={state['images']}, "
            f"seed={state['base_seed']}, point_cloud={state.get('point_cloud')}): run that command again "
            f"to finish it, or delete {staging.dir}"
        )
    meta = state or copy.deepcopy(target)
    if meta is None:
        meta = {
            "task": spec.name, "variant": spec.variant, "expert": f"{cls.__module__}.{cls.__qualname__}",
            "expert_version": cls.version, "base_seed": seed, "images": bool(cams), "cameras": list(cams),
            "point_cloud": pc, "fps": CONTROL_FREQ, "next_attempt": 0, "attempts": 0, "successes": 0,
            "seeds_kept": [], "seeds_failed": [],
            "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        }  # fmt: skip
    for attempt in staging.staged():  # saved just before a crash, ahead of state.json
        if seed + attempt in meta["seeds_kept"]:
            continue
        if attempt >= meta["next_attempt"]:
            meta["attempts"] += attempt + 1 - meta["next_attempt"]
            meta["next_attempt"] = attempt + 1
        meta["successes"] += 1
        meta["seeds_kept"] = sorted([*meta["seeds_kept"], seed + attempt])
    return meta


def collect(
    task: str,
    episodes: int,
    root: str | Path,
    repo_id: str | None = None,
    seed: int = 0,
    images: bool = False,
    cameras: tuple[str, ...] = ("wrist", "agentview"),
    image_size: int = 84,
    image_format: str = "video",
    max_attempts: int | None = None,
    progress: bool = True,
    point_cloud: bool = False,
    point_cloud_points: int = DEFAULT_POINT_CLOUD_POINTS,
    point_cloud_cameras: tuple[str, ...] = (),
    point_cloud_image_size: int = 128,
    point_cloud_dtype: str = "float16",
) -> dict[str, Any]:
    """Collect successful expert episodes until the dataset at ``root`` holds ``episodes``.

    Returns the collection metadata (also in ``meta/actionflow_collect.json``), with
    ``interrupted`` set when a signal stopped the run, ``episodes`` the dataset's episode count
    and ``recovered`` the notes of :meth:`Staging.recover`. See the module docstring.
    """
    from lerobot_actionflow.data.features import default_repo_id, schema_features
    from lerobot_actionflow.envs.tasks import CONTROL_FREQ, get_task
    from lerobot_actionflow.experts import expert_class

    spec = get_task(task)
    cls = expert_class(spec.name)  # fails early for a task without an expert
    root = Path(root)
    repo_id = repo_id or default_repo_id(spec.name)
    cams = tuple(cameras) if images else ()
    pc = None
    if point_cloud:
        cams_pc = list(point_cloud_cameras or spec.point_cloud_cameras)  # recorded as resolved
        pc = {"num_points": int(point_cloud_points), "cameras": cams_pc,
              "image_size": int(point_cloud_image_size), "dtype": point_cloud_dtype}  # fmt: skip
        _pc_env_kwargs(pc)  # ValueError naming a bad setting, before any work
    features = schema_features(
        spec.num_tokens, cams, (image_size, image_size), image_format,
        pc["num_points"] if pc else None, point_cloud_dtype,
    )  # fmt: skip
    if episodes < 0:
        raise ValueError(f"--episodes must be >= 0, got {episodes}")
    if root.exists() and not root.is_dir():
        raise ValueError(f"--root {root} is a file, not a dataset folder: choose a folder")
    staging = Staging(root, repo_id)
    # The stop flag covers everything from here: a signal sets it, and the loop then stops at the
    # next episode boundary; the staged episodes are merged below.
    with _StopFlag() as flag, staging.locked():
        notes = staging.recover(_target_meta)
        target = _check_target(root, repo_id, spec, cams, seed, features, pc)
        meta = _run_meta(staging, target, spec, cls, cams, seed, pc)
        meta["expert_version"] = cls.version  # the version of the last run (a resumed set may mix)
        meta["interrupted"] = False
        if len(meta["seeds_kept"]) < episodes and not flag():
            try:
                _collect_episodes(staging, meta, spec, cls, cams, image_size, features, image_format,
                                  episodes, max_attempts, progress, flag)  # fmt: skip
            except BaseException:
                meta["interrupted"] = True
                with contextlib.suppress(Exception):  # else the next run merges the staged episodes
                    staging.commit(_stamp(meta), target, features, CONTROL_FREQ, image_format == "video")
                raise
        meta["interrupted"] = flag()
        if staging.commit(_stamp(meta), target, features, CONTROL_FREQ, image_format == "video"):
            meta["episodes"] = check_dataset(root, repo_id, meta)
        else:
            meta["episodes"] = 0
    meta["recovered"] = notes
    return meta


def _collect_episodes(staging, meta, spec, cls, cams, image_size, features, image_format, episodes,
                      max_attempts, progress, flag) -> None:  # fmt: skip
    """Run attempts until ``meta`` lists ``episodes`` kept seeds (or the attempts or a signal
    stop it), staging each success and replacing ``state.json`` after each attempt."""
    import gymnasium as gym
    from tqdm import tqdm

    import lerobot_actionflow.envs  # noqa: F401  (gym ids)
    from lerobot_actionflow.data.features import frame_from_obs
    from lerobot_actionflow.experts.rollout import run_episode

    pc = meta.get("point_cloud")
    env = gym.make(
        spec.gym_id, cameras=cams, image_height=image_size, image_width=image_size, render_mode=None,
        point_cloud=_pc_env_kwargs(pc) if pc else False,
    )  # fmt: skip
    pc_dtype = pc["dtype"] if pc else "float32"
    try:
        expert = cls(env.unwrapped)
        saved, new_attempts = len(meta["seeds_kept"]), 0
        staging.write_state(_stamp(meta))
        bar = tqdm(
            total=episodes, initial=min(saved, episodes), desc=spec.name, unit="ep", disable=not progress
        )
        while saved < episodes and not flag():
            if max_attempts is not None and new_attempts >= max_attempts:
                break
            attempt = meta["next_attempt"]
            ep = run_episode(env, expert, meta["base_seed"] + attempt, stop=flag)
            if ep.interrupted:
                break
            if ep.success:
                steps = zip(ep.observations, ep.actions)
                frames = [frame_from_obs(o, a, spec.description, pc_dtype) for o, a in steps]
                staging.write_episode(attempt, frames)
                meta["successes"] += 1
                meta["seeds_kept"].append(meta["base_seed"] + attempt)
                saved += 1
                bar.update(1)
            else:
                meta["seeds_failed"].append(meta["base_seed"] + attempt)
                bar.set_postfix(failed=len(meta["seeds_failed"]))
            meta["next_attempt"] += 1
            meta["attempts"] += 1
            new_attempts += 1
            staging.write_state(_stamp(meta))
        bar.close()
    finally:
        env.close()


def _pc_env_kwargs(pc: dict) -> dict:
    """The env's ``point_cloud`` kwargs from the recorded settings (validated)."""
    from lerobot_actionflow.envs.point_cloud_config import PointCloudConfig

    if pc["dtype"] not in POINT_CLOUD_DTYPES:
        raise ValueError(f"--point-cloud-dtype must be one of {POINT_CLOUD_DTYPES}, got {pc['dtype']!r}")
    kw = {"num_points": pc["num_points"], "cameras": tuple(pc["cameras"]),
          "image_height": pc["image_size"], "image_width": pc["image_size"]}  # fmt: skip
    PointCloudConfig(**kw)
    return kw


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="actionflow-collect",
        description="Record scripted-expert demonstrations of a pose-token task into a LeRobotDataset. "
        "--episodes is the target total: re-running on an existing --root resumes/extends it.",
    )
    p.add_argument("--task", required=True, help="task name, e.g. Lift, StackThree_D1")
    p.add_argument("--episodes", type=int, required=True, help="target total of successful episodes")
    p.add_argument("--root", required=True, help="dataset folder")
    p.add_argument("--repo-id", default=None, help="dataset repo id (default local/<task>)")
    p.add_argument("--seed", type=int, default=0, help="base seed: attempt i uses seed + i")
    p.add_argument("--images", action="store_true", help="also record camera images")
    p.add_argument("--cameras", default="wrist,agentview", help="comma-separated cameras for --images")
    p.add_argument("--image-size", type=int, default=84, help="square image size in pixels")
    p.add_argument("--image-format", choices=("video", "image"), default="video")
    p.add_argument("--max-attempts", type=int, default=None, help="stop after this many new attempts")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--point-cloud", action="store_true", help="also record observation.point_cloud (M, 3)")
    p.add_argument("--point-cloud-points", type=int, default=DEFAULT_POINT_CLOUD_POINTS, help="M points")
    p.add_argument(
        "--point-cloud-cameras", default="", help="depth cameras fused (>= 2; default: the task's)"
    )
    p.add_argument("--point-cloud-image-size", type=int, default=128, help="depth image size per camera")
    p.add_argument("--point-cloud-dtype", choices=POINT_CLOUD_DTYPES, default="float16", help="dataset dtype")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        meta = collect(
            args.task,
            args.episodes,
            args.root,
            repo_id=args.repo_id,
            seed=args.seed,
            images=args.images,
            cameras=tuple(c.strip() for c in args.cameras.split(",") if c.strip()),
            image_size=args.image_size,
            image_format=args.image_format,
            max_attempts=args.max_attempts,
            progress=not args.no_progress,
            point_cloud=args.point_cloud,
            point_cloud_points=args.point_cloud_points,
            point_cloud_cameras=tuple(c.strip() for c in args.point_cloud_cameras.split(",") if c.strip()),
            point_cloud_image_size=args.point_cloud_image_size,
            point_cloud_dtype=args.point_cloud_dtype,
        )
    except KeyboardInterrupt:
        print("actionflow-collect: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except (ValueError, KeyError) as e:
        print(f"actionflow-collect: error: {e}", file=sys.stderr)
        return 2
    for note in meta["recovered"]:
        print(f"actionflow-collect: after an earlier crash: {note}", file=sys.stderr)
    rate = meta["successes"] / meta["attempts"] if meta["attempts"] else None
    print(
        f"{meta['task']}: {meta['episodes']} episodes in {args.root}; attempts {meta['attempts']}, "
        f"failures {len(meta['seeds_failed'])}, expert success rate "
        f"{'n/a' if rate is None else f'{rate:.3f}'}" + (" (interrupted)" if meta["interrupted"] else "")
    )
    return EXIT_INTERRUPTED if meta["interrupted"] else 0


if __name__ == "__main__":
    sys.exit(main())
