"""Base class of the tasks written here: a Panda at a table, free objects placed at random.

A subclass builds its objects in :meth:`TabletopTask._build_objects`, returning them with their
placement ranges (a :class:`Placement` each, chosen by the ``variant`` argument), and defines
``_check_success``. Placement, the sparse reward and references to the objects' bodies are
handled here. Every object gets a free joint and is placed in sequence (no overlaps) by
robosuite's ``UniformRandomSampler`` with a yaw about z, all through the env's one ``rng`` (so the
pose-token env's seeding covers them).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from robosuite.environments.manipulation.manipulation_env import ManipulationEnv
from robosuite.models.arenas import TableArena
from robosuite.models.tasks import ManipulationTask
from robosuite.utils.placement_samplers import SequentialCompositeSampler, UniformRandomSampler

TABLE_TOP_Z = 0.8


@dataclass(frozen=True)
class Placement:
    """Uniform ranges, relative to the table-top centre, of one object's initial x, y and yaw."""

    x: tuple[float, float]
    y: tuple[float, float]
    yaw: tuple[float, float]
    z_offset: float = 0.002


class TabletopTask(ManipulationEnv):
    """A Panda at a 0.8 x 0.8 m table (top at z = 0.8 m) with objects placed per ``variant``.

    Keyword arguments are robosuite's ``ManipulationEnv`` ones plus ``variant``,
    ``table_full_size``, ``table_friction`` and ``reward_scale`` (the sparse reward is
    ``reward_scale`` on success, else 0). ``use_object_obs`` is accepted for compatibility with
    robosuite's tasks and ignored: these tasks define no object observables (the pose-token env
    reads poses from MuJoCo).
    """

    #: The variants a subclass supports.
    VARIANTS: tuple[str, ...] = ("D0",)

    def __init__(
        self,
        robots,
        variant: str = "D0",
        table_full_size=(0.8, 0.8, 0.05),
        table_friction=(1.0, 5e-3, 1e-4),
        reward_scale: float | None = 1.0,
        reward_shaping: bool = False,
        use_object_obs: bool = True,
        **kwargs,
    ):
        if variant not in self.VARIANTS:
            raise ValueError(
                f"unknown {type(self).__name__} variant {variant!r}; known: {list(self.VARIANTS)}"
            )
        if reward_shaping:
            raise ValueError(f"{type(self).__name__} has a sparse reward only")
        self.variant = variant
        self.table_full_size = table_full_size
        self.table_friction = table_friction
        self.table_offset = np.array((0.0, 0.0, TABLE_TOP_Z))
        self.reward_scale = reward_scale
        self.reward_shaping = reward_shaping
        self.use_object_obs = use_object_obs
        self.objects: dict = {}
        super().__init__(robots=robots, **kwargs)

    def _build_objects(self) -> dict[str, tuple[object, Placement]]:
        """``{name: (robosuite object with a free joint, its placement)}`` in placement order."""
        raise NotImplementedError

    def _load_model(self):
        super()._load_model()
        robot = self.robots[0]
        robot.robot_model.set_base_xpos(robot.robot_model.base_xpos_offset["table"](self.table_full_size[0]))
        arena = TableArena(
            table_full_size=self.table_full_size,
            table_friction=self.table_friction,
            table_offset=self.table_offset,
        )
        arena.set_origin([0, 0, 0])
        built = self._build_objects()
        self.objects = {name: obj for name, (obj, _) in built.items()}
        self.placement_initializer = SequentialCompositeSampler(name="ObjectSampler")
        for name, (obj, place) in built.items():
            self.placement_initializer.append_sampler(
                UniformRandomSampler(
                    name=f"{name}Sampler",
                    mujoco_objects=obj,
                    x_range=place.x,
                    y_range=place.y,
                    rotation=place.yaw,
                    rotation_axis="z",
                    ensure_object_boundary_in_range=False,
                    ensure_valid_placement=True,
                    reference_pos=self.table_offset,
                    z_offset=place.z_offset,
                    rng=self.rng,
                )
            )
        self.model = ManipulationTask(
            mujoco_arena=arena,
            mujoco_robots=[r.robot_model for r in self.robots],
            mujoco_objects=list(self.objects.values()),
        )

    def _setup_references(self):
        super()._setup_references()
        self.obj_body_ids = {n: self.sim.model.body_name2id(o.root_body) for n, o in self.objects.items()}

    def _reset_internal(self):
        super()._reset_internal()
        if not self.deterministic_reset:
            for pos, quat, obj in self.placement_initializer.sample().values():
                self.sim.data.set_joint_qpos(obj.joints[0], np.concatenate([np.array(pos), np.array(quat)]))

    def body_pos(self, name: str) -> np.ndarray:
        """World position of an object's root body."""
        return np.array(self.sim.data.body_xpos[self.obj_body_ids[name]])

    def site_pos(self, site: str) -> np.ndarray:
        """World position of a site (full MuJoCo name)."""
        return np.array(self.sim.data.site_xpos[self.sim.model.site_name2id(site)])

    def grasped(self, name: str) -> bool:
        return bool(self._check_grasp(gripper=self.robots[0].gripper, object_geoms=self.objects[name]))

    def _check_success(self) -> bool:
        raise NotImplementedError

    def reward(self, action=None) -> float:
        success = 1.0 if self._check_success() else 0.0
        return success * (1.0 if self.reward_scale is None else self.reward_scale)
