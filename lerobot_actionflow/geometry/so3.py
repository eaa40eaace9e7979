"""The rotation group SO(3): hat/vee, Exp/Log, geodesics and uniform sampling.

All functions are batched over arbitrary leading dimensions, keep the input's dtype and
device, and are differentiable (including at the identity and at rotations by pi).

Conventions: a rotation vector ``w`` (shape ``(..., 3)``) has angle ``theta = |w|`` and axis
``w / theta``; ``Exp(w) = R`` (shape ``(..., 3, 3)``) rotates column vectors, ``x' = R x``.
"""

from __future__ import annotations

import torch

# Below this angle Exp/Log use Taylor series: the closed forms divide 0 by 0.
_SMALL_ANGLE = 1e-3
# Below this cosine (angles above 2*pi/3) Log reads the axis from the symmetric part of R,
# where the antisymmetric part (proportional to sin(theta)) carries too little signal.
_NEAR_PI_COS = -0.5


def hat(w: torch.Tensor) -> torch.Tensor:
    """Skew-symmetric matrix of ``w``: ``hat(w) @ x == cross(w, x)``.

    Args:
        w: ``(..., 3)``.
    Returns:
        ``(..., 3, 3)``.
    """
    if w.shape[-1] != 3:
        raise ValueError(f"hat expects a last dimension of 3, got shape {tuple(w.shape)}")
    x, y, z = w.unbind(-1)
    o = torch.zeros_like(x)
    return torch.stack(
        (
            torch.stack((o, -z, y), -1),
            torch.stack((z, o, -x), -1),
            torch.stack((-y, x, o), -1),
        ),
        -2,
    )


def vee(m: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`hat`: ``(..., 3, 3) -> (..., 3)``.

    For a matrix that is not exactly skew-symmetric this returns the vee of its
    antisymmetric part, ``vee((M - M^T) / 2)``.
    """
    _check_matrix_shape(m, "vee")
    return 0.5 * torch.stack(
        (m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]), -1
    )


def exp(w: torch.Tensor) -> torch.Tensor:
    """SO(3) exponential (Rodrigues): ``Exp(w) = I + A(theta) hat(w) + B(theta) hat(w)^2``.

    ``A = sin(theta) / theta`` and ``B = (1 - cos(theta)) / theta^2``, replaced by their Taylor
    series for ``theta < 1e-3`` so that values and gradients are exact at ``w = 0``.

    Args:
        w: rotation vectors ``(..., 3)``.
    Returns:
        rotation matrices ``(..., 3, 3)``.
    """
    if w.shape[-1] != 3:
        raise ValueError(f"exp expects rotation vectors (..., 3), got shape {tuple(w.shape)}")
    theta2 = (w * w).sum(-1)
    small = theta2 < _SMALL_ANGLE**2
    # Evaluate the closed form on a safe angle so that the unused branch has finite gradients.
    theta = torch.sqrt(torch.where(small, torch.ones_like(theta2), theta2))
    a = torch.where(small, 1 - theta2 / 6 + theta2**2 / 120, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24 + theta2**2 / 720, (1 - torch.cos(theta)) / theta**2)
    k = hat(w)
    eye = torch.eye(3, dtype=w.dtype, device=w.device).expand(k.shape)
    return eye + a[..., None, None] * k + b[..., None, None] * (k @ k)


def log(r: torch.Tensor) -> torch.Tensor:
    """SO(3) logarithm: the rotation vector ``w`` with ``|w| <= pi`` and ``Exp(w) = R``.

    Three regimes, all with finite values and gradients:

    * ``theta < 1e-3``: ``w = v (1/2 + theta^2/12 + 7 theta^4/720)`` with
      ``v = 2 vee(R)`` (``= 2 sin(theta) axis``), the series of ``theta / (2 sin theta)``.
    * generic: ``theta = atan2(|v|/2, (tr R - 1)/2)``, ``w = theta v / (2 sin theta)``.
    * ``cos(theta) < -1/2`` (near pi): from ``(R + R^T)/2 = cos(theta) I + (1 - cos(theta)) a a^T``
      the axis ``a`` is the normalised column of largest diagonal, signed to agree with ``v``.
      At exactly pi both signs are valid logarithms; the sign is then the one of that column.

    Args:
        r: rotation matrices ``(..., 3, 3)``.
    Returns:
        rotation vectors ``(..., 3)``.
    """
    _check_matrix_shape(r, "log")
    v = 2 * vee(r)  # = 2 sin(theta) * axis
    cos = ((r[..., 0, 0] + r[..., 1, 1] + r[..., 2, 2] - 1) / 2).clamp(-1.0, 1.0)
    sin2_4 = (v * v).sum(-1)  # = 4 sin^2(theta)
    tiny = torch.finfo(r.dtype).tiny
    sin = 0.5 * torch.sqrt(sin2_4.clamp_min(tiny))
    theta = torch.atan2(sin, cos)

    # Small angles: series of theta / (2 sin theta), with theta^2 ~ sin^2 (error O(theta^4)).
    s2 = sin2_4 / 4
    w_small = v * (0.5 + s2 / 12 + 7 * s2**2 / 720)[..., None]

    small = theta < _SMALL_ANGLE
    near_pi = cos < _NEAR_PI_COS
    generic_den = torch.where(small | near_pi, torch.ones_like(sin), 2 * sin)
    w_generic = v * (theta / generic_den)[..., None]

    # Near pi: axis from the symmetric part.
    sym = 0.5 * (r + r.transpose(-1, -2))
    eye = torch.eye(3, dtype=r.dtype, device=r.device)
    one_minus_cos = torch.where(near_pi, 1 - cos, torch.ones_like(cos))
    aat = (sym - cos[..., None, None] * eye) / one_minus_cos[..., None, None]
    diag = torch.diagonal(aat, dim1=-2, dim2=-1)
    k = diag.argmax(-1, keepdim=True)
    col = torch.gather(aat, -1, k[..., None, :].expand(*aat.shape[:-1], 1)).squeeze(-1)
    col_norm = torch.sqrt(torch.gather(diag, -1, k).squeeze(-1).clamp_min(tiny))
    axis = col / col_norm[..., None]
    sign = torch.where((axis * v).sum(-1) < 0, -torch.ones_like(cos), torch.ones_like(cos))
    w_pi = axis * (sign * theta)[..., None]

    out = torch.where(small[..., None], w_small, w_generic)
    return torch.where(near_pi[..., None], w_pi, out)


def geodesic_distance(r1: torch.Tensor, r2: torch.Tensor) -> torch.Tensor:
    """Angle of ``R1^T R2`` in ``[0, pi]``: ``(..., 3, 3), (..., 3, 3) -> (...)``."""
    return torch.linalg.vector_norm(log(r1.transpose(-1, -2) @ r2), dim=-1)


def interpolate(r0: torch.Tensor, r1: torch.Tensor, t: torch.Tensor | float) -> torch.Tensor:
    """Geodesic interpolation ``R_t = R0 Exp(t Log(R0^T R1))``.

    Args:
        r0, r1: ``(..., 3, 3)`` (broadcastable).
        t: scalar or ``(...)`` broadcastable to the batch shape; ``t = 0`` gives ``R0``,
            ``t = 1`` gives ``R1``.
    Returns:
        ``(..., 3, 3)``.
    """
    w = log(r0.transpose(-1, -2) @ r1)
    t = torch.as_tensor(t, dtype=w.dtype, device=w.device)
    return r0 @ exp(t[..., None] * w)


def random_rotation(
    *shape: int,
    generator: torch.Generator | None = None,
    dtype: torch.dtype = torch.float32,
    device: torch.device | str | None = None,
) -> torch.Tensor:
    """Rotations drawn uniformly (Haar measure) on SO(3), shape ``(*shape, 3, 3)``.

    A normalised 4D standard normal is a uniform unit quaternion, and the double cover
    maps it to a uniform rotation.
    """
    from lerobot_actionflow.geometry.quaternion import quaternion_to_matrix

    if generator is not None and device is None:
        device = generator.device
    q = torch.randn(*shape, 4, generator=generator, dtype=dtype, device=device)
    q = q / torch.linalg.vector_norm(q, dim=-1, keepdim=True).clamp_min(torch.finfo(dtype).tiny)
    return quaternion_to_matrix(q)


def project_to_so3(m: torch.Tensor) -> torch.Tensor:
    """Nearest rotation in Frobenius norm: ``U diag(1, 1, det(U V^T)) V^T`` from the SVD.

    Use it to remove small numerical drift; it is not a substitute for validation.
    """
    _check_matrix_shape(m, "project_to_so3")
    u, _, vh = torch.linalg.svd(m)
    det = torch.det(u @ vh)
    d = torch.ones(*m.shape[:-2], 3, dtype=m.dtype, device=m.device)
    d = torch.cat((d[..., :2], det[..., None]), -1)
    return (u * d[..., None, :]) @ vh


def _check_matrix_shape(m: torch.Tensor, name: str) -> None:
    if m.ndim < 2 or m.shape[-2:] != (3, 3):
        raise ValueError(f"{name} expects matrices (..., 3, 3), got shape {tuple(m.shape)}")
