"""Every expert draws the same random choices, in the same order, as the version that recorded
``plans_seed0.json``: the demonstrations of a seed depend on that order (see
:mod:`lerobot_actionflow.experts.pick_place`).

``plans_seed0.json`` holds, per expert, the ``rng`` calls of ``plan(default_rng(0))`` (method,
arguments) and the resulting waypoint table. It was recorded from the experts before they were
split into one module per task. A deliberate change of an expert's draws or waypoints changes
its demonstrations: bump its ``version`` and re-record the file with
``python tests/experts/test_draw_order.py > tests/experts/plans_seed0.json``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from lerobot_actionflow.envs.tasks import get_task
from lerobot_actionflow.experts import EXPERTS

GOLDEN = Path(__file__).with_name("plans_seed0.json")


class RecordingRng:
    """A ``Generator`` that logs every call (method and arguments) before passing it on."""

    def __init__(self, rng: np.random.Generator):
        self._rng, self.calls = rng, []

    def __getattr__(self, name):
        fn = getattr(self._rng, name)

        def call(*args, **kwargs):
            self.calls.append([name, [list(a) if isinstance(a, tuple) else a for a in args], kwargs])
            return fn(*args, **kwargs)

        return call


def fake_env(task: str) -> SimpleNamespace:
    """What ``plan`` reads of an env: the task's entities, and (Can) the can's bottom offset."""
    can = SimpleNamespace(bottom_offset=np.array([0.0, 0.0, -0.04]))
    return SimpleNamespace(
        spec_task=get_task(task), robosuite_env=SimpleNamespace(objects=[can], object_id=0)
    )


def record(cls) -> dict:
    expert = cls(fake_env(cls.tasks[0]))
    rng = RecordingRng(np.random.default_rng(0))
    expert.reset(rng)
    waypoints = [
        [w.name, w.gripper, float(w.speed), w.rot_speed, w.tol, int(w.hold), w.timeout, w.track,
         w.on_exit is not None, w.when is not None]
        for w in expert.waypoints
    ]  # fmt: skip
    return {"version": cls.version, "rng_calls": rng.calls, "waypoints": waypoints}


def experts() -> list[type]:
    return list(dict.fromkeys(EXPERTS.values()))


@pytest.mark.parametrize("cls", experts(), ids=lambda c: c.__name__)
def test_plan_draws_and_waypoints_match_the_recording(cls):
    golden = json.loads(GOLDEN.read_text())[cls.__name__]
    got = json.loads(json.dumps(record(cls)))  # tuples -> lists, as in the file
    assert got["version"] == golden["version"]
    for i, (g, want) in enumerate(zip(got["rng_calls"], golden["rng_calls"], strict=False)):
        assert g == want, f"draw {i} differs: {g} != {want}"
    assert len(got["rng_calls"]) == len(golden["rng_calls"])
    assert got["waypoints"] == golden["waypoints"]


if __name__ == "__main__":
    json.dump({cls.__name__: record(cls) for cls in experts()}, sys.stdout, indent=1)
    print()
