"""Checks of the observation tensors given to a policy, shared by both policies.

Every ``forward`` / ``predict_action_chunk`` / ``select_action`` input goes through
:func:`check_observation` before anything else touches it, so that a bad input is refused with
one ``ValueError`` naming the feature, the expected shape and dtype, and what was given, and
never reaches a policy's history.

Dtypes: a floating-point tensor of any precision (float16, bfloat16, float32, float64) is cast
to the policy's dtype (the dtype of its parameters), so a batch built from float64 numpy arrays
works. Integer, bool and complex tensors are refused by name: an integer pose or state is not a
value the policy was trained on, and integer (``uint8``) images mean the preprocessor, which
scales them to ``[0, 1]``, was skipped. Anything that is not a ``torch.Tensor`` (a numpy array, a
list) is refused too, for the same reason: LeRobot's preprocessor turns env arrays into tensors,
and normalises them, before the policy sees them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from torch import Tensor

from lerobot_actionflow.geometry import check_finite


def _shape_str(lead: Sequence[str | int], shape: Sequence[int | str]) -> str:
    return "(" + ", ".join(str(d) for d in (*lead, *shape)) + ")"


def describe(x: object) -> str:
    """What was given, for error messages: shape and dtype of a tensor, else the type too."""
    shape, dtype = getattr(x, "shape", None), getattr(x, "dtype", None)
    parts = [] if isinstance(x, Tensor) else [f"type {type(x).__module__}.{type(x).__qualname__}"]
    if shape is not None:
        parts.append(f"shape {tuple(shape)}")
    if dtype is not None:
        parts.append(f"dtype {dtype}")
    return ", ".join(parts)


def check_observation(
    batch: Mapping[str, object],
    features: Mapping[str, Sequence[int | str]],
    n_obs_steps: int,
    with_time: bool,
    dtype: torch.dtype,
) -> dict[str, Tensor]:
    """Check the observation features a policy reads and return them ready to use.

    Args:
        batch: the inputs; keys other than ``features`` are ignored.
        features: feature key -> per-step shape (from the config's input features); a ``str``
            entry (e.g. ``"H"``) names a dimension of any size.
        n_obs_steps: the length of the history.
        with_time: tensors are ``(B, n_obs_steps, *shape)`` (training and
            ``predict_action_chunk``; ``(B, *shape)`` is also accepted when ``n_obs_steps == 1``),
            else ``(B, *shape)`` (one environment step, ``select_action``).
        dtype: the policy's floating dtype; floating inputs are cast to it.

    Returns:
        ``{key: tensor}`` for every key of ``features``, with the time axis present when
        ``with_time`` and cast to ``dtype``.

    Raises:
        ValueError: a feature is missing, not a tensor, not floating point, of the wrong shape,
            of a batch size that differs from the other features', or not finite. The message
            names the feature, the expected shape and dtype, and what was given.
    """
    lead: tuple[str | int, ...] = ("B", n_obs_steps) if with_time else ("B",)
    out: dict[str, Tensor] = {}
    first: tuple[str, int] | None = None
    for key, shape in features.items():
        shape = tuple(shape)
        expected = f"{_shape_str(lead, shape)}, a floating-point torch.Tensor (cast to {dtype})"
        if key not in batch:
            raise ValueError(
                f"missing input feature '{key}': expected {expected}; the batch has {sorted(batch)}"
            )
        x = batch[key]
        if not isinstance(x, Tensor) or not x.is_floating_point():
            hint = ""
            if isinstance(x, Tensor) and x.dtype == torch.uint8:
                hint = " (uint8 images: run the policy's preprocessor, which scales them to [0, 1])"
            elif not isinstance(x, Tensor):
                hint = " (run the policy's preprocessor, or torch.as_tensor, first)"
            raise ValueError(f"input feature '{key}' has {describe(x)}, expected {expected}{hint}")
        if with_time and n_obs_steps == 1 and x.ndim == len(shape) + 1:
            x = x.unsqueeze(1)  # a single observation step may come without its time axis
        ok = x.ndim == len(lead) + len(shape) and all(
            isinstance(want, str) or want == got for want, got in zip(shape, x.shape[len(lead) :])
        )
        if not ok or (with_time and x.shape[1] != n_obs_steps):
            raise ValueError(f"input feature '{key}' has {describe(batch[key])}, expected {expected}")
        if first is None:
            first = (key, x.shape[0])
        elif x.shape[0] != first[1]:
            raise ValueError(
                f"input feature '{key}' has batch size B={x.shape[0]}, but '{first[0]}' has "
                f"B={first[1]}: every feature must have the same batch size"
            )
        try:
            check_finite(x, key)
        except ValueError as e:
            raise ValueError(f"input feature '{key}' contains non-finite values: {e}") from None
        out[key] = x.to(dtype)
    return out


def check_num_inference_steps(k: object) -> int:
    """``k`` as the number of Euler steps: an ``int >= 1`` (``ValueError`` otherwise)."""
    if isinstance(k, bool) or not isinstance(k, int) or k < 1:
        raise ValueError(f"num_inference_steps must be an integer >= 1, got {k!r}")
    return k
