"""Which weights a stored evaluation measured: the SHA-256 digest of a checkpoint's weights file.

Results files name a checkpoint by its path. A run trained again into the same folder (after a
crash, on a fresh machine, with changed code) writes its weights under the same name, so a sweep
that adds cells beside stored ones first compares the digest stored with them
(:data:`DIGEST_KEY`) with the file's (:func:`check_same_weights`): cells of two different sets of
weights never end up in one table under one name.
"""

from __future__ import annotations

import hashlib
import logging
import os
import platform
from collections.abc import Iterable
from pathlib import Path

from huggingface_hub.constants import SAFETENSORS_SINGLE_FILE

#: The key of a stored cell that holds the digest of the weights it was measured with.
DIGEST_KEY = "weights_sha256"
#: The key of a stored cell that names the machine that measured it (normally the one that trained
#: its checkpoint too: runs live on that machine's disk, and a run trained again elsewhere has
#: other weights, which :func:`check_same_weights` refuses).
MACHINE_KEY = "machine"
CPUINFO = Path("/proc/cpuinfo")


def machine_description(device: str = "cpu", cpuinfo: Path = CPUINFO) -> str:
    """``"<CPU model>, <n> CPUs"``, plus the GPU's name when ``device`` is a CUDA device.

    Stored beside results because training is bit-identical only on one kind of machine: the same
    seed trains other weights on another CPU model, and wall-clock figures depend on it too. The
    model is ``cpuinfo``'s first ``model name`` (Linux), else :func:`platform.processor`.
    """
    model = ""
    if cpuinfo.is_file():
        for line in cpuinfo.read_text(errors="replace").splitlines():
            key, sep, value = line.partition(":")
            if sep and key.strip() == "model name":
                model = value.strip()
                break
    description = (
        f"{model or platform.processor() or platform.machine() or 'unknown CPU'}, {os.cpu_count()} CPUs"
    )
    if device.startswith("cuda"):
        import torch

        description += f", {torch.cuda.get_device_name(torch.device(device))}"
    return description


def weights_digest(pretrained_dir: str | Path) -> str:
    """Hex SHA-256 of ``pretrained_dir/model.safetensors``.

    Raises:
        FileNotFoundError: naming the missing weights file.
    """
    path = Path(pretrained_dir) / SAFETENSORS_SINGLE_FILE
    if not path.is_file():
        raise FileNotFoundError(f"no weights file {path}: is {pretrained_dir} a pretrained_model folder?")
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def check_same_weights(stored: Iterable[dict], digest: str, checkpoint: str, advice: str) -> None:
    """Refuse to add cells of ``checkpoint`` (weights ``digest``) beside ``stored`` cells of the same
    name measured on other weights; cells stored without a digest cannot be checked and are
    reported in the log.

    Raises:
        ValueError: naming the checkpoint, both digests and ``advice``.
    """
    stored = list(stored)
    other = sorted({c[DIGEST_KEY] for c in stored if c.get(DIGEST_KEY) not in (None, digest)})
    if other:
        raise ValueError(
            f"{checkpoint} now holds weights {digest[:12]}, but its stored cells were measured on "
            f"{', '.join(d[:12] for d in other)}: it was trained again. {advice}"
        )
    unknown = sum(DIGEST_KEY not in c for c in stored)
    if unknown:
        logging.warning(
            "%d stored cells of %s carry no weights digest: they cannot be checked against %s",
            unknown, checkpoint, digest[:12],
        )  # fmt: skip
