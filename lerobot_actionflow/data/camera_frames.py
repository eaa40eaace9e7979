"""Camera frames of a LeRobotDataset for :class:`~lerobot_actionflow.data.in_memory.InMemoryLeRobotDataset`.

A camera feature is stored either as a video (``dtype: "video"``, one MP4 per chunk of episodes,
decoded by LeRobot) or as images (``dtype: "image"``, PNG bytes in the parquet rows). Two ways to
serve the frames of a batch:

* **decoded per item** (default, LeRobot's own path): videos through the dataset reader's
  decoder at the query timestamps, images from the Arrow rows through LeRobot's transform;
* **decoded once** (``image_cache=True``): every frame of every camera is decoded at load into
  one uint8 tensor ``(F, C, H, W)`` per camera, ``F`` the dataset's frames, and a batch is a
  gather of rows. Memory: ``F * C * H * W`` bytes per camera, e.g. 19.2 kB per frame at 80x80
  RGB, 35 MB for 1,845 frames, 7.7 GB for 400,000.

Either way a frame has the value and dtype LeRobot returns: videos uint8 ``(C, H, W)`` when the
dataset was opened with ``return_uint8=True`` (as ``lerobot-train`` does), else float32 in
``[0, 1]`` computed as ``(x / 255.0).type(torch.float32)`` like LeRobot's decoders; image
features float32 in ``[0, 1]`` (``ToTensor``: ``x.float().div(255)``).
"""

from __future__ import annotations

import io
import logging
import time
from collections.abc import Sequence

import numpy as np
import torch

logger = logging.getLogger(__name__)


def gather(values: torch.Tensor, rows: torch.Tensor) -> torch.Tensor:
    """``values[rows]`` for ``values`` ``(F, *shape)`` and integer ``rows`` of any shape ``S``:
    ``(*S, *shape)``. One ``index_select`` on the flattened rows, which stays on the calling thread
    for batch-sized gathers (advanced indexing with a 2-D index hands them to the intra-op thread
    pool: milliseconds of waiting on a busy machine)."""
    return values.index_select(0, rows.reshape(-1)).reshape(*rows.shape, *values.shape[1:])


def uint8_to_float(frames: torch.Tensor, kind: str) -> torch.Tensor:
    """uint8 frames -> float32 in [0, 1], with the exact arithmetic of LeRobot's path for
    ``kind`` (``"video"``: the decoders' ``(x / 255.0).type(float32)``; ``"image"``:
    torchvision's ``ToTensor``, ``x.to(float32).div(255)``)."""
    if kind == "video":
        return (frames / 255.0).type(torch.float32)
    return frames.to(dtype=torch.get_default_dtype()).div(255)


def decode_video_cache(dataset, key: str, rows_of_episode: dict[int, np.ndarray]) -> torch.Tensor:
    """Every frame of video feature ``key`` as uint8 ``(F, C, H, W)``, row ``r`` the frame of
    dataset row ``r``.

    ``rows_of_episode`` maps each loaded episode to its rows (in frame order). The frames of one
    episode are decoded in one call of LeRobot's ``decode_video_frames`` at the rows' own
    timestamps (shifted by the episode's ``from_timestamp`` in its video file), which is what
    LeRobot's reader asks the decoder for when an item needs that frame.
    """
    from lerobot.datasets.video_utils import decode_video_frames

    reader, meta = dataset.reader, dataset.meta
    timestamps = dataset.hf_dataset.data.column("timestamp").to_numpy()
    cache: torch.Tensor | None = None
    for ep_idx, rows in rows_of_episode.items():
        ep = meta.episodes[ep_idx]
        start = ep[f"videos/{key}/from_timestamp"]
        query = [start + ts for ts in torch.from_numpy(timestamps[rows]).tolist()]
        frames = decode_video_frames(
            dataset.root / meta.get_video_file_path(ep_idx, key),
            query,
            dataset.tolerance_s,
            reader._video_backend,
            return_uint8=True,
        )
        if frames.dtype != torch.uint8 or frames.ndim != 4:
            raise ValueError(
                f"video feature {key!r}: the decoder returned {tuple(frames.shape)} {frames.dtype}, "
                "expected uint8 (T, C, H, W); only RGB videos can be cached"
            )
        if cache is None:
            cache = torch.empty((len(timestamps), *frames.shape[1:]), dtype=torch.uint8)
        cache[torch.from_numpy(rows)] = frames
    assert cache is not None, "no episodes to decode"
    return cache


def decode_image_cache(column, key: str) -> torch.Tensor:
    """Every PNG/JPEG image of image feature ``key`` (an Arrow column of ``{bytes, path}``
    structs) as uint8 ``(F, C, H, W)``."""
    from PIL import Image

    arrays = []
    for cell in column.to_pylist():
        if cell is None or cell.get("bytes") is None:
            raise ValueError(f"image feature {key!r}: a row holds no image bytes (path-only images)")
        img = np.array(Image.open(io.BytesIO(cell["bytes"])))
        if img.dtype != np.uint8 or img.ndim != 3:
            raise ValueError(f"image feature {key!r}: {img.dtype} {img.shape} is not an 8-bit colour image")
        arrays.append(img)
    return torch.from_numpy(np.stack(arrays)).permute(0, 3, 1, 2).contiguous()


class CameraFrames:
    """The camera features of a dataset, served per batch (see the module docstring).

    Args:
        dataset: the ``LeRobotDataset`` (read side: ``meta``, ``reader``, ``hf_dataset``).
        rows_of_episode: each loaded episode's rows, in frame order.
        image_cache: decode every frame once into RAM (``True``) or per item (``False``).
    """

    def __init__(self, dataset, rows_of_episode: dict[int, np.ndarray], image_cache: bool):
        meta = dataset.meta
        self.dataset = dataset
        self.video_keys: list[str] = list(meta.video_keys)
        self.image_keys: list[str] = [k for k in meta.image_keys if k not in self.video_keys]
        self.return_uint8: bool = dataset.reader._return_uint8
        self.cached: dict[str, torch.Tensor] = {}
        if image_cache:
            start = time.perf_counter()
            for key in self.video_keys:
                self.cached[key] = decode_video_cache(dataset, key, rows_of_episode)
            for key in self.image_keys:
                self.cached[key] = decode_image_cache(dataset.hf_dataset.data.column(key), key)
            size = sum(t.numel() for t in self.cached.values())
            logger.info(
                "decoded %d camera feature(s) into RAM: %.1f MB in %.1f s",
                len(self.cached),
                size / 2**20,
                time.perf_counter() - start,
            )

    @property
    def nbytes(self) -> int:
        return sum(t.numel() * t.element_size() for t in self.cached.values())

    def image_rows(self, key: str, rows: torch.Tensor) -> torch.Tensor:
        """Image feature ``key`` at dataset rows ``rows`` (any shape ``S``): float32 ``(*S, C, H, W)``."""
        if key in self.cached:
            return uint8_to_float(gather(self.cached[key], rows), "image")
        flat = rows.reshape(-1).tolist()
        frames = torch.stack(self.dataset.hf_dataset[key][flat])
        return frames.reshape(*rows.shape, *frames.shape[1:])

    def cached_video_rows(self, key: str, rows: torch.Tensor) -> torch.Tensor:
        """Cached video feature ``key`` at dataset rows ``rows`` (shape ``S``): ``(*S, C, H, W)``."""
        frames = gather(self.cached[key], rows)
        return frames if self.return_uint8 else uint8_to_float(frames, "video")

    def decode_videos(self, episode: int, timestamps: dict[str, Sequence[float]]) -> dict[str, torch.Tensor]:
        """The uncached video features of one item: frames at ``timestamps[key]`` (seconds from
        the episode start) of ``episode``, through LeRobot's reader (all its decoding options)."""
        return self.dataset.reader._query_videos(timestamps, episode)
