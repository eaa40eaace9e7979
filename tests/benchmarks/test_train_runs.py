"""benchmarks/train_runs.py: a finished run is not trained again, an interrupted one resumes from
its last checkpoint with LeRobot's --resume, and one without a checkpoint starts over."""

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import train_runs

#: Stands in for actionflow-train: records its arguments, then writes the checkpoint of --steps
#: (or, with FAKE_NO_CHECKPOINT in the arguments, ends without one).
FAKE_TRAIN = """
import json, os, sys
from pathlib import Path
args = sys.argv[1:]
record = Path(os.environ["FAKE_CALLS"])
record.write_text(json.dumps((json.loads(record.read_text()) if record.exists() else []) + [args]))
if "FAKE_NO_CHECKPOINT" not in args:
    final = Path(os.environ["FAKE_RUN"]) / "checkpoints" / "000020" / "pretrained_model"
    final.mkdir(parents=True, exist_ok=True)
"""


@pytest.fixture
def fake_train(tmp_path, monkeypatch):
    script = tmp_path / "fake_train.py"
    script.write_text(FAKE_TRAIN)
    monkeypatch.setattr(train_runs, "train_command", lambda: [sys.executable, str(script)])
    run, calls = tmp_path / "run", tmp_path / "calls.json"
    env = {"FAKE_RUN": str(run), "FAKE_CALLS": str(calls)}

    def train(args=("--steps=20",)):
        return train_runs.train_run(run, list(args), 20, tmp_path / "train.log", env)

    return run, calls, train


def test_a_new_run_trains_with_its_arguments_and_a_finished_one_is_left_alone(fake_train):
    run, calls, train = fake_train
    assert train() is not None
    assert train_runs.final_checkpoint(run, 20) == run / "checkpoints" / "000020" / "pretrained_model"
    assert json.loads(calls.read_text()) == [["--steps=20"]]
    assert train() is None  # finished: nothing runs
    assert len(json.loads(calls.read_text())) == 1


def test_an_interrupted_run_resumes_from_its_last_checkpoint(fake_train):
    run, calls, train = fake_train
    last = run / "checkpoints" / "last" / "pretrained_model"
    last.mkdir(parents=True)
    (run / "checkpoints" / "000010" / "kept.txt").parent.mkdir(parents=True)
    (run / "checkpoints" / "000010" / "kept.txt").write_text("earlier checkpoint")
    train()
    (args,) = json.loads(calls.read_text())
    assert args == ["--resume=true", f"--config_path={last / 'train_config.json'}"]
    assert (run / "checkpoints" / "000010" / "kept.txt").exists()


def test_a_run_without_a_checkpoint_starts_over_and_a_run_that_saves_nothing_fails(fake_train):
    run, calls, train = fake_train
    (run / "stale.txt").parent.mkdir(parents=True)
    (run / "stale.txt").write_text("from an interrupted start")
    train()
    assert not (run / "stale.txt").exists()
    assert json.loads(calls.read_text()) == [["--steps=20"]]
    other = run.with_name("other")
    with pytest.raises(SystemExit, match="without its checkpoint"):
        env = {"FAKE_RUN": str(other), "FAKE_CALLS": str(calls)}
        train_runs.train_run(other, ["FAKE_NO_CHECKPOINT"], 20, other / "log", env)
