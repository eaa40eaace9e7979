"""The in-memory frame source gives exactly LeRobotDataset's items, for every index."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lerobot_actionflow.data.in_memory import InMemoryLeRobotDataset
from lerobot_actionflow.schema import ACTION_KEY, STATE_KEY, image_key
from tests.data.conftest import REPO_ID
from tests.synthetic_dataset import make_camera_dataset


def _policy_config(policy: str):
    """The policy's default config: its delta indices are what lerobot-train resolves."""
    if policy == "actionflow":
        from lerobot_actionflow.policies.actionflow.configuration_actionflow import ActionflowConfig

        return ActionflowConfig()
    from lerobot_actionflow.policies.euclidean_flow.configuration_euclidean_flow import EuclideanFlowConfig

    return EuclideanFlowConfig()


def _open(root, repo_id: str, policy: str | None, **kw):
    from lerobot.datasets.dataset_metadata import LeRobotDatasetMetadata
    from lerobot.datasets.factory import resolve_delta_timestamps
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    meta = LeRobotDatasetMetadata(repo_id, root=root)
    delta = None if policy is None else resolve_delta_timestamps(_policy_config(policy), meta)
    return LeRobotDataset(repo_id, root=root, delta_timestamps=delta, **kw)


def mismatches(expected: list[dict], got: list[dict]) -> list[str]:
    """Every (item, key) where ``got`` differs from ``expected``: key order, type, dtype, shape
    or value (tensors bit for bit, strings exactly)."""
    out = []
    for n, (a, b) in enumerate(zip(expected, got, strict=True)):
        if list(a) != list(b):
            out.append(f"item {n}: keys {list(a)} != {list(b)}")
            continue
        for key, va in a.items():
            vb = b[key]
            if isinstance(va, torch.Tensor):
                same = (
                    isinstance(vb, torch.Tensor)
                    and va.dtype == vb.dtype
                    and va.shape == vb.shape
                    and torch.equal(va, vb)
                )
            else:
                same = type(va) is type(vb) and va == vb
            if not same:
                out.append(f"item {n}: {key}")
    return out


def _all_items(ds, order) -> list[dict]:
    return [ds[int(i)] for i in order]


@pytest.fixture(scope="module", params=["actionflow", "euclidean_flow"])
def lift_pair(request, lift_three_episodes):
    """(LeRobotDataset, InMemoryLeRobotDataset, every index in a shuffled order) of the collected
    3-episode Lift dataset with the policy's delta timestamps."""
    ds = _open(lift_three_episodes, REPO_ID, request.param)
    order = np.random.default_rng(0).permutation(len(ds))
    return ds, InMemoryLeRobotDataset(ds), order, _all_items(ds, order)


def test_every_index_equals_lerobot_dataset(lift_pair):
    ds, fast, order, expected = lift_pair
    assert ds.num_episodes == 3 and len(fast) == len(ds) == ds.meta.total_frames
    # Both windows reach past the episode ends: the comparison covers padding and clamping.
    pads = torch.stack([item[f"{ACTION_KEY}_is_pad"] for item in expected])
    assert pads.any() and not pads.all()
    assert not mismatches(expected, fast.__getitems__(order.tolist()))
    assert not mismatches(expected[:5], [fast[int(i)] for i in order[:5]])


def test_a_frame_off_by_one_is_caught(lift_pair, monkeypatch):
    """Controls: each perturbation moves one frame by one and must make the comparison fail."""
    _, fast, order, expected = lift_pair
    # (a) the last action of every window read one frame later
    shifted = dict(fast._deltas)
    shifted[ACTION_KEY] = shifted[ACTION_KEY].clone()
    shifted[ACTION_KEY][-1] += 1
    monkeypatch.setattr(fast, "_deltas", shifted)
    assert mismatches(expected, fast.__getitems__(order.tolist()))
    monkeypatch.undo()
    # (b) the end of episode 0 one frame early (padding and clamping at that boundary)
    ends = fast._ep_to.clone()
    ends[0] -= 1
    monkeypatch.setattr(fast, "_ep_to", ends)
    bad = mismatches(expected, fast.__getitems__(order.tolist()))
    monkeypatch.undo()
    assert bad
    # (c) one frame's state replaced by the next frame's: only windows holding that frame differ
    state = fast._columns[STATE_KEY].clone()
    state[20] = state[21]
    monkeypatch.setitem(fast._columns, STATE_KEY, state)
    bad = mismatches(expected, fast.__getitems__(order.tolist()))
    assert bad and all(line.endswith(STATE_KEY) for line in bad)
    monkeypatch.undo()
    assert not mismatches(expected, fast.__getitems__(order.tolist()))


def test_episode_subset_equals_lerobot_dataset(lift_three_episodes):
    """Opened on episodes [0, 2] (as an eval split does): rows are renumbered, indices are not."""
    ds = _open(lift_three_episodes, REPO_ID, "actionflow", episodes=[0, 2])
    fast = InMemoryLeRobotDataset(ds)
    assert ds.absolute_to_relative_idx is not None and len(fast) == len(ds)
    order = range(len(ds))
    assert not mismatches(_all_items(ds, order), fast[:])
    assert fast.num_episodes == 2 and fast.episodes == [0, 2]


def test_without_delta_timestamps(lift_three_episodes):
    ds = _open(lift_three_episodes, REPO_ID, None)
    assert not mismatches(_all_items(ds, range(len(ds))), InMemoryLeRobotDataset(ds)[:])


def test_get_batch_is_the_collated_items(lift_pair):
    from torch.utils.data import default_collate

    _, fast, order, expected = lift_pair
    batch = fast.get_batch(order[:7])
    collated = default_collate(expected[:7])
    assert list(batch) == list(collated)
    for key, value in collated.items():
        assert value == batch[key] if key == "task" else torch.equal(value, batch[key]), key


@pytest.mark.parametrize("image_dtype", ["video", "image"])
def test_camera_features_equal_lerobot_dataset(tmp_path, image_dtype):
    """Video and image features, decoded per item and from the uint8 cache, with uint8 and float
    outputs and an image transform, over 3 episodes and 2 tasks."""
    root = make_camera_dataset(tmp_path / "cams", image_dtype)
    cam = image_key("wrist")
    for return_uint8 in (True, False):
        kw = {"return_uint8": return_uint8, "image_transforms": lambda x: x.flip(-1)}
        ds = _open(root, "local/cameras", "actionflow", **kw)
        expected = _all_items(ds, range(len(ds)))
        assert expected[0][cam].shape[-4:] == (2, 3, 32, 32)
        assert {item["task"] for item in expected} == {"task 0", "task 1"}
        for cache in (False, True):
            fast = InMemoryLeRobotDataset(ds, image_cache=cache)
            assert bool(fast._cameras.cached) == cache
            assert not mismatches(expected, fast.__getitems__(list(range(len(ds))))), (return_uint8, cache)


def test_bad_input_is_refused_by_name(lift_three_episodes):
    with pytest.raises(TypeError, match="LeRobotDataset"):
        InMemoryLeRobotDataset([{"index": 0}])
    fast = InMemoryLeRobotDataset(_open(lift_three_episodes, REPO_ID, None))
    with pytest.raises(IndexError, match=f"index {len(fast)} is out of range"):
        fast.__getitems__([0, len(fast)])
    assert torch.equal(fast[-1]["index"], fast[len(fast) - 1]["index"])
