"""An in-memory frame source with the items of a ``LeRobotDataset``, gathered a batch at a time.

``LeRobotDataset.__getitem__`` answers one item with one Arrow query per key and per frame of its
``delta_timestamps`` window (about 5 ms per item for 2 observation steps and 16 actions on two
CPU cores). :class:`InMemoryLeRobotDataset` wraps an opened ``LeRobotDataset``, copies its
non-camera columns once into contiguous tensors, and answers a batch of ``B`` rows with index
arithmetic and one gather per key:

* row ``r`` has absolute frame index ``i = index[r]`` in episode ``e = episode_index[r]``, whose
  frames are the absolute indices ``[lo, hi)`` = ``[dataset_from_index[e], dataset_to_index[e])``;
* a key with delta indices ``d`` (``round(delta_timestamp * fps)``, shape ``(T,)``) reads frames
  ``q = clamp(i + d, lo, hi - 1)`` (shape ``(B, T)``), flagged ``<key>_is_pad = (i + d < lo) |
  (i + d >= hi)``; absolute indices become rows through the dataset's own mapping when it was
  opened on a subset of episodes;
* a key without deltas reads row ``r``; ``task`` is the name of ``task_index[r]``.

Items are exactly ``LeRobotDataset``'s for the same arguments: the same keys in the same order,
values, dtypes (float columns float32, integer columns int64, bool bool; shape-``(1,)`` features
as 0-d tensors), pad masks, ``index``, ``episode_index``, ``frame_index``, ``timestamp`` and the
``task`` string. Camera features follow :mod:`lerobot_actionflow.data.camera_frames` (LeRobot's
per-item decoding, or a uint8 cache with ``image_cache=True``); image transforms are applied per
item and camera, in LeRobot's order.

torch's ``DataLoader`` calls :meth:`InMemoryLeRobotDataset.__getitems__` with a whole batch of
indices when a dataset has it, then its ``collate_fn`` on the returned list of items: the default
collate (``lerobot-train``'s) stacks them back. Not supported: depth features, language columns
and string columns (the constructor says which feature); streaming datasets are a different
class and are not wrapped.

The settings are read from the wrapped dataset and its reader (LeRobot 0.6.1, pinned: the delta
indices, ``return_uint8``, the video backend and per-item decoder); the item-by-item comparison
with ``LeRobotDataset`` in the tests is what guards them against a LeRobot change.
"""

from __future__ import annotations

import logging
import time
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import torch

from lerobot_actionflow.data.camera_frames import CameraFrames, gather

logger = logging.getLogger(__name__)

#: Arrow primitive kinds and the torch dtype ``torch.tensor(<python value>)`` gives them, which
#: is what LeRobot's ``hf_transform_to_torch`` returns.
_FLOAT, _INT, _BOOL = torch.get_default_dtype(), torch.int64, torch.bool


def _torch_dtype(arrow_type: pa.DataType, key: str) -> torch.dtype:
    if pa.types.is_floating(arrow_type):
        return _FLOAT
    if pa.types.is_integer(arrow_type):
        return _INT
    if pa.types.is_boolean(arrow_type):
        return _BOOL
    raise ValueError(
        f"feature {key!r} has Arrow type {arrow_type}; the in-memory source holds numeric and "
        "boolean features only (use LeRobotDataset for this dataset)"
    )


def column_tensor(column: pa.ChunkedArray, key: str) -> torch.Tensor:
    """An Arrow column of ``F`` rows as one contiguous tensor ``(F, *shape)``: scalars ``(F,)``,
    fixed- or variable-size lists of equal length, and ``datasets``' ArrayND extension types
    (lists of lists), with the dtype LeRobot's transform gives (:func:`_torch_dtype`)."""
    arr = column.combine_chunks()
    num_rows, shape = len(arr), []
    while True:
        if arr.null_count:
            raise ValueError(f"feature {key!r} has {arr.null_count} missing values")
        if isinstance(arr.type, pa.ExtensionType):
            arr = arr.storage
        elif pa.types.is_fixed_size_list(arr.type) or pa.types.is_list(arr.type):
            lengths = pc.list_value_length(arr).to_numpy(zero_copy_only=False)
            if len(lengths) and (lengths != lengths[0]).any():
                raise ValueError(f"feature {key!r} has rows of different lengths {sorted(set(lengths))[:5]}")
            shape.append(int(lengths[0]) if len(lengths) else 0)
            arr = arr.flatten()
        else:
            break
    values = np.asarray(arr.to_numpy(zero_copy_only=False))
    tensor = torch.from_numpy(np.array(values, copy=True)).to(_torch_dtype(arr.type, key))
    return tensor.reshape(num_rows, *shape)


class InMemoryLeRobotDataset(torch.utils.data.Dataset):
    """The items of ``dataset`` (an opened ``LeRobotDataset``) from tensors in RAM.

    Args:
        dataset: a ``LeRobotDataset`` opened with the ``delta_timestamps``, ``episodes``,
            ``image_transforms``, ``return_uint8``, video backend and tolerance wanted: they are
            read from it, and its metadata (``meta``: stats, episodes, tasks, features) is shared.
        image_cache: decode every camera frame once into uint8 RAM instead of per item.

    ``dataset[i]``, ``dataset[a:b]`` and ``dataset.__getitems__(indices)`` give what the wrapped
    dataset gives for the same indices; :meth:`get_batch` gives the collated batch directly. The
    read-side attributes ``lerobot-train`` uses (``meta``, ``num_frames``, ``num_episodes``,
    ``episodes``, ``absolute_to_relative_idx``, ``features``, ``fps``, ``hf_dataset``) are the
    wrapped dataset's; ``source`` is the wrapped dataset.
    """

    def __init__(self, dataset, image_cache: bool = False):
        from lerobot.datasets.lerobot_dataset import LeRobotDataset

        if not isinstance(dataset, LeRobotDataset):
            raise TypeError(f"expected a LeRobotDataset, got {type(dataset).__name__}")
        meta = dataset.meta
        if meta.depth_keys:
            raise ValueError(f"depth features {meta.depth_keys} are not supported by the in-memory source")
        if meta.has_language_columns:
            raise ValueError("language columns are not supported by the in-memory source")
        start = time.perf_counter()
        self.source = dataset
        hf = dataset.hf_dataset
        table = hf.data
        if len(hf) != table.num_rows:
            raise ValueError("the dataset's rows are a selection of its Arrow table; open it unselected")
        cameras = set(meta.camera_keys)
        self._columns: dict[str, torch.Tensor] = {
            key: column_tensor(table.column(key), key) for key in table.column_names if key not in cameras
        }
        for key in ("index", "episode_index", "frame_index", "timestamp", "task_index"):
            if key not in self._columns:
                raise ValueError(f"the dataset has no {key!r} column")
        #: Item key order: LeRobot's (videos, then the Arrow columns, then the pad masks, then task).
        self._row_keys = list(table.column_names)
        self._index = self._columns["index"]
        self._episode = self._columns["episode_index"]
        self._timestamp = self._columns["timestamp"]
        episodes = meta.episodes.data
        self._ep_from = column_tensor(episodes.column("dataset_from_index"), "dataset_from_index")
        self._ep_to = column_tensor(episodes.column("dataset_to_index"), "dataset_to_index")
        self._tasks: list[str] = [str(name) for name in meta.tasks.index]
        # Absolute frame index -> row, as LeRobot's reader maps it (identity when all episodes
        # are loaded, its own dict when a subset is).
        self._rel_of_abs: torch.Tensor | None = None
        mapping = dataset.absolute_to_relative_idx
        if mapping is not None:
            rel = torch.full((int(self._index.max()) + 1,), -1, dtype=torch.int64)
            rel[torch.tensor(list(mapping), dtype=torch.int64)] = torch.tensor(list(mapping.values()))
            self._rel_of_abs = rel
        delta = dataset.reader.delta_indices or {}
        self._deltas = {key: torch.tensor(d, dtype=torch.int64) for key, d in delta.items()}
        for key in self._deltas:
            if key not in self._columns and key not in cameras:
                raise ValueError(f"delta_timestamps names {key!r}, which is not a feature of the dataset")
        rows_of_episode = self._rows_of_episode()
        self._cameras = CameraFrames(dataset, rows_of_episode, image_cache) if cameras else None
        self._image_transforms = dataset.image_transforms
        self._camera_keys = list(meta.camera_keys)
        self.load_s = time.perf_counter() - start
        logger.info(
            "in-memory frame source: %d frames, %d episodes, %.1f MB, loaded in %.2f s",
            len(self),
            self.num_episodes,
            self.nbytes / 2**20,
            self.load_s,
        )

    # -- LeRobotDataset's read-side interface ----------------------------------------------
    @property
    def meta(self):
        return self.source.meta

    @property
    def num_frames(self) -> int:
        return len(self._index)

    @property
    def num_episodes(self) -> int:
        return self.source.num_episodes

    @property
    def episodes(self) -> list[int] | None:
        return self.source.episodes

    @property
    def absolute_to_relative_idx(self) -> dict[int, int] | None:
        return self.source.absolute_to_relative_idx

    @property
    def features(self) -> dict[str, dict]:
        return self.source.features

    @property
    def fps(self) -> int:
        return self.source.fps

    @property
    def hf_dataset(self):
        return self.source.hf_dataset

    @property
    def nbytes(self) -> int:
        """Bytes held in RAM by this source (columns and cached camera frames)."""
        columns = sum(t.numel() * t.element_size() for t in self._columns.values())
        return columns + (self._cameras.nbytes if self._cameras is not None else 0)

    def __len__(self) -> int:
        return self.num_frames

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(repo_id={self.source.repo_id!r}, frames={len(self)}, "
            f"episodes={self.num_episodes}, {self.nbytes / 2**20:.1f} MB)"
        )

    # -- items -----------------------------------------------------------------------------
    def __getitem__(self, idx: int | slice) -> dict[str, Any] | list[dict[str, Any]]:
        if isinstance(idx, slice):
            return self.__getitems__(list(range(*idx.indices(len(self)))))
        return self.__getitems__([idx])[0]

    def __getitems__(self, indices: list[int]) -> list[dict[str, Any]]:
        """The items of rows ``indices``, as ``[dataset[i] for i in indices]``."""
        if len(indices) == 0:
            return []
        batch = self.get_batch(indices)
        keys = list(batch)
        parts = [value if isinstance(value, list) else value.unbind(0) for value in batch.values()]
        items = [dict(zip(keys, values, strict=True)) for values in zip(*parts, strict=True)]
        if self._image_transforms is not None:
            for item in items:
                for cam in self._camera_keys:
                    item[cam] = self._image_transforms(item[cam])
        return items

    def get_batch(self, indices) -> dict[str, torch.Tensor | list[str]]:
        """The collated batch of rows ``indices`` (``B`` of them): every key of an item stacked
        along a new first dimension, ``task`` a list of ``B`` strings. Image transforms are not
        applied here (they are per item: use ``__getitems__``)."""
        rows = self._rows(indices)  # (B,)
        abs_idx, ep = gather(self._index, rows), gather(self._episode, rows)
        lo, hi = gather(self._ep_from, ep).unsqueeze(1), gather(self._ep_to, ep).unsqueeze(1)  # (B, 1)
        query_rows: dict[str, torch.Tensor] = {}
        pads: dict[str, torch.Tensor] = {}
        for key, d in self._deltas.items():
            q = abs_idx.unsqueeze(1) + d  # (B, T) absolute frame indices
            pads[f"{key}_is_pad"] = (q < lo) | (q >= hi)
            q = torch.minimum(torch.maximum(q, lo), hi - 1)
            query_rows[key] = q if self._rel_of_abs is None else gather(self._rel_of_abs, q)

        batch: dict[str, Any] = {}
        if self._cameras is not None:
            batch.update(self._videos(rows, ep, query_rows))
        for key in self._row_keys:
            key_rows = query_rows.get(key, rows)
            if key in self._columns:
                batch[key] = gather(self._columns[key], key_rows)
            else:  # an image feature (PNG in the rows)
                batch[key] = self._cameras.image_rows(key, key_rows)
        batch.update(pads)
        batch["task"] = [self._tasks[t] for t in gather(self._columns["task_index"], rows).tolist()]
        return batch

    def _rows(self, indices) -> torch.Tensor:
        rows = torch.as_tensor(indices, dtype=torch.int64).reshape(-1)
        n = len(self)
        if rows.numel() and (rows.min() < -n or rows.max() >= n):
            bad = rows[(rows < -n) | (rows >= n)][0].item()
            raise IndexError(f"index {bad} is out of range for a dataset of {n} frames")
        return torch.where(rows < 0, rows + n, rows)

    def _videos(self, rows, ep, query_rows) -> dict[str, torch.Tensor]:
        cams = self._cameras
        out: dict[str, torch.Tensor] = {}
        for key in cams.video_keys:
            if key in cams.cached:
                out[key] = cams.cached_video_rows(key, query_rows.get(key, rows))
        uncached = [k for k in cams.video_keys if k not in cams.cached]
        if uncached:
            per_item = []
            for b in range(len(rows)):
                stamps = {
                    key: self._timestamp[query_rows[key][b]].tolist()
                    if key in query_rows
                    else [self._timestamp[rows[b]].item()]
                    for key in uncached
                }
                per_item.append(cams.decode_videos(int(ep[b]), stamps))
            for key in uncached:
                out[key] = torch.stack([frames[key] for frames in per_item])
        return {key: out[key] for key in cams.video_keys}

    def _rows_of_episode(self) -> dict[int, np.ndarray]:
        episodes = self._episode.numpy()
        order = np.argsort(episodes, kind="stable")
        values, starts = np.unique(episodes[order], return_index=True)
        groups = np.split(order, starts[1:])
        return {int(e): rows for e, rows in zip(values, groups, strict=True)}
