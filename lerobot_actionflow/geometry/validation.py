"""Checks that refuse bad rotations with a message naming the offending batch entry.

Data that has drifted slightly off the manifold (float32 round-off, a quaternion stored with
four decimals) is projected back; anything further off is refused, since silently
"fixing" a wrong rotation would train or act on a different pose than the user gave.
"""

from __future__ import annotations

import torch

from lerobot_actionflow.geometry.so3 import project_to_so3


def _first_bad(mask: torch.Tensor) -> tuple[int, ...]:
    idx = torch.nonzero(mask)[0]
    return tuple(int(i) for i in idx)


def _where(name: str, index: tuple[int, ...]) -> str:
    return f"{name}[{', '.join(map(str, index))}]" if index else name


def check_finite(x: torch.Tensor, name: str = "tensor") -> None:
    """Raise ``ValueError`` naming the first entry (over leading dims) holding NaN or inf."""
    bad = ~torch.isfinite(x)
    if bad.any():
        index = _first_bad(bad)
        raise ValueError(f"{_where(name, index[:-1] if x.ndim else index)} is not finite: NaN or inf")


def rotation_error(r: torch.Tensor) -> torch.Tensor:
    """Distance from SO(3): ``max(|R^T R - I|_max, |det R - 1|)`` per matrix ``(...)``."""
    eye = torch.eye(3, dtype=r.dtype, device=r.device)
    ortho = (r.transpose(-1, -2) @ r - eye).abs().amax((-1, -2))
    return torch.maximum(ortho, (torch.det(r) - 1).abs())


def check_rotation_matrix(
    r: torch.Tensor, atol: float = 1e-3, name: str = "rotation", project: bool = True
) -> torch.Tensor:
    """Validate rotation matrices ``(..., 3, 3)`` and return them, projected onto SO(3).

    Raises:
        ValueError: wrong shape; a non-finite entry; or a matrix whose :func:`rotation_error`
            exceeds ``atol`` (e.g. a reflection or a scaled matrix). The message names the
            batch index.
    Returns:
        ``project_to_so3(r)`` if ``project`` else ``r`` unchanged.
    """
    if r.ndim < 2 or r.shape[-2:] != (3, 3):
        raise ValueError(f"{name} must have shape (..., 3, 3), got {tuple(r.shape)}")
    bad = ~torch.isfinite(r).all(-1).all(-1)
    if bad.any():
        raise ValueError(f"{_where(name, _first_bad(bad))} is not finite: NaN or inf")
    err = rotation_error(r)
    off = err > atol
    if off.any():
        index = _first_bad(off)
        raise ValueError(
            f"{_where(name, index)} is not a rotation matrix: deviation {float(err[index]):.3g} "
            f"from orthonormal with det +1 exceeds the tolerance {atol:g}"
        )
    return project_to_so3(r) if project else r


def check_quaternion(
    q: torch.Tensor, atol: float = 1e-3, name: str = "quaternion", normalize: bool = True
) -> torch.Tensor:
    """Validate quaternions ``(..., 4)`` and return them normalised.

    Raises:
        ValueError: wrong shape, non-finite entries, or a norm farther than ``atol`` from 1
            (a zero quaternion, or a vector that was never a unit quaternion).
    """
    if q.shape[-1] != 4:
        raise ValueError(f"{name} must have shape (..., 4), got {tuple(q.shape)}")
    bad = ~torch.isfinite(q).all(-1)
    if bad.any():
        raise ValueError(f"{_where(name, _first_bad(bad))} is not finite: NaN or inf")
    norm = torch.linalg.vector_norm(q, dim=-1)
    off = (norm - 1).abs() > atol
    if off.any():
        index = _first_bad(off)
        raise ValueError(
            f"{_where(name, index)} is not a unit quaternion: norm {float(norm[index]):.6g} "
            f"differs from 1 by more than {atol:g}"
        )
    return q / norm[..., None] if normalize else q
