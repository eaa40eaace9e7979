"""Inference-step sweep through LeRobot's eval machinery, on a tiny env defined here.

The env rewards commitment: an episode is one step and succeeds when ``|action| > 0.5``. The
two-mode policy (conftest) commits with K = 10 Euler steps and averages the modes (action near
0) with K = 1, so the success rate must depend on IS: the sweep really changes the sampler.
"""

from dataclasses import dataclass, field
from typing import ClassVar

import gymnasium as gym
import numpy as np
import pytest
import torch
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig

from lerobot_actionflow.evaluation.sweep import main, set_inference_steps

GYM_ID = "gym_ef_commit/Commit-v0"


class CommitEnv(gym.Env):
    """One-step env: observation zeros, success iff ``|a| > 0.5``."""

    metadata: ClassVar[dict] = {"render_modes": ["rgb_array"], "render_fps": 10}
    task = "commit"
    task_description = "commit to one of two modes"

    def __init__(self):
        self.observation_space = gym.spaces.Dict(
            {
                "agent_pos": gym.spaces.Box(-1, 1, (3,), np.float32),
                "environment_state": gym.spaces.Box(-1, 1, (2,), np.float32),
            }
        )
        self.action_space = gym.spaces.Box(-1, 1, (1,), np.float32)

    def _obs(self):
        return {"agent_pos": np.zeros(3, np.float32), "environment_state": np.zeros(2, np.float32)}

    def reset(self, seed=None, options=None):
        super().reset(seed=seed)
        return self._obs(), {}

    def step(self, action):
        success = bool(abs(float(action[0])) > 0.5)
        return self._obs(), float(success), True, False, {"is_success": success}

    def render(self):
        return np.zeros((8, 8, 3), np.uint8)


if GYM_ID not in gym.registry:
    gym.register(id=GYM_ID, entry_point=CommitEnv, max_episode_steps=2)


@EnvConfig.register_subclass("ef_commit")
@dataclass
class CommitEnvConfig(EnvConfig):
    task: str | None = "Commit-v0"
    features: dict = field(
        default_factory=lambda: {
            "action": PolicyFeature(FeatureType.ACTION, (1,)),
            "agent_pos": PolicyFeature(FeatureType.STATE, (3,)),
            "environment_state": PolicyFeature(FeatureType.ENV, (2,)),
        }
    )
    features_map: dict = field(
        default_factory=lambda: {
            "action": "action",
            "agent_pos": "observation.state",
            "environment_state": "observation.environment_state",
        }
    )

    @property
    def gym_kwargs(self) -> dict:
        return {}


def _tiny_diffusion(**kw):
    from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig
    from lerobot.policies.diffusion.modeling_diffusion import DiffusionPolicy

    cfg = DiffusionConfig(
        device="cpu",
        horizon=8,
        n_action_steps=4,
        down_dims=(8, 16),
        n_groups=4,
        diffusion_step_embed_dim=8,
        input_features={
            "observation.state": PolicyFeature(FeatureType.STATE, (3,)),
            "observation.environment_state": PolicyFeature(FeatureType.ENV, (2,)),
        },
        output_features={"action": PolicyFeature(FeatureType.ACTION, (1,))},
        **kw,
    )
    return DiffusionPolicy(cfg).eval()


def test_set_inference_steps_for_diffusion_ddim_then_ddpm():
    from diffusers import DDIMScheduler, DDPMScheduler

    policy = _tiny_diffusion()
    calls = []
    policy.diffusion.unet.register_forward_hook(lambda *a: calls.append(1))
    batch = {"observation.state": torch.zeros(1, 2, 3), "observation.environment_state": torch.zeros(1, 2, 2)}
    betas = policy.diffusion.noise_scheduler.betas.clone()
    for steps, cls, name in [
        (5, DDIMScheduler, "ddim"),
        (100, DDPMScheduler, "ddpm"),
        (2, DDIMScheduler, "ddim"),
    ]:
        calls.clear()
        assert set_inference_steps(policy, steps) == name
        assert type(policy.diffusion.noise_scheduler) is cls
        assert torch.equal(policy.diffusion.noise_scheduler.betas, betas)  # the trained schedule
        policy.predict_action_chunk(batch)
        assert len(calls) == steps
    with pytest.raises(ValueError, match="trained with 100 steps"):
        set_inference_steps(policy, 101)


def test_set_inference_steps_rejects_other_policies_and_bad_counts(bimodal_policy):
    with pytest.raises(ValueError, match=">= 1"):
        set_inference_steps(bimodal_policy, 0)
    other = type("P", (), {"config": type("C", (), {"type": "act"})()})()
    with pytest.raises(ValueError, match="'act'"):
        set_inference_steps(other, 5)


def test_sweep_reports_success_per_inference_step(bimodal_checkpoint, tmp_path):
    from lerobot.policies.factory import make_pre_post_processors

    # An untrained Diffusion Policy checkpoint as second entry: the sweep handles both types.
    diffusion = _tiny_diffusion()
    dp_path = tmp_path / "dp"
    stats = {
        "observation.state": {"min": -torch.ones(3), "max": torch.ones(3)},
        "observation.environment_state": {"min": -torch.ones(2), "max": torch.ones(2)},
        "action": {"min": -torch.ones(1), "max": torch.ones(1)},
    }
    diffusion.save_pretrained(dp_path)
    for proc in make_pre_post_processors(diffusion.config, dataset_stats=stats):
        proc.save_pretrained(dp_path)

    rows = main(
        [
            "--env.type=ef_commit",
            f"--checkpoints=[{bimodal_checkpoint},{dp_path}]",
            "--inference_steps=[1,10]",
            "--eval.n_episodes=40",
            "--eval.batch_size=20",
            "--eval.use_async_envs=false",
            "--device=cpu",
            f"--output_dir={tmp_path / 'sweep'}",
        ]
    )
    by = {(r["policy"], r["inference_steps"]): r for r in rows}
    assert set(by) == {("euclidean_flow", 1), ("euclidean_flow", 10), ("diffusion", 1), ("diffusion", 10)}
    assert all(r["n_episodes"] == 40 for r in rows)
    assert by[("euclidean_flow", 1)]["pc_success"] <= 20.0, by  # one Euler step: the average
    assert by[("euclidean_flow", 10)]["pc_success"] >= 70.0, by  # ten steps: one of the modes
    assert by[("euclidean_flow", 10)]["sampler"] == "euler-exponential-guided"
    assert by[("diffusion", 10)]["sampler"] == "ddim"
    saved = (tmp_path / "sweep" / "sweep_results.json").read_text()
    assert '"inference_steps": 10' in saved


def test_the_solver_is_a_sampling_choice_counted_in_network_calls():
    from lerobot_actionflow.policies.euclidean_flow.modeling_euclidean_flow import EuclideanFlowPolicy

    from .conftest import bimodal_batch, bimodal_config

    policy = EuclideanFlowPolicy(bimodal_config()).eval()  # trained with the default Euler solver
    calls = []
    policy.velocity_net.register_forward_hook(lambda *a: calls.append(1))
    obs = {k: v for k, v in bimodal_batch(2, torch.Generator().manual_seed(0)).items() if k != "action"}
    for steps, solver, name in [
        (4, "midpoint", "midpoint-exponential"),
        (4, None, "midpoint-exponential"),
        (3, "euler", "euler-exponential-guided"),  # guided by default with Euler steps
    ]:
        calls.clear()
        assert set_inference_steps(policy, steps, solver=solver) == name
        policy.predict_action_chunk(obs)
        assert len(calls) == steps  # IS counts network calls whatever the solver
    with pytest.raises(ValueError, match="multiple of 2"):
        set_inference_steps(policy, 3, solver="midpoint")
    with pytest.raises(ValueError, match="'rk4'"):
        set_inference_steps(policy, 4, solver="rk4")
    with pytest.raises(ValueError, match="flow policies only"):
        set_inference_steps(_tiny_diffusion(), 10, solver="midpoint")


def test_a_checkpoint_swept_again_gives_the_same_rates_and_names_its_weights(bimodal_checkpoint, tmp_path):
    """The policy's noise starts from ``--seed`` at every IS, so a rerun repeats every rate (at
    IS = 2 the two-mode policy succeeds in part of the episodes, by its noise); each row names
    the weights it measured."""
    from lerobot_actionflow.evaluation.provenance import DIGEST_KEY, weights_digest

    args = [
        "--env.type=ef_commit",
        f"--checkpoints=[{bimodal_checkpoint}]",
        "--inference_steps=[2,3]",
        "--eval.n_episodes=40",
        "--eval.batch_size=20",
        "--eval.use_async_envs=false",
        "--device=cpu",
    ]
    torch.manual_seed(1)
    first = main(args)
    torch.manual_seed(2)  # whatever the caller's generator holds
    again = main(args)
    rates = [r["pc_success"] for r in first]
    assert rates == [r["pc_success"] for r in again]
    assert any(0 < rate < 100 for rate in rates), rates  # the noise decides episodes
    assert {r[DIGEST_KEY] for r in first} == {weights_digest(bimodal_checkpoint)}
