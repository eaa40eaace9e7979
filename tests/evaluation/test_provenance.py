"""A stored cell names the weights it measured; cells of other weights are never added beside it."""

import os
import shutil

import pytest

from lerobot_actionflow.evaluation.provenance import (
    DIGEST_KEY,
    check_same_weights,
    machine_description,
    weights_digest,
)


def _checkpoint(path, payload: bytes):
    path.mkdir(parents=True)
    (path / "model.safetensors").write_bytes(payload)
    return path


def test_the_digest_follows_the_weights_bytes_not_the_folder(tmp_path):
    a = _checkpoint(tmp_path / "a", b"\x00weights" * 1000)
    copy = tmp_path / "copy"
    shutil.copytree(a, copy)
    assert weights_digest(a) == weights_digest(copy) and len(weights_digest(a)) == 64
    retrained = _checkpoint(tmp_path / "b", b"\x01weights" + b"\x00weights" * 999)  # one byte differs
    assert weights_digest(retrained) != weights_digest(a)
    with pytest.raises(FileNotFoundError, match=r"no weights file .*empty/model\.safetensors"):
        weights_digest(tmp_path / "empty")


def test_cells_of_other_weights_are_refused_and_cells_without_a_digest_are_let_through(caplog):
    mine, other = "a" * 64, "b" * 64
    check_same_weights([{DIGEST_KEY: mine}, {DIGEST_KEY: mine}], mine, "ckpt", "advice")  # control
    with pytest.raises(ValueError, match=r"ckpt now holds weights aaaaaaaaaaaa.*bbbbbbbbbbbb.*advice"):
        check_same_weights([{DIGEST_KEY: mine}, {DIGEST_KEY: other}], mine, "ckpt", "advice")
    check_same_weights([{"pc_success": 1.0}], mine, "ckpt", "advice")  # older cells: unknown weights
    assert "1 stored cells of ckpt carry no weights digest" in caplog.text


def test_the_machine_is_named_by_its_cpu_model_and_count(tmp_path):
    cpuinfo = tmp_path / "cpuinfo"
    cpuinfo.write_text(
        "processor\t: 0\nvendor_id\t: AuthenticAMD\nmodel name\t: AMD EPYC 9B14\n\nmodel name\t: X\n"
    )
    assert machine_description(cpuinfo=cpuinfo) == f"AMD EPYC 9B14, {os.cpu_count()} CPUs"
    cpuinfo.write_text("processor\t: 0\n")  # no model name (e.g. some ARM kernels): the platform's
    fallback = machine_description(cpuinfo=cpuinfo)
    assert "AMD EPYC" not in fallback and fallback.endswith(f", {os.cpu_count()} CPUs")
    assert machine_description(cpuinfo=tmp_path / "missing") == fallback
