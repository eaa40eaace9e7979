"""benchmarks/bench_checkpoint_latency.py: every (checkpoint, IS) cell is timed with IS network
calls per chunk, flow policies and LeRobot's diffusion alike; a cell a policy cannot run is named
with its reason, and a bad checkpoint argument is refused by name."""

import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import bench_checkpoint_latency as bench


class CountingPolicy:
    """Stands in for a flow policy: records the integration steps of each chunk."""

    def __init__(self, solver: str):
        self.config = SimpleNamespace(
            type="actionflow", solver=solver, num_inference_steps=10, time_spacing="uniform"
        )
        self.steps_per_chunk: list[int] = []

    def predict_action_chunk(self, batch):
        self.steps_per_chunk.append(self.config.num_inference_steps)


class CountingDiffusion:
    """Stands in for LeRobot's diffusion: records the scheduler and steps of each chunk."""

    def __init__(self, trained_steps: int):
        from diffusers import DDPMScheduler

        self.config = SimpleNamespace(type="diffusion")
        self.diffusion = SimpleNamespace(
            noise_scheduler=DDPMScheduler(num_train_timesteps=trained_steps), num_inference_steps=None
        )
        self.chunks: list[tuple[str, int]] = []

    def predict_action_chunk(self, batch):
        model = self.diffusion
        self.chunks.append((type(model.noise_scheduler).__name__, model.num_inference_steps))


def test_each_cell_runs_its_own_number_of_network_calls():
    euler, midpoint = CountingPolicy("euler"), CountingPolicy("midpoint")
    cells, skipped = bench.time_cells({"e": (euler, {}), "m": (midpoint, {})}, [2, 4], warmup=1, repeats=3)
    assert sorted(cells) == ["e/IS2", "e/IS4", "m/IS2", "m/IS4"] and skipped == {}
    assert all(c["median_ms"] >= 0 and c["p90_ms"] >= c["median_ms"] for c in cells.values())
    assert euler.steps_per_chunk == [2, 4] * 4  # round-robin, warmup included
    assert midpoint.steps_per_chunk == [1, 2] * 4  # two calls per midpoint step
    override = CountingPolicy("euler")
    cells, skipped = bench.time_cells({"o": (override, {})}, [1, 2], 0, 1, {"o": "midpoint"})
    assert sorted(cells) == ["o/IS2"] and "use a multiple of 2" in skipped["o/IS1"]
    assert override.steps_per_chunk == [1]  # odd IS skipped: a midpoint step makes two calls


def test_diffusion_is_timed_with_ddim_and_with_ddpm_at_its_trained_steps():
    diffusion, flow = CountingDiffusion(trained_steps=10), CountingPolicy("euler")
    cells, skipped = bench.time_cells({"d": (diffusion, {}), "f": (flow, {})}, [2, 10, 20], 0, 1)
    assert sorted(cells) == ["d/IS10", "d/IS2", "f/IS10", "f/IS2", "f/IS20"]
    assert diffusion.chunks == [("DDIMScheduler", 2), ("DDPMScheduler", 10)]
    assert list(skipped) == ["d/IS20"] and "trained with 10 steps" in skipped["d/IS20"]
    with pytest.raises(ValueError, match=r"no IS of \[20\] can be set for \['d'\]"):  # before any timing
        bench.time_cells({"d": (CountingDiffusion(trained_steps=10), {}), "f": (flow, {})}, [20], 0, 1)
    assert len(flow.steps_per_chunk) == 3  # control: the flow policy was not timed again


def test_history_is_filled_so_that_diffusion_with_a_camera_predicts_from_the_batch():
    import torch
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig
    from lerobot.policies.diffusion.modeling_diffusion import DiffusionPolicy

    features = {"observation.state": PolicyFeature(FeatureType.STATE, (4,)),
                "observation.image": PolicyFeature(FeatureType.VISUAL, (3, 32, 32))}  # fmt: skip
    cfg = DiffusionConfig(
        input_features=features, output_features={"action": PolicyFeature(FeatureType.ACTION, (2,))},
        down_dims=(16, 32), crop_shape=None, pretrained_backbone_weights=None, use_group_norm=True,
        num_inference_steps=2,
        device="cpu",
    )  # fmt: skip
    policy = DiffusionPolicy(cfg).eval()
    batch = {"observation.state": torch.zeros(1, 4), "observation.image": torch.zeros(1, 3, 32, 32)}
    filled = bench.fill_history(policy, batch)
    assert set(filled) == {*batch, "observation.images"}
    chunk = policy.predict_action_chunk(filled)
    assert chunk.shape[0] == 1 and chunk.shape[-1] == 2 and torch.isfinite(chunk).all()
    with pytest.raises(KeyError, match=r"observation\.images"):  # control: the plain batch lacks it
        policy.predict_action_chunk(batch)


def test_a_checkpoint_without_a_name_or_directory_is_refused(tmp_path):
    with pytest.raises(SystemExit, match="no_such_dir"):
        bench.main(["--task", "Lift", "--checkpoints", f"a={tmp_path / 'no_such_dir'}"])
    with pytest.raises(SystemExit, match="expected NAME="):
        bench.main(["--task", "Lift", "--checkpoints", str(tmp_path)])
    with pytest.raises(SystemExit, match="the name 'a' is given twice"):
        bench.main(["--task", "Lift", "--checkpoints", f"a={tmp_path}", f"a={tmp_path}"])
    with pytest.raises(SystemExit, match=r"--repeats >= 1.*got 0"):
        bench.main(["--task", "Lift", "--checkpoints", f"a={tmp_path}", "--repeats", "0"])
    with pytest.raises(SystemExit, match=r"--midpoint \['b'\]"):
        bench.main(["--task", "Lift", "--checkpoints", f"a={tmp_path}", "--midpoint", "b"])


class RecordingFlow(CountingPolicy):
    """Stands in for a flow policy with RTC: returns a chunk and records the guidance it got."""

    def __init__(self):
        super().__init__("euler")
        self.config.n_action_steps = 3
        self.calls: list[dict] = []

    def supports_rtc(self):
        return True

    def predict_action_chunk(self, batch, **kw):
        import torch

        self.calls.append(kw)
        return torch.arange(8.0).reshape(1, 8, 1).expand(1, 8, 10)


def test_guided_cells_guide_every_chunk_toward_the_tail_of_a_plain_one():
    policy = RecordingFlow()
    guided = bench.GuidedChunks(policy, {})
    assert policy.calls == [{}]  # the plain chunk whose tail is the leftover
    cells, _ = bench.time_cells({"f": (policy, {}), "f+guided": (guided, {})}, [2], warmup=0, repeats=2)
    assert sorted(cells) == ["f+guided/IS2", "f/IS2"]
    plain, with_guidance = policy.calls[1::2], policy.calls[2::2]
    assert plain == [{}, {}] and all(kw["inference_delay"] == 0 for kw in with_guidance)
    assert all(kw["prev_chunk_left_over"][0, :, 0].tolist() == [3, 4, 5, 6, 7] for kw in with_guidance)
    with pytest.raises(ValueError, match="no guided sampler"):  # LeRobot's diffusion has none
        bench.GuidedChunks(CountingDiffusion(trained_steps=10), {})
    midpoint = RecordingFlow()
    midpoint.config.solver = "midpoint"
    with pytest.raises(ValueError, match="steers Euler steps"):
        bench.GuidedChunks(midpoint, {})


def test_only_the_named_checkpoints_sample_with_their_exported_samplers():
    from lerobot_actionflow.policies.exported import ArtefactKey

    def with_artefacts(*keys):
        policy = CountingPolicy("euler")
        policy.exported_samplers = SimpleNamespace(keys=lambda: list(keys))
        return policy

    keys = (ArtefactKey("cpu", 2, 1), ArtefactKey("cpu", 2, 1, guided=True))
    policies = {"eager": (with_artefacts(*keys), {}), "exported": (with_artefacts(*keys), {})}
    policies["diffusion"] = (CountingDiffusion(trained_steps=10), {})  # has no such attribute
    in_use = bench.choose_samplers(policies, ["exported"])
    assert in_use == {"exported": ["K=2 batch 1 on cpu", "guided K=2 batch 1 on cpu"]}
    assert policies["eager"][0].exported_samplers is None
    assert policies["exported"][0].exported_samplers is not None
    # a checkpoint named --exported without an accepted artefact is refused by name
    with pytest.raises(ValueError, match="--exported none: the checkpoint has no exported sampler"):
        bench.choose_samplers({"none": (with_artefacts(), {})}, ["none"])
