"""``actionflow-train``: ``lerobot-train`` with its training data served from RAM.

    actionflow-train <any lerobot-train arguments> [--image_cache=true]
    actionflow-train --resume=true --config_path=OUT/checkpoints/last/pretrained_model/train_config.json

It runs LeRobot's own ``train()`` (the same config parsing, policy and processor factories,
sampler, DataLoader, optimiser, logging, checkpoints, evaluation) with one difference: the
datasets that ``lerobot.scripts.lerobot_train.make_train_eval_datasets`` returns are wrapped in
:class:`~lerobot_actionflow.data.in_memory.InMemoryLeRobotDataset`, which gives the same items
from tensors in RAM, a batch at a time. The replacement lives only inside this process, for the
duration of the call, so ``lerobot-train`` and every other user of LeRobot are unchanged.

Consequences, by construction: checkpoints are LeRobot checkpoints (either CLI resumes the
other's), and with the same seed the sampler draws the same indices and the batches are equal.

Options of this command (removed from the arguments before LeRobot parses them):

* ``--image_cache=true``: decode every camera frame (video or image features) once into uint8
  RAM, ``frames x C x H x W`` bytes per camera (19.2 kB per frame at 80x80), instead of decoding
  per item.

``--num_workers``: LeRobot's default is 4 worker processes (spawned, each importing torch and
LeRobot). A pose-token batch is gathered in about a millisecond in the training process, so
``--num_workers=0`` is the right choice on a few CPU cores; keep workers for per-item video
decoding. Streaming datasets (``--dataset.streaming=true``) are passed through unwrapped.
"""

from __future__ import annotations

import contextlib
import logging
import sys
from collections.abc import Iterator

IMAGE_CACHE_FLAG = "--image_cache"
_TRUE, _FALSE = ("true", "1", "yes"), ("false", "0", "no")


def pop_image_cache_flag(args: list[str]) -> tuple[bool, list[str]]:
    """``--image_cache[=| ][true|false]`` out of ``args``: (its value, the other arguments)."""
    value, rest, i = False, [], 0
    while i < len(args):
        name, eq, text = args[i].partition("=")
        i += 1
        if name != IMAGE_CACHE_FLAG:
            rest.append(args[i - 1])
            continue
        if not eq and i < len(args) and args[i].lower() in (*_TRUE, *_FALSE):
            text, i = args[i], i + 1
        elif not eq:
            text = "true"
        if text.lower() not in (*_TRUE, *_FALSE):
            raise SystemExit(f"actionflow-train: {IMAGE_CACHE_FLAG} takes true or false, got {text!r}")
        value = text.lower() in _TRUE
    return value, rest


def in_memory(dataset, image_cache: bool):
    """``dataset`` wrapped in an :class:`InMemoryLeRobotDataset` (``None`` and non-map-style
    datasets, such as streaming ones, are returned as they are)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from lerobot_actionflow.data.in_memory import InMemoryLeRobotDataset

    if dataset is None:
        return None
    if not isinstance(dataset, LeRobotDataset):
        logging.warning("actionflow-train: %s is read as LeRobot reads it", type(dataset).__name__)
        return dataset
    return InMemoryLeRobotDataset(dataset, image_cache=image_cache)


@contextlib.contextmanager
def in_memory_training_data(image_cache: bool = False) -> Iterator[None]:
    """Within the block, ``lerobot.scripts.lerobot_train.train`` gets its train and eval datasets
    as :class:`InMemoryLeRobotDataset` (the factory it calls, ``make_train_eval_datasets``, is
    wrapped in its module's namespace and restored on exit)."""
    from lerobot.scripts import lerobot_train

    original = lerobot_train.make_train_eval_datasets

    def make_in_memory_datasets(cfg):
        train_ds, eval_ds = original(cfg)
        return in_memory(train_ds, image_cache), in_memory(eval_ds, image_cache)

    lerobot_train.make_train_eval_datasets = make_in_memory_datasets
    try:
        yield
    finally:
        lerobot_train.make_train_eval_datasets = original


def main(argv: list[str] | None = None) -> None:
    """Parse this command's own option, then run LeRobot's ``train()`` on the in-memory data."""
    args = sys.argv[1:] if argv is None else list(argv)
    image_cache, rest = pop_image_cache_flag(args)
    sys.argv = [sys.argv[0], *rest]

    from lerobot.scripts import lerobot_train
    from lerobot.utils.import_utils import register_third_party_plugins

    register_third_party_plugins()
    if lerobot_train._remote_target_in_argv():
        raise SystemExit("actionflow-train runs locally; submit remote jobs with lerobot-train")
    with in_memory_training_data(image_cache=image_cache):
        lerobot_train.train()


if __name__ == "__main__":
    main()
