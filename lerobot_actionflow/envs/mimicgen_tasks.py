"""Mimicgen-style tasks built here from robosuite primitives (no mimicgen code or assets).

| task            | robosuite env (ours)        | tokens after the EEF      | episode |
| --------------- | --------------------------- | ------------------------- | ------- |
| StackThree_D*   | ``stack_three.StackThree``  | cubeA, cubeB, cubeC       | 400     |
| Threading_D*    | ``threading_task.Threading`` | needle, ring (tripod)    | 400     |
| ThreePieceAssembly_D* | ``three_piece_assembly.ThreePieceAssembly`` | base, piece1, piece2 | 500 |
| Coffee_D*       | ``coffee.Coffee``           | pod, holder, lid          | 400     |

Variants D0/D1/D2 widen the initial placement (see each env's module).
"""

from __future__ import annotations

from lerobot_actionflow.envs.tasks import Entity, TaskSpec, register_task

STACK_THREE_ENTITIES = (
    Entity("cubeA", body="cubeA_main", doc="red cube, half size 0.02 m"),
    Entity("cubeB", body="cubeB_main", doc="green cube, half size 0.025 m (the tower's base)"),
    Entity("cubeC", body="cubeC_main", doc="blue cube, half size 0.02 m"),
)

STACK_THREE = {
    variant: register_task(
        TaskSpec(
            name=f"StackThree_{variant}",
            env_class="lerobot_actionflow.envs.stack_three:StackThree",
            subgoals="lerobot_actionflow.envs.stack_three:subgoals",
            env_kwargs={"variant": variant},
            entities=STACK_THREE_ENTITIES,
            episode_length=400,
            description="Stack the red cube on the green cube, then the blue cube on the red cube.",
            success="A on B and C on A: cube A's centre more than 0.04 m and cube C's more than 0.08 m "
            "above the table, A touching B, C touching A, and neither grasped",
            variant=variant,
        )
    )
    for variant in ("D0", "D1", "D2")
}

THREADING = {
    variant: register_task(
        TaskSpec(
            name=f"Threading_{variant}",
            env_class="lerobot_actionflow.envs.threading_task:Threading",
            subgoals="lerobot_actionflow.envs.threading_task:subgoals",
            env_kwargs={"variant": variant},
            entities=(
                Entity("needle", body="needle_root", doc="the needle (origin mid-length, tip along +x)"),
                Entity("ring", site="tripod_ring_center", doc="the tripod's ring centre, axis along x"),
            ),
            episode_length=400,
            description="Pick up the needle and thread it through the ring of the tripod.",
            success="the needle's tip is within the ring's inner radius (0.012 m) of the ring's centre",
            variant=variant,
        )
    )
    for variant in ("D0", "D1", "D2")
}

THREE_PIECE_ASSEMBLY = {
    variant: register_task(
        TaskSpec(
            name=f"ThreePieceAssembly_{variant}",
            env_class="lerobot_actionflow.envs.three_piece_assembly:ThreePieceAssembly",
            subgoals="lerobot_actionflow.envs.three_piece_assembly:subgoals",
            env_kwargs={"variant": variant},
            entities=(
                Entity("base", body="assembly_base_root", doc="the base with a square socket"),
                Entity("piece1", body="piece1_root", doc="piece 1: a block with a socket on top"),
                Entity("piece2", body="piece2_root", doc="piece 2: a block"),
            ),
            episode_length=500,
            description="Insert the red piece into the base, then the blue piece into the red piece.",
            success="piece 1 within 0.02 m (xy) of the base at its inserted height (5 mm), released; "
            "piece 2 within 0.02 m (xy) of piece 1 at its inserted height (5 mm), released",
            variant=variant,
        )
    )
    for variant in ("D0", "D1", "D2")
}

COFFEE = {
    variant: register_task(
        TaskSpec(
            name=f"Coffee_{variant}",
            env_class="lerobot_actionflow.envs.coffee:Coffee",
            subgoals="lerobot_actionflow.envs.coffee:subgoals",
            env_kwargs={"variant": variant},
            entities=(
                Entity("pod", body="pod_main", doc="the coffee pod (a cylinder)"),
                Entity(
                    "holder",
                    site="coffee_machine_body_holder",
                    doc="the holder's floor centre (machine pose)",
                ),
                Entity("lid", body="coffee_machine_lid_root", doc="the hinged lid (centre of the plate)"),
            ),
            episode_length=400,
            description="Put the coffee pod into the machine's pod holder and close the lid.",
            success="the lid's hinge angle is below 15 deg and the pod is inside the holder (centre within "
            "0.012 m of its axis and 0.01 m of its resting height)",
            variant=variant,
        )
    )
    for variant in ("D0", "D1", "D2")
}
