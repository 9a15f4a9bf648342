"""``head360 bench summary`` and ``bench all``: one table and one plot from the stages."""

from __future__ import annotations

import json

import numpy as np
import pytest

from head360cli.bench.summary import collect, summarize

STAGES = {
    "fit_shape": {"iterations_sweep": [
        {"iterations": 4, "fit_ms_median": 3.7, "real_nme_fit_%_yaw0-30": 3.56},
        {"iterations": 12, "fit_ms_median": 6.0, "real_nme_fit_%_yaw0-30": 3.42}]},
    "fit": {"sweep": [{"texture_steps": 5, "psnr_face": 21.4, "invert_s": 1.5,
                       "total_s": 4.0}]},
    "animate": {"speed": [{"samples": 8, "precision": "fp32", "ms_per_frame": 96.9,
                           "psnr_vs_32_samples": 38.18}]},
    "onnx": {"parity": {"max_abs_diff": 4.6e-5},
             "speed": [{"backend": "torch", "precision": "fp32", "hair": "yes",
                        "ms_per_frame": 95.6},
                       {"backend": "onnxruntime", "precision": "fp32", "hair": "yes",
                        "ms_per_frame": 154.0}]},
}


def test_collect_makes_one_row_per_measured_setting():
    rows = collect(STAGES)
    assert [r["stage"] for r in rows] == ["shape fit", "shape fit", "inversion",
                                          "render (animation)", "torch vs onnxruntime",
                                          "torch vs onnxruntime"]
    assert rows[2] == {"stage": "inversion", "setting": "5 texture steps", "ms": 1500.0,
                       "metric": "face PSNR dB (photo)", "value": 21.4, "better": "higher"}
    assert rows[-1]["value"] == pytest.approx(4.6e-5) and rows[-2]["value"] == 0.0
    assert collect({}) == []


def test_collect_reads_the_image_size_sweep():
    sweep = [{"size": 128, "samples": 8, "precision": "bf16", "ms_per_frame": 30.0,
              "psnr_vs_32_samples_same_size": 38.0, "psnr_vs_32_samples_512px": 24.1},
             {"size": 512, "samples": 8, "precision": "bf16", "ms_per_frame": 300.0,
              "psnr_vs_32_samples_same_size": 37.5, "psnr_vs_32_samples_512px": 37.5}]
    rows = collect({"animate": {"speed": [], "resolution": sweep}})
    assert [(r["stage"], r["setting"], r["ms"], r["value"]) for r in rows] == [
        ("render (image size)", "128 px, 8 samples, bf16", 30.0, 24.1),
        ("render (image size)", "512 px, 8 samples, bf16", 300.0, 37.5)]
    assert rows[0]["metric"] == "PSNR dB vs 32 samples at 512 px"


def test_collect_reads_reuse_between_frames():
    reuse = {"tol": 1e-3, "samples": 8, "ms_per_frame": 76.0, "ms_per_frame_exact": 131.0,
             "psnr_vs_exact_min": 94.2}
    rows = collect({"animate": {"speed": [], "reuse": reuse}})
    assert [(r["setting"], r["ms"], r["value"]) for r in rows] == [
        ("tol 0.001, 8 samples", 76.0, 94.2), ("exact, 8 samples", 131.0, None)]
    assert {r["stage"] for r in rows} == {"reuse between frames"}


def test_summarize_writes_table_and_plot(tmp_path):
    from PIL import Image

    for name, result in STAGES.items():
        (tmp_path / f"{name}.json").write_text(json.dumps(result))
    result, md = summarize(tmp_path, tmp_path / "out")
    assert result["stages"] == ["fit_shape", "fit", "animate", "onnx"]
    assert "| inversion | 5 texture steps | 1500.0 | face PSNR dB (photo) | 21.4 | higher |" in md
    saved = json.loads((tmp_path / "out" / "bench.json").read_text())
    assert len(saved["rows"]) == 6
    img = np.asarray(Image.open(tmp_path / "out" / "bench.png"))
    assert img.shape == (640, 960, 3)  # four panels: two rows of three
    assert (img < 128).any() and (img == 255).mean() > 0.5  # drawn, mostly background


@pytest.mark.parametrize(("text", "says"), [
    ("{bad", "expected the JSON that head360 bench writes, found unreadable text"),
    ('{"sweep": [{"a": 1}]}', "expected the results of head360 bench fit, found another "
                             "layout (KeyError: 'texture_steps')"),
    ("[1, 2]", "found another layout (AttributeError")])
def test_summary_names_a_stage_file_it_cannot_read(run_cli, tmp_path, text, says):
    """A truncated or foreign fit.json ended bench summary in an internal error."""
    (tmp_path / "onnx.json").write_text(json.dumps(STAGES["onnx"]))
    (tmp_path / "fit.json").write_text(text)
    r = run_cli("bench", "summary", tmp_path)
    assert r.code == 5 and says in r.err and "fit.json" in r.err, r.err
    assert not (tmp_path / "bench.md").exists()


def test_summary_and_all_on_the_command_line(run_cli, tmp_path):
    assert run_cli("bench", "summary", tmp_path).code == 3  # no results there
    (tmp_path / "onnx.json").write_text(json.dumps(STAGES["onnx"]))
    skip = [a for s in ("fit-shape", "fit", "generator", "animate", "onnx", "synth")
            for a in ("--skip", s)]
    r = run_cli("bench", "all", "--out", tmp_path, *skip, "--json")
    assert r.code == 0, r.err
    res = json.loads(r.out)
    assert res["failed"] == [] and res["stages"] == ["onnx"]
    assert (tmp_path / "bench.md").is_file() and (tmp_path / "bench.png").is_file()


def test_bench_all_hands_the_device_to_every_stage(run_cli, tmp_path, monkeypatch):
    """``head360 --device cuda bench all``: each stage's command gets --device (the CPU-only
    stages then say they do not use it); with the default CPU none does, and a device that
    is not there stops it before the first stage. The stages' processes are stubbed."""
    import subprocess

    import torch

    calls = []

    def fake_run(cmd, **kwargs):
        calls.append(cmd)
        return subprocess.CompletedProcess(cmd, 0)

    (tmp_path / "onnx.json").write_text(json.dumps(STAGES["onnx"]))
    monkeypatch.setattr(subprocess, "run", fake_run)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)
    r = run_cli("--device", "cuda", "bench", "all", "--out", tmp_path, "--skip", "synth")
    assert r.code == 0, r.err
    assert [c[4] for c in calls] == ["fit-shape", "fit", "generator", "animate", "onnx"]
    assert all(c[-2:] == ["--device", "cuda"] for c in calls)
    calls.clear()
    assert run_cli("bench", "all", "--out", tmp_path, "--skip", "synth").code == 0
    assert len(calls) == 5 and not any("--device" in c for c in calls)
    calls.clear()
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    r = run_cli("bench", "all", "--device", "cuda", "--out", tmp_path)
    assert r.code == 3 and "no CUDA device is available" in r.err and calls == []


def test_collect_reads_a_deferred_generators_rows():
    """Samples a pixel against a 4-sample reference, and the generator sweep by samples
    a pixel (0.5.0's keys), beside the older 32-sample ones above."""
    rows = collect({
        "animate": {"speed": [{"samples": 1, "precision": "fp32", "ms_per_frame": 12.0,
                               "reference_samples": 4, "psnr_vs_reference": 33.1}],
                    "resolution": [{"size": 256, "samples": 2, "precision": "fp32",
                                    "ms_per_frame": 20.0, "reference_samples": 4,
                                    "psnr_vs_reference_same_size": 40.0,
                                    "psnr_vs_reference_256px": 40.0}]},
        "generator": {"sweep": [{"pixel_samples": 2, "ms_hair": 30.0, "psnr_hair": 31.0}]}})
    assert [(r["setting"], r["metric"], r["value"]) for r in rows] == [
        ("2 samples a pixel", "PSNR dB vs ground truth, with hair", 31.0),
        ("1 samples, fp32", "PSNR dB vs 4 samples", 33.1),
        ("256 px, 2 samples, fp32", "PSNR dB vs 4 samples at 256 px", 40.0)]
