"""``actionflow-collect``: scripted-expert demonstrations into a LeRobotDataset.

    actionflow-collect --task Lift --episodes 100 --root data/lift [--images] [--seed 0]
                       [--repo-id local/lift] [--cameras wrist,agentview] [--image-size 84]
                       [--image-format video|image] [--max-attempts K]

Semantics:

- ``--episodes`` is the **target total** of successful episodes in the dataset. Only
  successful rollouts are saved; failures are counted and reported.
- Attempt ``i`` (0, 1, 2, ...) uses seed ``seed + i`` for the env reset and for the expert's
  random choices, so a dataset is reproducible from its metadata.
- Re-running the same command on an existing dataset **resumes** it: it reopens the dataset
  (``LeRobotDataset.resume``), checks that task and features match, and continues from the
  next unused attempt index until the total reaches ``--episodes`` (nothing happens if it
  already does). A larger ``--episodes`` thus extends a dataset.
- Ctrl-C / SIGINT / SIGTERM: the episode in progress is discarded, the episodes already saved
  are finalised (a loadable dataset), and the command exits with status 130. If the run had
  created the dataset and saved nothing, the folder is removed. The same happens on an error
  (which is then re-raised).
- ``meta/actionflow_collect.json`` records task, variant, expert class and version, base seed,
  the seeds kept and failed, attempts, successes and the success rate; it is rewritten after
  every saved episode.
- fps is the env's control frequency (:data:`~lerobot_actionflow.envs.tasks.CONTROL_FREQ`). Each
  frame holds the observation the expert saw and the action it took on it (``action[t]`` is the
  absolute EEF target sent at step ``t``).
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as _dt
import json
import os
import shutil
import signal
import sys
from pathlib import Path
from typing import Any

META_FILE = "actionflow_collect.json"
EXIT_INTERRUPTED = 130


def read_collect_meta(root: str | Path) -> dict[str, Any] | None:
    """The collection metadata of a dataset, or ``None`` if it has none."""
    path = Path(root) / "meta" / META_FILE
    return json.loads(path.read_text()) if path.exists() else None


def _write_meta(root: Path, meta: dict[str, Any]) -> None:
    meta["success_rate"] = meta["successes"] / meta["attempts"] if meta["attempts"] else None
    meta["updated"] = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
    path = root / "meta" / META_FILE
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(meta, indent=2))
    os.replace(tmp, path)


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


def _open_dataset(root: Path, repo_id: str, spec, cls, features: dict, cams, seed: int, image_format: str):
    """Resume the dataset at ``root`` (checking it matches) or create it.

    Returns ``(dataset, meta, created, episodes already saved)``.
    """
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from lerobot_actionflow.envs.tasks import CONTROL_FREQ

    if (root / "meta" / "info.json").exists():
        meta = read_collect_meta(root)
        if meta is None:
            raise ValueError(f"{root} holds a dataset without {META_FILE}; not written by actionflow-collect")
        if meta["task"] != spec.name or meta["images"] != bool(cams) or meta["base_seed"] != seed:
            raise ValueError(
                f"{root} holds a {meta['task']} dataset (images={meta['images']}, seed={meta['base_seed']}); "
                f"asked for {spec.name} (images={bool(cams)}, seed={seed}): use another --root"
            )
        ds = LeRobotDataset.resume(repo_id, root=root)
        have = {k: (v["dtype"], tuple(v["shape"])) for k, v in ds.meta.features.items() if k in features}
        want = {k: (v["dtype"], tuple(v["shape"])) for k, v in features.items()}
        if have != want:
            ds.finalize()
            raise ValueError(f"{root}: existing features {have} differ from the requested {want}")
        return ds, meta, False, int(ds.meta.total_episodes)
    if root.exists() and any(root.iterdir()):
        raise ValueError(f"{root} exists and is not a LeRobotDataset: refusing to write into it")
    if root.exists():
        root.rmdir()
    ds = LeRobotDataset.create(
        repo_id=repo_id, fps=CONTROL_FREQ, features=features, root=root, use_videos=image_format == "video"
    )
    meta = {
        "task": spec.name,
        "variant": spec.variant,
        "expert": f"{cls.__module__}.{cls.__qualname__}",
        "expert_version": cls.version,
        "base_seed": seed,
        "images": bool(cams),
        "cameras": list(cams),
        "fps": CONTROL_FREQ,
        "next_attempt": 0,
        "attempts": 0,
        "successes": 0,
        "seeds_kept": [],
        "seeds_failed": [],
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
    }
    return ds, meta, True, 0


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
) -> dict[str, Any]:
    """Collect successful expert episodes until the dataset at ``root`` holds ``episodes``.

    Returns the collection metadata (also in ``meta/actionflow_collect.json``), with
    ``interrupted`` set when a signal stopped the run. See the module docstring.
    """
    import gymnasium as gym
    from tqdm import tqdm

    import lerobot_actionflow.envs  # noqa: F401  (gym ids)
    from lerobot_actionflow.data.features import default_repo_id, frame_from_obs, schema_features
    from lerobot_actionflow.envs.tasks import get_task
    from lerobot_actionflow.experts import expert_class
    from lerobot_actionflow.experts.rollout import run_episode

    spec = get_task(task)
    cls = expert_class(spec.name)  # fails early for a task without an expert
    root = Path(root)
    repo_id = repo_id or default_repo_id(spec.name)
    cams = tuple(cameras) if images else ()
    features = schema_features(spec.num_tokens, cams, (image_size, image_size), image_format)
    if episodes < 0:
        raise ValueError(f"--episodes must be >= 0, got {episodes}")

    env = gym.make(
        spec.gym_id, cameras=cams, image_height=image_size, image_width=image_size, render_mode=None
    )
    expert = cls(env.unwrapped)
    created, saved, ds, meta = False, 0, None, None
    # The stop flag covers everything from here: a signal while the dataset is being opened or
    # created is seen by the loop, which then saves nothing and cleans up below.
    with _StopFlag() as flag:
        try:
            ds, meta, created, saved = _open_dataset(
                root, repo_id, spec, cls, features, cams, seed, image_format
            )
            meta["expert_version"] = cls.version  # the version of the last run (a resumed set may mix)
            meta["interrupted"] = False
            bar = tqdm(
                total=episodes, initial=min(saved, episodes), desc=spec.name, unit="ep", disable=not progress
            )
            new_attempts = 0
            while saved < episodes and not flag():
                if max_attempts is not None and new_attempts >= max_attempts:
                    break
                s = seed + meta["next_attempt"]
                ep = run_episode(env, expert, s, stop=flag)
                if ep.interrupted:
                    break
                meta["next_attempt"] += 1
                meta["attempts"] += 1
                new_attempts += 1
                if not ep.success:
                    meta["seeds_failed"].append(s)
                    _write_meta(root, meta)
                    bar.set_postfix(failed=len(meta["seeds_failed"]))
                    continue
                for obs, action in zip(ep.observations, ep.actions):
                    ds.add_frame(frame_from_obs(obs, action, spec.description))
                ds.save_episode()
                saved += 1
                meta["successes"] += 1
                meta["seeds_kept"].append(s)
                _write_meta(root, meta)
                bar.update(1)
            bar.close()
            meta["interrupted"] = flag()
        except BaseException:
            if meta is not None:
                meta["interrupted"] = True
            raise
        finally:
            env.close()
            if ds is not None:
                with contextlib.suppress(Exception):
                    if ds.has_pending_frames():
                        ds.clear_episode_buffer()
                ds.finalize()
                if created and saved == 0:
                    shutil.rmtree(root, ignore_errors=True)
                    meta["removed"] = True
                else:
                    _write_meta(root, meta)
    meta["episodes"] = saved
    return meta


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
        )
    except KeyboardInterrupt:
        print("actionflow-collect: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except (ValueError, KeyError) as e:
        print(f"actionflow-collect: error: {e}", file=sys.stderr)
        return 2
    rate = meta["successes"] / meta["attempts"] if meta["attempts"] else None
    print(
        f"{meta['task']}: {meta['episodes']} episodes in {args.root}; attempts {meta['attempts']}, "
        f"failures {len(meta['seeds_failed'])}, expert success rate "
        f"{'n/a' if rate is None else f'{rate:.3f}'}" + (" (interrupted)" if meta["interrupted"] else "")
    )
    return EXIT_INTERRUPTED if meta["interrupted"] else 0


if __name__ == "__main__":
    sys.exit(main())
