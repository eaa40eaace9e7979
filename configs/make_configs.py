"""Write the ready training configs: configs/train/<policy>/<task>.json.

    python configs/make_configs.py          # regenerate after editing the tables below
    actionflow-train --config_path=configs/train/actionflow/StackThree_D0.json \\
        --dataset.root=data/StackThree_D0 --policy.device=cuda

They are `lerobot-train` configs, meant for `actionflow-train` (the same arguments and training
loop, the dataset served from RAM): `num_workers` is 0 because a batch of pose tokens is gathered
in about a millisecond in the training process. With plain `lerobot-train`, which reads the
dataset item by item, add `--num_workers=4` or more.

Each config names its dataset (`local/<task>`, root `data/<task>`: what `actionflow-collect`
writes by default there), the env for periodic evaluation (`--env.type=actionflow`), the
policy, and the run length. Paper settings where the paper gives them (ActionFlow: horizon 16,
K = 4, 4 IPA layers; history 5 on the real robot, 2 here for the simulated tasks as Diffusion
Policy uses; Diffusion Policy: DDPM with 100 training steps), documented choices elsewhere:
every policy sees 2 observation steps, predicts 16 actions and executes 8, so that the three
are compared on equal terms.
"""

from __future__ import annotations

import json
from pathlib import Path

TASKS = [
    "Lift", "Can", "Square", "ToolHang",
    *(f"{t}_D{d}" for t in ("StackThree", "Threading", "ThreePieceAssembly", "Coffee") for d in range(3)),
]  # fmt: skip

COMMON_POLICY = {"n_obs_steps": 2, "horizon": 16, "n_action_steps": 8, "push_to_hub": False}

POLICIES = {
    "actionflow": {
        "type": "actionflow",
        "num_layers": 4,
        "num_inference_steps": 4,
        "time_spacing": "uniform",
        "translation_scale": 10.0,
        "squash_translations": True,
        "optimizer_lr": 1e-4,
    },
    "euclidean_flow": {
        "type": "euclidean_flow",
        "backbone": "transformer",
        "num_inference_steps": 10,
        "time_spacing": "exponential",
    },
    "diffusion": {
        "type": "diffusion",
        "noise_scheduler_type": "DDPM",
        "num_train_timesteps": 100,
        "num_inference_steps": 10,
        # horizon 16 must be a multiple of 2 ** len(down_dims)
        "down_dims": [256, 512, 1024],
    },
}

RUN = {
    "steps": 100_000,
    "batch_size": 64,
    "num_workers": 0,
    "log_freq": 200,
    "save_freq": 20_000,
    "env_eval_freq": 20_000,
    "eval": {"n_episodes": 50, "batch_size": 10, "use_async_envs": True},
    "wandb": {"enable": False},
    "seed": 1000,
}


def config(policy: str, task: str) -> dict:
    return {
        "dataset": {"repo_id": f"local/{task}", "root": f"data/{task}"},
        "env": {"type": "actionflow", "task": task},
        "policy": {**POLICIES[policy], **COMMON_POLICY},
        "job_name": f"{policy}_{task}",
        **RUN,
    }


def main() -> None:
    root = Path(__file__).parent / "train"
    for policy in POLICIES:
        for task in TASKS:
            path = root / policy / f"{task}.json"
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(json.dumps(config(policy, task), indent=2) + "\n")
    print(f"wrote {len(POLICIES) * len(TASKS)} configs under {root}")


if __name__ == "__main__":
    main()
