"""`lerobot-rollout --robot.type=actionflow_sim` runs a policy checkpoint for one short episode.

In-process (the test session has paid LeRobot's and robosuite's imports already): the CLI's
``main`` with patched ``sys.argv``; the signal handlers it installs are restored afterwards.
"""

import json
import logging
import signal
import sys

import pytest
from lerobot.scripts import lerobot_rollout

from lerobot_actionflow.evaluation.untrained import save_untrained_actionflow
from lerobot_actionflow.robots.processor import add_robot_observation_step

_SIGNALS = [getattr(signal, s) for s in ("SIGINT", "SIGTERM", "SIGHUP", "SIGQUIT") if hasattr(signal, s)]


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    path = save_untrained_actionflow("Lift", tmp_path_factory.mktemp("ckpt") / "pretrained_model")
    assert add_robot_observation_step(path) is False  # a new checkpoint needs no preparing
    return path


def _run_rollout(argv: list[str], monkeypatch) -> None:
    handlers = {s: signal.getsignal(s) for s in _SIGNALS}
    root = logging.getLogger()
    root_handlers, root_level = list(root.handlers), root.level
    monkeypatch.setattr(sys, "argv", ["lerobot-rollout", *argv])
    try:
        lerobot_rollout.main()
    finally:
        for s, h in handlers.items():
            signal.signal(s, h)
        root.handlers[:], root.level = root_handlers, root_level


def _rollout_one_episode(inference: str, checkpoint, tmp_path, monkeypatch) -> dict:
    results = tmp_path / "episodes.jsonl"
    argv = [
        "--robot.type=actionflow_sim", "--robot.task=Lift", "--robot.episode_length=10",
        f"--robot.results_path={results}", f"--robot.calibration_dir={tmp_path / 'calib'}",
        f"--policy.path={checkpoint}", "--policy.device=cpu", f"--inference.type={inference}",
        "--fps=20", "--play_sounds=false",
    ]  # fmt: skip
    _run_rollout(argv, monkeypatch)
    # The robot ended the rollout itself once its one episode was over (here by time: the
    # policy is untrained), after the policy had driven it.
    (episode,) = [json.loads(x) for x in results.read_text().splitlines()]
    assert episode["task"] == "Lift" and episode["steps"] == 10 and not episode["success"]
    return episode


@pytest.mark.slow
@pytest.mark.parametrize("inference", ["sync", "rtc"])
def test_lerobot_rollout_runs_an_episode_on_the_simulated_robot(inference, checkpoint, tmp_path, monkeypatch):
    episode = _rollout_one_episode(inference, checkpoint, tmp_path, monkeypatch)
    assert episode["actions_received"] >= 5, episode


@pytest.mark.slow
def test_rtc_engine_feeds_the_simulated_robot(checkpoint, tmp_path, monkeypatch):
    """The robot side of ``--inference.type=rtc`` (observations through ``hw_features`` and the
    policy's preprocessor on LeRobot's RTC thread, actions from its queue), with a test double
    for the policy's RTC: plain chunks that ignore the leftover. LeRobot's RTC thread passes one
    observation frame per call, so the double keeps the policy's observation history as
    ``select_action`` does."""
    import torch
    from lerobot.policies.utils import populate_queues

    from lerobot_actionflow.policies.actionflow.modeling_actionflow import ActionflowPolicy
    from lerobot_actionflow.schema import ACTION_KEY

    plain = ActionflowPolicy.predict_action_chunk
    calls = []

    def predict_action_chunk(self, batch, inference_delay=0, prev_chunk_left_over=None, **kw):
        calls.append(inference_delay)
        self._queues = populate_queues(self._queues, self.check_observation(batch, with_time=False))
        history = {k: torch.stack(list(q), dim=1) for k, q in self._queues.items() if k != ACTION_KEY}
        return plain(self, history)

    monkeypatch.setattr(ActionflowPolicy, "supports_rtc", lambda self: True)
    monkeypatch.setattr(ActionflowPolicy, "predict_action_chunk", predict_action_chunk)
    episode = _rollout_one_episode("rtc", checkpoint, tmp_path, monkeypatch)
    assert calls and episode["actions_received"] >= 5, (calls, episode)
