"""Make a saved ActionFlow / euclidean_flow checkpoint deployable on a LeRobot robot.

``python -m lerobot_actionflow.robots.prepare_checkpoint CHECKPOINT`` inserts the
``actionflow_robot_observation`` step (:mod:`lerobot_actionflow.robots.processor`) into the
checkpoint's ``policy_preprocessor.json``, so that ``lerobot-rollout --policy.path=CHECKPOINT``
accepts a robot's flat observation. Running it again changes nothing.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from lerobot_actionflow.registry import register_all
from lerobot_actionflow.robots.processor import REGISTRY_NAME, add_robot_observation_step


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint", type=Path, help="a pretrained_model folder")
    args = parser.parse_args(argv)
    register_all()  # the checkpoint's policy type
    added = add_robot_observation_step(args.checkpoint)
    print(f"{args.checkpoint}: {'added' if added else 'already has'} the step {REGISTRY_NAME}")


if __name__ == "__main__":
    main()
