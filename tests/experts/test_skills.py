"""The pick and place skills and their typed state, on a stub env (no simulation).

What users of the skills rely on: a pick follows the object until the descent begins and then
keeps its grasp; a place puts the held object's origin at the goal whatever the offset in the
fingers; a relocation decides once and sets the object down clear of the others; the action
has the schema's layout.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from lerobot_actionflow import rotations
from lerobot_actionflow.experts import frames as fr
from lerobot_actionflow.experts.pick_place import PickPlaceExpert
from lerobot_actionflow.experts.pose import Pose, token_pose
from lerobot_actionflow.experts.relocate import (
    RELOCATE_FROM,
    SPOT_CLEARANCE,
    SPOT_RANGE,
    Relocate,
    RelocateDraws,
    Relocation,
    lean_pick,
)
from lerobot_actionflow.experts.skills import (
    Grasp,
    Pick,
    PickDraws,
    PickParams,
    Place,
    PlaceDraws,
    PlaceParams,
)
from lerobot_actionflow.schema import ACTION_DIM, ACTION_GRIPPER_INDEX, ENV_POSES

BASE = np.array([-0.56, 0.0, 0.912])  # the Panda's base in robosuite's table scenes


def expert() -> PickPlaceExpert:
    robot = SimpleNamespace(base_pos=BASE)
    return PickPlaceExpert(SimpleNamespace(robosuite_env=SimpleNamespace(robots=[robot])))


def obs_of(*poses: Pose) -> dict:
    """Observation with the EEF (top-down, heading 0, over the table) then ``poses``."""
    eef = Pose(fr.top_down(0.0), np.array([-0.1, 0.0, 1.0]))
    return {ENV_POSES: np.stack([rotations.rp_to_pose7(p.r, p.p) for p in (eef, *poses)])}


def test_pick_tracks_the_object_until_the_descent_then_keeps_its_grasp():
    params = PickParams(order=4, grasp_dz=0.0, xy_noise=0.0)
    grasp = Grasp(row=1)
    pick = Pick(expert(), grasp, params, PickDraws.draw(np.random.default_rng(0), params, 1.0))
    cube = Pose(rotations.yaw_matrix(0.3), np.array([0.05, 0.02, 0.82]))
    moved = Pose(cube.r, cube.p + np.array([0.03, -0.01, 0.0]))
    a0, a1 = pick.above(obs_of(cube)), pick.above(obs_of(moved))
    np.testing.assert_allclose(a1.p - a0.p, [0.03, -0.01, 0.0], atol=1e-12)
    g = pick.grasp_pose(obs_of(moved))
    assert grasp.eef is g and pick.grasp_pose(obs_of(cube)) is g  # frozen from the descent on
    # A cube's grasp heading is its yaw plus a multiple of pi / 2, up to the drawn xy noise (0).
    k = fr.wrap(fr.heading(g.r) - 0.3) / (math.pi / 2)
    assert abs(k - round(k)) < 1e-9
    np.testing.assert_allclose(g.p, moved.p + np.array([0.0, 0.0, pick.draws.dz]), atol=1e-12)
    # The lift keeps the grasp orientation and rises straight up.
    lift = pick.lift(obs_of(moved))
    np.testing.assert_allclose(lift.p - g.p, [0.0, 0.0, pick.draws.lift], atol=1e-12)


@pytest.mark.parametrize("offset, dz", [((0.0, 0.02), 0.0), ((0.0, 0.02, 0.0), 0.02)])
def test_a_3d_grasp_offset_gives_the_grasp_height_and_a_2d_one_does_not(offset, dz):
    """On an object lying on its side (local y up), a 3-D ``grasp_offset`` is a point whose
    height is the grasp's; a 2-D one keeps the origin's height."""
    params = PickParams(order=2, grasp_dz=0.0, xy_noise=0.0, grasp_offset=offset)
    pick = Pick(expert(), Grasp(row=1), params, PickDraws.draw(np.random.default_rng(1), params, 1.0))
    lying = Pose(
        rotations.axis_angle_to_matrix(np.array([math.pi / 2, 0.0, 0.0])), np.array([0.0, 0.1, 0.82])
    )
    g = pick.target(obs_of(lying))
    np.testing.assert_allclose(g.p[:2], lying.p[:2], atol=1e-12)  # local y is vertical: same xy
    np.testing.assert_allclose(g.p[2], lying.p[2] + dz + pick.draws.dz, atol=1e-12)


def test_place_puts_the_held_object_at_the_goal_whatever_its_offset_in_the_fingers():
    rng = np.random.default_rng(2)
    in_hand = Pose(rotations.axis_angle_to_matrix(rng.normal(size=3) * 0.2), np.array([0.01, -0.006, 0.03]))
    grasp = Grasp(row=1, eef=Pose(fr.top_down(0.4), np.array([0.0, 0.0, 0.9])), in_hand=in_hand)
    goal = [np.array([0.1, 0.2, 0.85])]
    params = PlaceParams(carry_z=1.0)
    place = Place(grasp, lambda obs: goal[0], params, PlaceDraws.draw(rng, params, 1.0))
    obs = obs_of()
    release = place.release_pose(obs)
    np.testing.assert_allclose(release.r, grasp.eef.r)  # the grasp's orientation by default
    np.testing.assert_allclose((release @ in_hand).p, goal[0] + [0, 0, place.draws.release_dz], atol=1e-12)
    goal[0] = goal[0] + 0.05  # read once, when the carry begins
    np.testing.assert_allclose(place.release_pose(obs).p, release.p)
    assert place.carry(obs).p[2] >= 1.0
    # With a place orientation, the object still lands on the goal.
    turned = Grasp(row=1, eef=grasp.eef, in_hand=in_hand)
    r = fr.top_down(-0.7)
    place = Place(turned, lambda obs: goal[0], params, place.draws, rot=lambda obs: r)
    np.testing.assert_allclose((place.eef_at(obs, 0.0) @ in_hand).p, goal[0], atol=1e-12)
    np.testing.assert_allclose(turned.place.r, r)
    # eef_for is the inverse of holding: T_eef G = T_obj.
    target = Pose(rotations.yaw_matrix(1.0), np.array([0.3, -0.1, 0.9]))
    held = grasp.eef_for(target) @ in_hand
    np.testing.assert_allclose(held.r, target.r, atol=1e-12)
    np.testing.assert_allclose(held.p, target.p, atol=1e-12)


@pytest.mark.parametrize("distance", [0.60, 0.79])
def test_relocation_decides_once_and_sets_the_object_down_clear_of_the_others(distance):
    x = expert()
    piece = Pose(np.eye(3), np.array([BASE[0] + distance, 0.0, 0.83]))
    # Another entity right where the straight-line spot would be.
    other = Pose(np.eye(3), np.array([BASE[0] + 0.64, 0.0, 0.83]))
    obs = obs_of(piece, other)
    rel = Relocation(row=1, others=(2,))
    params = lean_pick(4, 0.0)
    relocate = Relocate(x, rel, params, RelocateDraws.draw(np.random.default_rng(3), params, 1.0))
    assert relocate.far(obs) is (distance >= RELOCATE_FROM)
    if rel.far:
        assert SPOT_RANGE[0] <= np.linalg.norm(rel.spot[:2] - BASE[:2]) <= SPOT_RANGE[1]
        assert np.linalg.norm(rel.spot[:2] - other.p[:2]) >= SPOT_CLEARANCE
        np.testing.assert_allclose(rel.spot[2], piece.p[2] + relocate.draws.drop)
    else:
        assert rel.spot is None
    # Decided once: moving the piece later changes nothing.
    moved = obs_of(Pose(np.eye(3), np.array([BASE[0] + 1.4 - distance, 0.0, 0.83])), other)
    assert relocate.far(moved) is rel.far
    assert all(w.when is not None for w in relocate.waypoints())


def test_lean_tilts_the_wrist_towards_the_robot_only_far_away():
    """A leaning pick leans by the ramp from LEAN_START to LEAN_FULL of the grasp point's reach,
    with the wrist (back along the approach axis) towards the robot base."""
    params = lean_pick(4, 0.0)
    draws = PickDraws.draw(np.random.default_rng(4), params, 1.0)
    for reach, leaning in [(0.60, False), (0.80, True)]:
        obj = Pose(rotations.yaw_matrix(0.2), np.array([BASE[0] + reach, 0.05, 0.83]))
        r = Pick(expert(), Grasp(row=1), params, draws).target(obs_of(obj)).r
        wrist = -r[:, 2]
        to_robot = BASE[:2] - obj.p[:2]
        tilt = math.asin(np.clip(np.dot(wrist[:2], to_robot / np.linalg.norm(to_robot)), -1, 1))
        if leaning:
            assert tilt == pytest.approx(draws.lean_max, abs=0.05)
        else:
            assert abs(tilt) < 1e-9


def test_action_has_the_schema_layout():
    pose = Pose(rotations.axis_angle_to_matrix(np.array([0.3, -1.2, 2.0])), np.array([0.1, -0.2, 1.0]))
    a = fr.action(pose, 1.0)
    assert a.shape == (ACTION_DIM,) and a.dtype == np.float32 and a[ACTION_GRIPPER_INDEX] == 1.0
    r, p = rotations.pose9_to_rp(a[:ACTION_GRIPPER_INDEX].astype(np.float64))
    np.testing.assert_allclose(r, pose.r, atol=1e-6)
    np.testing.assert_allclose(p, pose.p, atol=1e-6)
    # Pose composition follows rotations' (r, p) order: T T^-1 = I, and from_pose7 round-trips.
    eye = pose @ pose.inverse()
    np.testing.assert_allclose(eye.r, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(eye.p, 0.0, atol=1e-12)
    back = token_pose({ENV_POSES: rotations.rp_to_pose7(pose.r, pose.p)[None]}, 0)
    np.testing.assert_allclose(back.r, pose.r, atol=1e-12)
