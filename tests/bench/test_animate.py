"""``head360 bench animate``'s image-size sweep on a sampled head (tiny sizes)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from head360cli.bench.animate import (
    _markdown,
    _resolution,
    _turning_capture,
    correlation,
)


@pytest.mark.slow
def test_resolution_sweep_scores_each_size_twice(head_file):
    weights = np.zeros((3, 52), np.float32)
    weights[1, 24] = 1.0  # jawOpen on one frame
    rows = _resolution(head_file, weights, sizes=(32, 64), samples=4)
    assert [r["size"] for r in rows] == [32, 64]
    for r in rows:
        assert r["fps"] > 0 and r["ms_per_frame"] > 0 and r["samples"] == 4
        assert 15.0 < r["psnr_vs_reference_same_size"] <= 120.0
        assert 10.0 < r["psnr_vs_reference_64px"] <= 120.0
    # at the largest size the two scores are the same comparison (upsampling is identity)
    assert rows[1]["psnr_vs_reference_64px"] == rows[1]["psnr_vs_reference_same_size"]
    # 32 pixels upsampled lose detail the 64-pixel render keeps
    assert rows[0]["psnr_vs_reference_64px"] < rows[1]["psnr_vs_reference_64px"]


def test_a_deferred_head_is_swept_by_samples_a_pixel_without_a_reuse_part(head_file):
    """The shipped generator is deferred: the throughput sweep is over samples a pixel
    against 4, and there are no decoded points to reuse (a still camera's G-buffer is
    reused instead, exactly: tests/model/test_deferred.py)."""
    from head360cli.bench.animate import _sampling

    assert _sampling(head_file, "cpu") == (4, (1, 2, 4), None)
    md = _markdown({"stream": "s", "stream_frames": 5, "threads": 2,
                    "speed": [{"samples": 1, "precision": "fp32", "fps": 50.0,
                               "ms_per_frame": 20.0, "reference_samples": 4,
                               "psnr_vs_reference": 31.5}], "fidelity": [],
                    "swap": {"own_style": "bob", "views_yaw": [0], "styles": [],
                             "mean_psnr_face": 0.0, "mean_psnr_hull": 0.0}})
    assert "| samples | networks | frames/s | ms/frame | PSNR vs 4 samples |" in md
    assert "| 1 | fp32 | 50.0 | 20 | 31.50 |" in md and "Reuse" not in md


@pytest.mark.slow
def test_run_cli_reports_the_child_s_own_peak_memory():
    """A parent holding 600 MB does not lend its size to the command it runs (Linux's
    ru_maxrss would: it carries the parent's resident size across fork and exec)."""
    from head360cli.bench.animate import _run_cli

    big = np.ones(600 * 2**20 // 8)  # touched: resident
    out = _run_cli(["info"])
    assert big.sum() > 0
    assert 20 < out["peak_rss_mib"] < 500


def test_correlation_interval_brackets_the_correlation():
    rng = np.random.default_rng(0)
    a = rng.normal(size=400)
    exact = correlation(a, 2 * a + 1)
    assert exact["r"] == 1.0 and exact["interval_95"] == [1.0, 1.0]
    assert correlation(a, 2 * a + 1, rounds=0) == {"r": 1.0, "interval_95": None}
    wide = correlation(a[:20], a[:20] + rng.normal(size=20))
    narrow = correlation(a, a + rng.normal(size=400))
    for c in (wide, narrow):
        lo, hi = c["interval_95"]
        assert lo < c["r"] < hi
    # 0.71 expected (unit signal, unit noise); 20 pairs leave it far less certain
    assert abs(narrow["r"] - 0.71) < 0.06
    assert np.diff(narrow["interval_95"])[0] < 0.5 * np.diff(wide["interval_95"])[0]
    assert correlation(a, np.ones(400)) is None and correlation(a[:2], a[:2]) is None


def test_the_turning_capture_is_the_one_whose_head_turns_most(tmp_path):
    (tmp_path / "arkit").mkdir()

    def write(name, yaw_deg):
        rows = ["time,jawOpen,HeadYaw,HeadPitch,HeadRoll"]
        rows += [f"{i / 30:.4f},0.1,{np.radians(y):.6f},0,0" for i, y in enumerate(yaw_deg)]
        (tmp_path / "arkit" / name).write_text("\n".join(rows) + "\n")

    write("still.csv", [0.0] * 5)
    assert _turning_capture(tmp_path) is None  # a head that does not turn is no test
    write("nod.csv", [0.0, 2.0, 4.0, 2.0, 0.0])
    write("turn.csv", [-10.0, 0.0, 10.0, 20.0, 5.0])
    path, turn = _turning_capture(tmp_path)
    assert path.name == "turn.csv" and abs(turn - 30.0) < 0.01
    md = _markdown({"stream": "s", "stream_frames": 5, "threads": 2, "speed": [],
                    "fidelity": [],
                    "swap": {"own_style": "bob", "views_yaw": [0], "styles": [],
                             "mean_psnr_face": 0.0, "mean_psnr_hull": 0.0},
                    "head_pose": {"capture": "turn.csv", "head_turn_deg": 30.0, "frames": 5,
                                  "workers": 2, "fps_head_pose": 12.04, "fps_still": 14.9,
                                  "fps_head_pose_one_process": 9.02,
                                  "fps_still_one_process": 11.5}})
    assert "| `--head-pose` (every point decoded) | 12.0 | 9.0 |" in md
    assert "(2 processes, the default)" in md
    assert "turns through 30 degrees" in md


@pytest.mark.slow
def test_frames_per_call_rows_time_each_batch_with_and_without_hair(head_file):
    """The GPU part (``--device cuda``), run here on the CPU at a tiny size: a row per
    precision, hair and batch, each timed, float32's frames its own reference."""
    from head360cli.bench.animate import _batches, _precisions

    weights = np.zeros((4, 52), np.float32)
    weights[:, 24] = np.linspace(0.0, 0.8, 4)  # jawOpen
    rows = _batches(head_file, weights, "cpu", batches=(1, 3), samples=4, size=64)
    precisions = _precisions("cpu")
    assert [(r["precision"], r["hair"], r["batch"]) for r in rows] == [
        (p, h, b) for p in precisions for h in (True, False) for b in (1, 3)]
    for r in rows:
        assert r["fps"] > 0 and r["ms_per_frame"] > 0 and r["samples"] == 4
        if r["precision"] == "fp32":
            assert r["psnr_vs_fp32"] >= 119.0  # its own reference
        else:  # bfloat16 networks, where this CPU has them: close, not the same
            assert 30.0 < r["psnr_vs_fp32"] < 119.0
    md = _markdown({"stream": "s", "stream_frames": 4, "threads": 2, "device": "cuda",
                    "gpu": "NVIDIA H200", "head": "me.h360", "speed": [], "batch": rows,
                    "swap": {"own_style": "bob", "views_yaw": [0], "styles": [],
                             "mean_psnr_face": 0.0, "mean_psnr_hull": 0.0}})
    assert "Head: me.h360. Stream: s (4 frames); on NVIDIA H200." in md
    assert "| 3 | no | fp32 |" in md and "Expression fidelity" not in md
    run = {"frames": 600, "render_fps": 389.0, "peak_rss_mib": 1807.0, "wall_s": 14.4,
           "gpu_peak_mib": 2867.0}
    md = _markdown({"stream": "s", "stream_frames": 4, "threads": 2, "device": "cuda",
                    "speed": [], "swap": {"own_style": "bob", "views_yaw": [0],
                                          "styles": [], "mean_psnr_face": 0.0,
                                          "mean_psnr_hull": 0.0},
                    "memory": {"capture": "take.csv", "first_10_s": run, "whole": run}})
    assert "| whole capture | 600 | 389.0 | 1807 | 14 | 2867 |" in md
    assert "GPU peak MiB" in md


def test_bench_on_a_given_head_without_fidelity_needs_no_dlib(head_file, monkeypatch):
    """``--head`` and ``--no-fidelity``: no photo is fitted and no landmarks are read, so
    the bench runs where dlib's model files are not (a GPU machine); every part is
    handed the device."""
    import head360cli.bench.animate as bench
    import head360cli.fitting.landmarks as landmarks
    import head360cli.fitting.pipeline as pipeline
    import head360cli.paths as paths
    from head360cli.io.arkit import ArkitStream

    def refuse(*args, **kwargs):
        raise AssertionError("dlib or the fit was called")

    monkeypatch.setattr(landmarks, "LandmarkDetector", refuse)
    monkeypatch.setattr(pipeline, "run_demo", refuse)
    monkeypatch.setattr(paths, "shared_data_dir", lambda: None)  # no capture runs
    seen = []

    def record(name, value):
        def part(head, *args, **kwargs):
            seen.append((name, Path(head), kwargs.get("device", args[-1] if args else None)))
            return value
        return part

    speed = [{"samples": 2, "precision": "fp32", "fps": 1.0, "ms_per_frame": 1.0,
              "reference_samples": 4, "psnr_vs_reference": 40.0}]
    swap = {"own_style": "bob", "views_yaw": [0], "styles": [], "mean_psnr_face": 0.0,
            "mean_psnr_hull": 0.0}
    monkeypatch.setattr(bench, "_speed", record("speed", speed))
    reuse = {"tol": 1e-3, "samples": 8, "size": 256, "frames": 8, "precision": "fp32",
             "fps": 2.0, "ms_per_frame": 500.0, "fps_exact": 1.0, "ms_per_frame_exact": 1e3,
             "decoded_share": 0.2, "psnr_vs_exact_min": 70.0, "max_abs_vs_exact": 1e-4}
    monkeypatch.setattr(bench, "_reuse", record("reuse", reuse))
    resolution = [{"size": 256, "samples": 2, "precision": "fp32", "fps": 1.0,
                   "ms_per_frame": 1.0, "reference_samples": 4,
                   "psnr_vs_reference_same_size": 40.0, "psnr_vs_reference_256px": 40.0}]
    monkeypatch.setattr(bench, "_resolution", record("resolution", resolution))
    monkeypatch.setattr(bench, "_swap", record("swap", swap))
    monkeypatch.setattr(bench, "_stream", lambda data: (
        ArkitStream(np.zeros((10, 52), np.float32), np.arange(10) / 30.0, 30.0), None))
    result, md = bench.bench_animate(frames=8, memory=False, head_path=head_file,
                                     fidelity=False, device="cpu")
    # a deferred head: no decoded points to reuse
    assert [name for name, _, _ in seen] == ["speed", "resolution", "swap"]
    assert all(head == head_file for _, head, _ in seen)
    assert [device for name, _, device in seen] == ["cpu"] * 3
    assert result["device"] == "cpu" and result["head"] == head_file.name
    assert "fidelity" not in result and "memory" not in result
    assert "Expression fidelity" not in md and "on cpu, " in md
