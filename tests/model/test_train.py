"""Training: determinism, resuming, exported weights, and data parallel under torchrun."""

from __future__ import annotations

import json
import os
import re
import shutil
import socket
import subprocess
import sys

import pytest
import torch

from head360cli.errors import FileFormatError
from head360cli.model.train import CHECKPOINT, TrainConfig, load_generator, save_generator, train
from tests.model.test_generator import TINY

CFG = TrainConfig(identities=2, steps=4, batch=2, log_every=2, checkpoint_every=2)


def _weights(run):
    return torch.load(run / CHECKPOINT, weights_only=False)["model"]


@pytest.mark.slow
def test_same_seed_same_run_and_resume_continues_it(tmp_path):
    a = train(tmp_path / "a", CFG, TINY, progress=False)
    b = train(tmp_path / "b", CFG, TINY, progress=False)
    assert a["step"] == 4 and a["l1"] == b["l1"]
    for k, v in _weights(tmp_path / "a").items():
        assert torch.equal(v, _weights(tmp_path / "b")[k]), k
    # Interrupted after two steps, then resumed to four: the same weights as four in one go.
    train(tmp_path / "c", CFG, TINY, progress=False, stop_at=2)
    c = train(tmp_path / "c", CFG, TINY, progress=False)
    assert c["step"] == 4
    for k, v in _weights(tmp_path / "a").items():
        assert torch.allclose(v, _weights(tmp_path / "c")[k], atol=1e-6), k
    lines = [json.loads(x) for x in (tmp_path / "c" / "log.jsonl").read_text().splitlines()]
    assert [x["step"] for x in lines] == [2, 4] and all(x["l1"] > 0 for x in lines)


def test_exported_weights_load_and_render(tmp_path):
    train(tmp_path / "run", CFG, TINY, progress=False)
    info = save_generator(tmp_path / "run" / CHECKPOINT, tmp_path / "g.pt")
    assert info["step"] == 4 and info["bytes"] < 5_000_000
    gen, codes = load_generator(tmp_path / "g.pt")
    assert codes.shape == (2, TINY.code_dim) and gen.cfg == TINY
    assert not gen.training


def test_init_starts_a_new_run_from_exported_weights(tmp_path):
    import dataclasses

    train(tmp_path / "run", CFG, TINY, progress=False)
    save_generator(tmp_path / "run" / CHECKPOINT, tmp_path / "g.pt")
    shipped = torch.load(tmp_path / "g.pt", weights_only=True)
    other = dataclasses.replace(TINY, hidden=TINY.hidden * 2)  # the weights' config wins
    # on a corpus with soft hairlines: the new weights record them, for run time
    more = dataclasses.replace(CFG, init=str(tmp_path / "g.pt"), seed=1, soft_hair=True)
    train(tmp_path / "more", more, other, progress=False, stop_at=1)
    state = torch.load(tmp_path / "more" / CHECKPOINT, weights_only=False)
    assert state["generator_config"] == dataclasses.replace(TINY, soft_hair=True).to_dict()
    assert state["train_config"]["init"] == str(tmp_path / "g.pt")
    moved = [k for k, v in shipped["generator"].items()
             if not torch.equal(v, state["model"]["generator." + k])]
    # One step from the weights: every trained tensor moved a little, none is re-drawn.
    assert moved and all(
        (state["model"]["generator." + k] - shipped["generator"][k]).abs().max() < 0.05
        for k in moved)
    assert (state["model"]["codes"] - shipped["codes"]).abs().max() < 0.05
    (tmp_path / "junk.pt").write_bytes(b"not weights")
    with pytest.raises(FileFormatError, match="expected head360 generator weights"):
        train(tmp_path / "junk", dataclasses.replace(more, init=str(tmp_path / "junk.pt")),
              TINY, progress=False, stop_at=1)
    with pytest.raises(ValueError, match="expected codes for 3 identities, found 2"):
        train(tmp_path / "bad", dataclasses.replace(more, identities=3), TINY,
              progress=False, stop_at=1)


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("torchrun") is None and not os.path.exists(
    os.path.join(os.path.dirname(sys.executable), "torchrun")), reason="torchrun missing")
def test_two_process_data_parallel_on_cpu(tmp_path):
    torchrun = shutil.which("torchrun") or os.path.join(os.path.dirname(sys.executable),
                                                        "torchrun")
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    with socket.socket() as s:  # a free port: a fixed one failed once, still held
        s.bind(("127.0.0.1", 0))
        port = str(s.getsockname()[1])
    cmd = [torchrun, "--nproc_per_node", "2", "--master_port", port, "-m", "head360cli",
           "train", str(tmp_path / "ddp"), "--preset", "tiny", "--steps", "3", "-n", "2",
           "--batch", "1", "-q", "--export", str(tmp_path / "ddp.pt")]
    done = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    state = torch.load(tmp_path / "ddp" / CHECKPOINT, weights_only=False)
    assert state["step"] == 3 and len(state["rng"]) == 2  # both processes' samplers
    assert state["rng"][0] != state["rng"][1]  # each drew its own views
    gen, _ = load_generator(tmp_path / "ddp.pt")
    assert gen.cfg.render_res == 16


def test_cli_train_says_the_init_weights_configuration_replaces_preset(run_cli, tmp_path):
    """With --init the weights' own configuration is used: a --preset or ablation flag
    given beside it was dropped silently; now a warning names it (here before the junk
    weights are refused)."""
    (tmp_path / "junk.pt").write_bytes(b"not weights")
    r = run_cli("train", tmp_path / "run", "--init", tmp_path / "junk.pt", "--preset",
                "tiny", "--planes", "tri", "--steps", "1", "-n", "2")
    assert r.code == 5 and "expected head360 generator weights" in r.err
    assert "--preset and --planes are not used with --init" in r.err


@pytest.mark.parametrize(("args", "says"), [
    (("--group", "0"), "--group and --workers >= 1, found 0 and 1"),
    (("--workers", "-2"), "--group and --workers >= 1, found 1 and -2"),
    (("--lr", "-1"), "finite --lr > 0, found -1.0"),
    (("--lr", "nan"), "finite --lr > 0, found nan"),
    (("--minutes", "-1"), "--minutes >= 0 (0: no limit), found -1.0"),
])
def test_cli_train_refuses_settings_that_cannot_train(run_cli, tmp_path, args, says):
    """Each of these trained (or ended in an internal error) before being refused."""
    r = run_cli("train", tmp_path / "run", "--preset", "tiny", "--steps", "1", "-n", "2", *args)
    assert r.code == 3 and says in r.err, r.err
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize(("args", "says"), [
    (("--lr", "inf"), "finite --lr > 0, found inf"),
    (("--minutes", "-0.5"), "--minutes >= 0 (0: no limit), found -0.5"),
])
def test_cli_train_hair_prior_refuses_settings_that_cannot_train(run_cli, tmp_path, args,
                                                                 says):
    out = tmp_path / "prior.pt"
    r = run_cli("train-hair-prior", "-o", out, "--heads", "1", "--steps", "1", *args)
    assert r.code == 3 and says in r.err, r.err
    assert not out.exists()


def test_cli_train_hair_prior_refuses_an_output_it_cannot_write_before_rendering(run_cli,
                                                                                   tmp_path):
    """``-o prior.txt`` rendered 600 heads and trained before writing the weights under a
    text name; its help printed the learning rate's floor as '5 %%'."""
    for out, says in ((tmp_path / "prior.txt", "ending in .pt, found"),
                      (tmp_path / "none" / "p.pt", "output folder")):
        r = run_cli("train-hair-prior", "-o", out, "--steps", "1")
        assert r.code == 3 and says in r.err, r.err
    assert not any(tmp_path.iterdir())
    text = " ".join(run_cli("train-hair-prior", "--help").out.split())
    assert "decays linearly to 5 % of it" in text


def test_cli_train_resume_names_the_options_its_checkpoint_replaces(run_cli, tmp_path):
    """Resuming used the checkpoint's configuration and dropped --preset, -n, --lr...
    without a word; a run already at --steps said 'trained to step None: L1 None'."""
    run = tmp_path / "run"
    r = run_cli("train", run, "--preset", "tiny", "--steps", "1", "-n", "2", "--json")
    assert r.code == 0, r.err
    assert json.loads(r.out)["trained"] is True
    r = run_cli("train", run, "--preset", "cpu", "--steps", "1", "-n", "3", "--lr", "0.001")
    assert r.code == 0, r.err
    assert ("--preset and --identities and --lr are not used when resuming" in r.err
            and "its checkpoint's configuration is used" in r.err)
    assert "is at step 1 already (--steps 1): nothing was trained" in r.err
    assert "at step 1, as before" in r.out
    r = run_cli("train", run, "--steps", "2", "--json")
    assert r.code == 0 and "not used" not in r.err
    out = json.loads(r.out)
    assert out["trained"] is True and out["last"]["step"] == 2


@pytest.mark.parametrize(("field", "value", "expected"), [
    ("lr", -1.0, "finite and > 0"), ("lr", float("nan"), "finite and > 0"),
    ("batch", 0, ">= 1"), ("identities", 0, ">= 1"), ("workers", 0, ">= 1"),
    ("steps", -1, ">= 0"), ("minutes", -0.5, "finite and >= 0"),
    ("bald_share", 1.5, "in [0, 1]"), ("featured_share", float("nan"), "in [0, 1]"),
    ("checkpoint_every", 0, ">= 1"),
])
def test_train_config_refuses_settings_no_run_trains_with(field, value, expected):
    """From Python, TrainConfig(lr=-1) trained (the CLI checked only its options)."""
    from head360cli.errors import BadInputError

    with pytest.raises(BadInputError, match=re.escape(
            f"expected TrainConfig.{field} {expected}, found {value!r}")):
        TrainConfig(**{field: value})
    # the edges of the ranges are settings a run can train with
    edge = TrainConfig(steps=0, minutes=0.0, code_prior=0.0, final_lr=1.0)
    assert (edge.steps, edge.minutes, edge.code_prior, edge.final_lr) == (0, 0.0, 0.0, 1.0)


class _Payload:
    """Pickles as a call that makes a marker file: code a checkpoint could run on load."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


def test_a_checkpoint_that_would_run_code_is_refused_not_loaded(tmp_path, run_cli):
    """Resuming and exporting loaded the run folder's checkpoint with weights_only=False,
    so a checkpoint.pt someone else made could run code; it is now read as data only."""
    run, marker = tmp_path / "run", tmp_path / "ran"
    train(run, CFG, TINY, progress=False, stop_at=2)
    state = torch.load(run / CHECKPOINT, weights_only=True)  # a real one loads as data
    assert state["format"] == "head360-train" and state["step"] == 2
    torch.save({**state, "extra": _Payload(marker)}, run / CHECKPOINT)
    with pytest.raises(FileFormatError, match="could run code, so it is not loaded"):
        train(run, CFG, TINY, progress=False)
    with pytest.raises(FileFormatError, match="could run code, so it is not loaded"):
        save_generator(run / CHECKPOINT, tmp_path / "g.pt")
    r = run_cli("train", run, "--steps", "4")
    assert r.code == 5 and "could run code, so it is not loaded" in r.err, r.err
    assert not marker.exists() and not (tmp_path / "g.pt").exists()
    torch.save({"format": "other"}, run / CHECKPOINT)
    with pytest.raises(FileFormatError, match="training checkpoint, found 'other'"):
        train(run, CFG, TINY, progress=False)


def test_a_skipped_step_leaves_the_log_finite_and_standard_json(tmp_path, monkeypatch):
    """A step whose loss overflows is skipped; the interval's logged losses are the mean of
    the steps taken, not NaN (written as a bare ``NaN``, which JSON readers refuse)."""
    import head360cli.model.train as train_module

    real, calls = train_module.losses, []

    def overflow_first(out, batch, cfg):
        parts = real(out, batch, cfg)
        calls.append(1)
        if len(calls) == 1:
            parts["total"] = parts["total"] * float("inf")
        return parts

    monkeypatch.setattr(train_module, "losses", overflow_first)
    last = train(tmp_path / "r", CFG, TINY, progress=False)

    def refuse(word):
        raise ValueError(f"not JSON: {word}")

    lines = [json.loads(x, parse_constant=refuse)
             for x in (tmp_path / "r" / "log.jsonl").read_text().splitlines()]
    assert [x["step"] for x in lines] == [2, 4] and [x["skipped"] for x in lines] == [1, 1]
    assert all(x["l1"] > 0 and x["total"] > 0 for x in lines)
    assert last["l1"] == lines[-1]["l1"]


def _log_steps(run):
    return [json.loads(x)["step"] for x in (run / "log.jsonl").read_text().splitlines()]


@pytest.mark.slow
def test_ctrl_c_checkpoints_the_step_it_is_on_and_resuming_ends_as_one_run(tmp_path,
                                                                          monkeypatch):
    """Ctrl-C used to lose every step since the last checkpoint (up to 199 by default)."""
    import dataclasses
    import signal

    import head360cli.model.train as train_module
    from head360cli.model.train import read_checkpoint

    cfg = dataclasses.replace(CFG, steps=6, log_every=1, checkpoint_every=4)
    real, calls = train_module.losses, []

    def interrupted_in_the_third_step(out, batch, c):
        calls.append(1)
        if len(calls) == 3:
            os.kill(os.getpid(), signal.SIGINT)
        return real(out, batch, c)

    monkeypatch.setattr(train_module, "losses", interrupted_in_the_third_step)
    with pytest.raises(KeyboardInterrupt):
        train(tmp_path / "r", cfg, TINY, progress=False)
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # put back
    assert read_checkpoint(tmp_path / "r" / CHECKPOINT)["step"] == 3
    monkeypatch.setattr(train_module, "losses", real)
    train(tmp_path / "r", cfg, TINY, progress=False)
    train(tmp_path / "whole", cfg, TINY, progress=False)
    assert _log_steps(tmp_path / "r") == [1, 2, 3, 4, 5, 6]
    for k, v in _weights(tmp_path / "whole").items():
        assert torch.allclose(v, _weights(tmp_path / "r")[k], atol=1e-6), k


def test_a_resumed_run_logs_each_step_once(tmp_path):
    """Steps logged after the last checkpoint (a run killed before the next one) are
    logged again when resumed; the log kept both, and a line cut off mid-write."""
    import dataclasses

    cfg = dataclasses.replace(CFG, steps=4, log_every=1)
    train(tmp_path / "r", cfg, TINY, progress=False, stop_at=2)
    with open(tmp_path / "r" / "log.jsonl", "a") as f:
        f.write('{"step": 3, "l1": 0.5}\n{"step": 4, "l1"')
    train(tmp_path / "r", cfg, TINY, progress=False)
    assert _log_steps(tmp_path / "r") == [1, 2, 3, 4]


def test_generator_weights_with_nan_are_refused_on_load_and_as_init(tmp_path):
    """Weights from a run that diverged loaded and rendered every frame as NaN (black
    images, exit 0), and ``train --init`` trained on from them."""
    import dataclasses

    train(tmp_path / "run", CFG, TINY, progress=False)
    save_generator(tmp_path / "run" / CHECKPOINT, tmp_path / "g.pt")
    weights = torch.load(tmp_path / "g.pt", weights_only=True)
    name = next(k for k, v in weights["generator"].items() if v.is_floating_point())
    weights["generator"][name].view(-1)[0] = float("nan")
    torch.save(weights, tmp_path / "nan.pt")
    with pytest.raises(FileFormatError, match=f"expected finite generator weights, found "
                                              f"NaN or infinity in {re.escape(name)}$"):
        load_generator(tmp_path / "nan.pt")
    more = dataclasses.replace(CFG, init=str(tmp_path / "nan.pt"))
    with pytest.raises(FileFormatError, match="expected finite generator weights"):
        train(tmp_path / "more", more, TINY, progress=False, stop_at=1)
    weights = torch.load(tmp_path / "g.pt", weights_only=True)
    weights["codes"][0, 0] = float("inf")
    torch.save(weights, tmp_path / "inf.pt")
    with pytest.raises(FileFormatError, match=r"infinity in codes$"):
        load_generator(tmp_path / "inf.pt")
