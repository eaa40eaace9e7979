"""Crash-safe writes of ``actionflow-collect``: a staging folder next to the dataset.

The dataset folder ``ROOT`` is never written in place. A run works in ``ROOT.collect-staging/``:

- ``lock``: held (``flock``) by the running collection; a second one on the same ``ROOT`` is
  refused. The kernel drops the lock when the process dies, ``kill -9`` included.
- ``episodes/attempt_<a>.npz``: the frames of kept attempt ``a`` (seed ``base_seed + a``) as
  :meth:`Staging.write_episode` stores them, written as ``episodes/.tmp-<a>.npz``, flushed to
  disk and renamed in when complete; a file without the ``.tmp-`` prefix is always whole.
- ``state.json``: the collection metadata the dataset will carry once the staged episodes are
  merged (attempts, kept and failed seeds, ...), replaced atomically after every attempt.
- ``merge.tmp/``: the merge in progress: a copy of ``ROOT`` (or a new dataset) to which LeRobot's
  writer appends the staged episodes in attempt order, plus ``meta/actionflow_collect.json``.
  (LeRobot 0.6.1's ``aggregate_datasets`` cannot merge datasets with the 2-D
  ``observation.poses`` feature: pyarrow rejects the column it reads back.)
- ``merged/``: the merge after it has been loaded back with ``LeRobotDataset`` and checked
  (:func:`check_dataset`) and flushed to disk.
- ``previous/``: the old ``ROOT`` while the new one is moved in.

Commit (:meth:`Staging.commit`): ``merge.tmp -> merged`` (the decision), ``ROOT -> previous``,
``merged -> ROOT``, then ``previous`` and the staged files are removed. Each step is one
``rename``, atomic on a POSIX file system, so after a crash at any instant the folders say how
far it got, and :meth:`Staging.recover` finishes the commit (``merged/`` exists) or puts
``previous/`` back; ``ROOT`` is at all times either the old dataset, the new one, or (only
between the two renames, with ``previous/`` and ``merged/`` both present) absent. Staged episodes
whose seed the dataset already lists, and a ``state.json`` not ahead of the dataset's own
metadata, were committed before the crash and are dropped.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

META_FILE = "actionflow_collect.json"
STAGING_SUFFIX = ".collect-staging"

_rename = os.rename  # one name for every rename of the commit protocol


def staging_dir(root: str | Path) -> Path:
    """The staging folder of the dataset folder ``root``: ``<root>.collect-staging``."""
    root = Path(root)
    return root.with_name(root.name + STAGING_SUFFIX)


def read_json(path: Path) -> dict[str, Any] | None:
    return json.loads(path.read_text()) if path.exists() else None


@contextlib.contextmanager
def exclusive_lock(path: Path, busy: str | None = None) -> Iterator[None]:
    """Hold an exclusive ``flock`` on the file ``path`` (created with its folder). If another
    process (or another open of the file) holds it: with ``busy``, raise ``ValueError(busy)`` at
    once; without, wait for it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX if busy is None else fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise ValueError(busy) from None
        yield


def write_json_atomic(path: Path, data: dict[str, Any]) -> None:
    """Write ``data`` to ``path`` via a flushed temporary file and ``os.replace``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w") as f:
        f.write(json.dumps(data, indent=2))
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    fsync_dir(path.parent)


def fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def fsync_tree(path: Path) -> None:
    """Flush every file and folder under ``path`` to disk (a rename after it survives a power cut
    with its content)."""
    for dirpath, _, files in os.walk(path):
        for name in files:
            with open(os.path.join(dirpath, name), "rb") as f:
                os.fsync(f.fileno())
        fsync_dir(Path(dirpath))


class InconsistentDataset(ValueError):
    """A dataset folder whose files disagree (e.g. left by a crash of an older collector)."""


def check_dataset(root: Path, repo_id: str, meta: dict[str, Any] | None) -> int:
    """Load ``root`` with ``LeRobotDataset`` and check that it is whole; returns its episodes.

    Checks: ``info.json``, ``meta/episodes`` and the data agree on the episode count and frame
    count, episode indices are ``0..E-1``, the frame index is ``0..F-1`` and each episode's
    frames are contiguous, the last frame reads, and (with ``meta``) the collection metadata
    lists one kept seed per episode.

    Raises:
        InconsistentDataset: naming the first disagreement.
    """
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    try:
        ds = LeRobotDataset(repo_id, root=root)
        n_ep, n_fr = int(ds.meta.total_episodes), int(ds.meta.total_frames)
        eps = ds.meta.episodes
        ep_idx = np.asarray(eps["episode_index"], dtype=np.int64)
        lengths = np.asarray(eps["length"], dtype=np.int64)
        index = np.asarray(ds.hf_dataset["index"], dtype=np.int64)
        frame_ep = np.asarray(ds.hf_dataset["episode_index"], dtype=np.int64)
        if len(ds):
            ds[len(ds) - 1]
    except Exception as e:  # any load failure is an inconsistency of the folder
        raise InconsistentDataset(f"{root} does not load as a LeRobotDataset: {type(e).__name__}: {e}") from e
    problems = []
    if len(ep_idx) != n_ep or not np.array_equal(ep_idx, np.arange(n_ep)):
        problems.append(f"info.json has {n_ep} episodes, meta/episodes lists {ep_idx.tolist()}")
    if int(lengths.sum()) != n_fr or len(index) != n_fr:
        problems.append(f"info.json has {n_fr} frames, meta/episodes {lengths.sum()}, data {len(index)}")
    elif not np.array_equal(index, np.arange(n_fr)) or not np.array_equal(
        frame_ep, np.repeat(np.arange(len(lengths)), lengths)
    ):
        problems.append("the frame or episode index of the data is not contiguous")
    if meta is not None and len(meta.get("seeds_kept", [])) != n_ep:
        problems.append(f"{META_FILE} lists {len(meta.get('seeds_kept', []))} kept seeds for {n_ep} episodes")
    if problems:
        raise InconsistentDataset(f"{root} is inconsistent: " + "; ".join(problems))
    return n_ep


class Staging:
    """The staging folder of one dataset folder ``root`` (module docstring)."""

    def __init__(self, root: str | Path, repo_id: str):
        self.root = Path(root)
        self.repo_id = repo_id
        self.dir = staging_dir(self.root)
        self.episodes = self.dir / "episodes"
        self.state_path = self.dir / "state.json"
        self.merge_tmp = self.dir / "merge.tmp"
        self.merged = self.dir / "merged"
        self.previous = self.dir / "previous"

    # ------------------------------------------------------------------ lock
    @contextlib.contextmanager
    def locked(self) -> Iterator[Staging]:
        """Hold the staging lock; removes the staging folder on exit if nothing is staged."""
        busy = f"another actionflow-collect is writing {self.root} (lock in {self.dir})"
        with exclusive_lock(self.dir / "lock", busy):
            try:
                yield self
            finally:
                if not self.pending():
                    shutil.rmtree(self.dir, ignore_errors=True)

    def pending(self) -> bool:
        """Whether anything (state, episodes, a commit) is staged."""
        return any(p.exists() for p in (self.state_path, self.merged, self.previous)) or bool(self.staged())

    # ------------------------------------------------------------------ state and episodes
    def read_state(self) -> dict[str, Any] | None:
        return read_json(self.state_path)

    def write_state(self, meta: dict[str, Any]) -> None:
        write_json_atomic(self.state_path, meta)

    def staged(self) -> dict[int, Path]:
        """Whole staged episodes by attempt index."""
        if not self.episodes.is_dir():
            return {}
        out = {}
        for p in self.episodes.iterdir():
            if p.name.startswith("attempt_") and p.suffix == ".npz":
                out[int(p.stem.removeprefix("attempt_"))] = p
        return dict(sorted(out.items()))

    def write_episode(self, attempt: int, frames: list[dict[str, Any]]) -> Path:
        """Save the ``add_frame`` dicts of one episode as ``episodes/attempt_<attempt>.npz``: each
        key's values stacked along a leading time axis ``(T, ...)``, written to a temporary file,
        flushed and renamed in."""
        self.episodes.mkdir(parents=True, exist_ok=True)
        final = self.episodes / f"attempt_{attempt:06d}.npz"
        tmp = self.episodes / f".tmp-{attempt:06d}.npz"
        arrays = {k: np.stack([np.asarray(f[k]) for f in frames]) for k in frames[0]}
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)
            fh.flush()
            os.fsync(fh.fileno())
        _rename(tmp, final)
        fsync_dir(self.episodes)
        return final

    @staticmethod
    def read_episode(path: Path) -> list[dict[str, Any]]:
        """The ``add_frame`` dicts saved by :meth:`write_episode` (``task`` as ``str``)."""
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        t_len = len(next(iter(arrays.values())))
        return [{k: (str(v[t]) if k == "task" else v[t]) for k, v in arrays.items()} for t in range(t_len)]

    def clear(self) -> None:
        """Remove the staged episodes and state (after a commit, or when they were committed)."""
        shutil.rmtree(self.episodes, ignore_errors=True)
        self.state_path.unlink(missing_ok=True)

    # ------------------------------------------------------------------ commit and recovery
    def commit(
        self,
        meta: dict[str, Any],
        target_meta: dict[str, Any] | None,
        features: dict,
        fps: int,
        use_videos: bool,
    ) -> bool:
        """Merge the staged episodes into ``root`` with ``meta`` as its collection metadata.

        ``target_meta`` is the metadata ``root`` holds now (``None`` when it does not exist);
        ``features``, ``fps`` and ``use_videos`` are those of ``LeRobotDataset.create`` for a new
        dataset. The merge copies ``root`` to ``merge.tmp`` (or creates it there), appends the
        staged episodes in attempt order with ``LeRobotDataset.resume`` / ``add_frame`` /
        ``save_episode`` (images are encoded once, here), finalises, checks and swaps it in.
        With no new episode only the metadata file of an existing ``root`` is replaced. Returns
        whether ``root`` exists afterwards.
        """
        from lerobot.datasets.lerobot_dataset import LeRobotDataset

        kept = set(target_meta["seeds_kept"]) if target_meta else set()
        new = [p for a, p in self.staged().items() if meta["base_seed"] + a not in kept]
        if not new:
            if target_meta is not None and self.root.is_dir():
                write_json_atomic(self.root / "meta" / META_FILE, meta)
            self.clear()
            return self.root.is_dir()
        shutil.rmtree(self.merge_tmp, ignore_errors=True)
        if target_meta is not None:
            shutil.copytree(self.root, self.merge_tmp)
            ds = LeRobotDataset.resume(self.repo_id, root=self.merge_tmp)
        else:
            ds = LeRobotDataset.create(
                repo_id=self.repo_id, fps=fps, features=features, root=self.merge_tmp, use_videos=use_videos
            )
        try:
            for path in new:
                for frame in self.read_episode(path):
                    ds.add_frame(frame)
                ds.save_episode()
        finally:
            ds.finalize()
        (self.merge_tmp / "meta" / META_FILE).write_text(json.dumps(meta, indent=2))
        check_dataset(self.merge_tmp, self.repo_id, meta)
        fsync_tree(self.merge_tmp)
        _rename(self.merge_tmp, self.merged)
        fsync_dir(self.dir)
        self._swap()
        return True

    def _swap(self) -> None:
        """``root -> previous``, ``merged -> root``, then drop ``previous`` and the staged files."""
        if self.root.exists():
            if self.previous.exists():
                raise InconsistentDataset(
                    f"{self.root}, {self.merged} and {self.previous} all exist: keep the dataset you want "
                    f"as {self.root} and remove {self.dir}"
                )
            _rename(self.root, self.previous)
            fsync_dir(self.dir)
        _rename(self.merged, self.root)
        fsync_dir(self.root.parent)
        shutil.rmtree(self.previous, ignore_errors=True)
        self.clear()

    def recover(self, target_meta_of) -> list[str]:
        """Finish or undo a commit a crash interrupted and drop what a crash left half-written.

        ``target_meta_of(root)`` reads the collection metadata of the dataset at ``root`` (or
        ``None``). Returns notes on what was done, for the user.
        """
        notes = []
        if self.merge_tmp.exists():
            shutil.rmtree(self.merge_tmp)
            notes.append("dropped an unfinished merge")
        if self.episodes.is_dir():
            for p in self.episodes.iterdir():
                if p.name.startswith(".tmp-"):
                    p.unlink()
                    notes.append(f"dropped the unfinished episode file of attempt {int(p.stem[5:])}")
        if self.merged.exists():
            self._swap()
            notes.append(f"finished moving the merged dataset into {self.root}")
        elif self.previous.exists():
            if self.root.exists():
                shutil.rmtree(self.previous)
            else:
                _rename(self.previous, self.root)
                notes.append(f"restored {self.root} from {self.previous}")
        state, target = self.read_state(), target_meta_of(self.root)
        if state is not None and target is not None and state["next_attempt"] <= target["next_attempt"]:
            self.clear()  # committed before the crash, which hit the clean-up
        return notes
