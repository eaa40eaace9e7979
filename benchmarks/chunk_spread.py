"""How far a demonstration's action chunks range from the EEF, against ActionFlow's prior.

    python benchmarks/chunk_spread.py --datasets Lift=/work/study/Lift/data \\
        StackThree_D0=/work/study/StackThree_D0/data Coffee_D0=/work/study/Coffee_D0/data

ActionFlow draws a chunk's initial poses around the current EEF pose ``(R_e, p_e)``: positions
``p_e + N(0, sigma^2 I)`` (``noise_sigma``) and rotations ``R_e Exp(kappa eps)``, ``eps ~ N(0, I)``
(``noise_kappa``, concentrated). The flow carries them to the demonstrated chunk. This script
measures the other end of those paths on a LeRobotDataset in the project's schema: for every
frame ``t`` whose chunk ``t .. t + horizon - 1`` (ActionFlow's ``action_delta_indices``) lies
inside its episode, and every action ``k`` of that chunk,

* the offset ``R_e^T (p_k - p_e)`` of the target position in the EEF frame of frame ``t``
  (``observation.poses`` row 0), in metres;
* the angle ``|Log(R_e^T R_k)|`` of the target rotation from the EEF's, in degrees.

The last ``horizon - 1`` frames of each episode start no full chunk and are left out (training
also uses them, with padded, masked chunks). It prints their RMS and quantiles per dataset, and
the same figures of the prior for each ``--sigmas`` / ``--kappas`` (exact: ``|N(0, s^2 I_3)|``
has RMS ``s sqrt 3``; the angle of ``Exp(kappa eps)`` is ``kappa |eps|``, chi with 3 degrees of
freedom, while that is below pi, so a ``kappa`` whose top quantile passes pi is refused). The
data's figures are invariant to a rigid motion of the whole episode, like the policy.

It does not say which prior trains the better policy: the prior's width against the data's is
one input to that choice, measured here; success is in RESULTS.md.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
from scipy.stats import chi

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lerobot_actionflow import rotations  # noqa: E402
from lerobot_actionflow.schema import ACTION_KEY, POSE9_DIM, POSES_KEY  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from study import task_files  # noqa: E402

#: ActionFlow's chunk length at the study's size (``ActionFlowConfig.horizon``).
DEFAULT_HORIZON = 16
QUANTILES = (50, 90, 99)


def chunk_offsets(
    eef_r: np.ndarray,
    eef_p: np.ndarray,
    act_r: np.ndarray,
    act_p: np.ndarray,
    episode: np.ndarray,
    horizon: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Every full chunk's target poses relative to the EEF at the chunk's first frame.

    Args:
        eef_r, eef_p: the EEF pose of each frame, ``(N, 3, 3)`` and ``(N, 3)``.
        act_r, act_p: the action's target pose of each frame, ``(N, 3, 3)`` and ``(N, 3)``.
        episode: ``(N,)`` episode index of each frame; frames of one episode are contiguous and
            in time order.
        horizon: actions per chunk.

    Returns:
        ``offsets (C * horizon, 3)`` in the EEF frame (metres) and ``angles (C * horizon,)`` in
        radians, for the ``C`` frames whose chunk ends inside their episode.

    Raises:
        ValueError: arrays of different lengths, or ``horizon < 1``.
    """
    n = len(episode)
    if horizon < 1:
        raise ValueError(f"horizon must be >= 1, got {horizon}")
    for name, a in (("eef_r", eef_r), ("eef_p", eef_p), ("act_r", act_r), ("act_p", act_p)):
        if len(a) != n:
            raise ValueError(f"{name} has {len(a)} frames, episode has {n}")
    episode = np.asarray(episode)
    # Frame t starts a full chunk when frame t + horizon - 1 exists and is of t's episode.
    last = np.arange(n) + horizon - 1
    starts = np.flatnonzero((last < n) & (episode[np.minimum(last, n - 1)] == episode))
    rows = starts[:, None] + np.arange(horizon)  # (C, horizon)
    r_e, p_e = eef_r[starts][:, None], eef_p[starts][:, None]
    offsets = rotations.apply(*rotations.inverse(r_e, p_e), act_p[rows])
    angles = rotations.geodesic_distance(r_e, act_r[rows])
    return offsets.reshape(-1, 3), angles.reshape(-1)


def _load(root: Path) -> tuple[np.ndarray, ...]:
    """``(eef_r, eef_p, act_r, act_p, episode)`` of the dataset at ``root``."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    if not (root / "meta" / "info.json").exists():
        raise SystemExit(f"{root}: not a LeRobotDataset root (no meta/info.json)")
    data = LeRobotDataset(f"local/{root.parent.name}", root=root).hf_dataset.with_format("numpy")
    for key in (POSES_KEY, ACTION_KEY):
        if key not in data.column_names:
            raise SystemExit(f"{root}: no '{key}' feature; this script reads the project's schema")
    poses = np.asarray(data[POSES_KEY], dtype=np.float64)
    action = np.asarray(data[ACTION_KEY], dtype=np.float64)
    eef_r, eef_p = rotations.pose7_to_rp(poses[:, 0])
    act_r, act_p = rotations.pose9_to_rp(action[:, :POSE9_DIM])
    return eef_r, eef_p, act_r, act_p, np.asarray(data["episode_index"])


def _row(name: str, dist: np.ndarray, angle_deg: np.ndarray, rms_axes: str) -> str:
    q = np.percentile(dist * 1000, QUANTILES)
    qa = np.percentile(angle_deg, QUANTILES)
    return (
        f"| {name} | {rms_axes} | {1000 * math.sqrt(np.mean(dist**2)):.0f} | "
        + " / ".join(f"{v:.0f}" for v in q)
        + " | "
        + " / ".join(f"{v:.1f}" for v in qa)
        + " |"
    )


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--datasets", nargs="+", required=True, metavar="TASK=ROOT")
    parser.add_argument("--horizon", type=int, default=DEFAULT_HORIZON)
    parser.add_argument("--sigmas", type=float, nargs="*", default=[0.05, 0.07, 0.1])
    parser.add_argument("--kappas", type=float, nargs="*", default=[0.25, 0.5])
    args = parser.parse_args(argv)
    try:
        roots = task_files(args.datasets, "--datasets")
    except ValueError as e:
        parser.error(str(e))
    for k in args.kappas:
        if not 0 < k * chi.ppf(QUANTILES[-1] / 100, 3) < math.pi:
            parser.error(
                f"--kappas {k}: its p{QUANTILES[-1]} angle is not in (0, pi), where kappa |eps| is the angle"
            )
    quant = " / ".join(f"p{q}" for q in QUANTILES)
    head = (
        f"| chunk targets (horizon {args.horizon}) | RMS x / y / z in the EEF frame (mm) | RMS distance (mm)"
    )
    print(f"{head} | distance {quant} (mm) | angle {quant} (deg) |")
    print("| --- | --- | ---: | --- | --- |")
    for task, root in roots.items():
        offsets, angles = chunk_offsets(*_load(root), horizon=args.horizon)
        axes = " / ".join(f"{v:.0f}" for v in 1000 * np.sqrt(np.mean(offsets**2, axis=0)))
        name = f"{task} ({len(angles) // args.horizon} chunks)"
        print(_row(name, np.linalg.norm(offsets, axis=1), np.degrees(angles), axes))
    # The prior's exact quantiles: |N(0, s^2 I_3)| = s chi_3; the angle kappa chi_3 (checked < pi above).
    for s in args.sigmas:
        q = " / ".join(f"{1000 * s * chi.ppf(p / 100, 3):.0f}" for p in QUANTILES)
        print(f"| prior, noise_sigma = {s} | {1000 * s:.0f} each | {1000 * s * math.sqrt(3):.0f} | {q} | |")
    for k in args.kappas:
        q = " / ".join(f"{math.degrees(k * chi.ppf(p / 100, 3)):.1f}" for p in QUANTILES)
        print(f"| prior, noise_kappa = {k} | | | | {q} |")


if __name__ == "__main__":
    main()
