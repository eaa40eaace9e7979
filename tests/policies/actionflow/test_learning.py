"""ActionFlow learns a pose-conditioned grasp: a fixed offset applied to a random object pose."""

import torch

from lerobot_actionflow import geometry as g
from lerobot_actionflow.geometry.se3 import compose, rp_to_pose7
from lerobot_actionflow.policies.actionflow.modeling_actionflow import ActionflowPolicy
from lerobot_actionflow.schema.tensors import action_to_pose, pose_to_action

from .helpers import small_config

HORIZON = 4
GRASP_R = g.exp(torch.tensor([0.0, 3.0, 0.0]))  # nearly upside down, as a top grasp
GRASP_P = torch.tensor([0.0, 0.0, 0.05])


def grasp_data(batch_size: int, gen: torch.Generator) -> dict:
    """EEF anywhere with any orientation; one object within ~0.25 m of it; every action of the
    chunk is the grasp pose T_object * T_offset with the gripper closing (+1)."""
    r_e, p_e = g.random_rotation(batch_size, generator=gen), 0.5 * torch.randn(batch_size, 3, generator=gen)
    r_o = g.random_rotation(batch_size, generator=gen)
    p_o = p_e + 0.15 * torch.randn(batch_size, 3, generator=gen)
    poses = rp_to_pose7(torch.stack((r_e, r_o), 1), torch.stack((p_e, p_o), 1))[:, None]
    r_a, p_a = compose(r_o, p_o, GRASP_R, GRASP_P)
    action = pose_to_action(
        r_a[:, None].expand(-1, HORIZON, 3, 3),
        p_a[:, None].expand(-1, HORIZON, 3),
        torch.ones(batch_size, HORIZON),
    )
    return {"observation.poses": poses, "action": action}


def pose_errors(policy, data):
    r, p, grip = action_to_pose(policy.predict_action_chunk(data))
    r1, p1, g1 = action_to_pose(data["action"])
    return (
        (p - p1).norm(dim=-1).mean().item(),
        g.geodesic_distance(r, r1).mean().item(),
        (grip - g1).abs().mean().item(),
    )


def test_actionflow_learns_grasp_offset_from_object_pose():
    torch.manual_seed(0)
    # Actions lie 0.1-0.4 m from the EEF, where tanh(10 x) saturates: scale without squashing.
    cfg = small_config(
        num_entities=2, n_obs_steps=1, horizon=HORIZON, with_state=False, dim=64, num_heads=4, head_dim=16,
        num_query_points=4, num_value_points=4, squash_translations=False, translation_scale=10.0,
    )  # fmt: skip
    policy = ActionflowPolicy(cfg)
    test = grasp_data(256, torch.Generator().manual_seed(99))
    policy.eval()
    before = pose_errors(policy, test)
    policy.train()

    steps = 600
    opt = torch.optim.AdamW(policy.parameters(), lr=3e-3)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=3e-3, total_steps=steps, pct_start=0.1)
    gen = torch.Generator().manual_seed(1)
    for _ in range(steps):
        loss, terms = policy.forward(grasp_data(64, gen))
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
    assert set(terms) == {"loss_translation", "loss_rotation", "loss_gripper"}

    policy.eval()
    trans, rot, grip = pose_errors(policy, test)
    assert before[0] > 0.1 and before[1] > 1.0, before  # the task is not trivially solved at init
    assert trans < 0.02, f"mean translation error {trans:.4f} m"
    assert rot < 0.3, f"mean rotation error {rot:.3f} rad"
    assert grip < 0.1, f"mean gripper error {grip:.3f}"
