"""The mug-hanging tasks (paper App. G.5), built here from robosuite primitives.

| task          | robosuite env (ours)  | tokens after the EEF | episode |
| ------------- | --------------------- | -------------------- | ------- |
| MugHang_D0    | ``mug_hang.MugHang``  | mug, hanger          | 400     |
| MugHang_Moved | ``mug_hang.MugHang``  | mug, hanger          | 400     |

``MugHang_D0`` keeps the hanger in one place (the training set); ``MugHang_Moved`` stands it on
either side of the table, turned (see :mod:`lerobot_actionflow.envs.mug_hang`).
"""

from __future__ import annotations

from lerobot_actionflow.envs.tasks import Entity, TaskSpec, register_task

MUG_HANG = {
    variant: register_task(
        TaskSpec(
            name=f"MugHang_{variant}",
            env_class="lerobot_actionflow.envs.mug_hang:MugHang",
            subgoals="lerobot_actionflow.envs.mug_hang:subgoals",
            env_kwargs={"variant": variant},
            entities=(
                Entity("mug", body="mug_root", doc="the mug (centre of its body; handle along +x)"),
                Entity(
                    "hanger",
                    site="hanger_peg",
                    doc="the peg's root on the hanger's post, x along the peg towards its tip",
                ),
            ),
            episode_length=400,
            description="Pick up the mug and hang it by its handle on the hanger's peg.",
            success="the peg passes through the mug's handle, the mug touches the peg and neither the "
            "table nor the gripper, and it has stayed still (< 0.03 m/s, < 0.5 rad/s) for 5 steps",
            variant=variant,
        )
    )
    for variant in ("D0", "Moved")
}
