"""ONNX export: the exported graphs run in onnxruntime and match the torch generator."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture(scope="module")
def exported(head_file, tmp_path_factory):
    from head360cli.export.onnx import export_onnx
    from head360cli.fitting.pipeline import load_head_renderer

    r = load_head_renderer(head_file, samples=3, size=48, precision="fp32")
    out = tmp_path_factory.mktemp("onnx") / "gen.onnx"
    res = export_onnx(r, out)
    return r, out, res


@pytest.mark.slow
def test_onnx_matches_torch_with_and_without_hair(exported):
    from head360cli.drive.views import view_cameras, view_intrinsics
    from head360cli.export.onnx import OnnxFrameRunner, head_inputs

    r, out, res = exported
    assert [p.split("/")[-1] for p in res["files"]] == ["gen.onnx", "gen_bald.onnx"]
    runner = OnnxFrameRunner(out)
    assert runner.size == 48 and runner.meta["samples"] == 3
    inputs = head_inputs(r)
    rng = np.random.default_rng(0)
    worst = 0.0
    for i in range(6):
        w = rng.uniform(0, 1, 52) * (rng.uniform(0, 1, 52) < 0.2)
        cam = view_cameras(rng.uniform(-180, 180), rng.uniform(-60, 60))
        k = view_intrinsics(48)
        hair = i % 2 == 0
        ref = r.render(cam, k, w, hair=hair).numpy()
        got = runner.render(inputs, w, cam.numpy(), k.numpy(), hair=hair)
        assert got.shape == (1, 3, 48, 48) and np.isfinite(got).all()
        worst = max(worst, float(np.abs(got - ref).max()))
    assert worst <= 1e-3
    # one graph for every hairstyle: another style's mesh, padded, renders like torch
    other = r.with_hair(9 if r.hair_style != 9 else 17, r.hair_colour)
    cam, k = view_cameras(20.0, 5.0), view_intrinsics(48)
    got = runner.render(head_inputs(other), np.zeros(52), cam.numpy(), k.numpy())
    assert np.abs(got - other.render(cam, k, np.zeros(52)).numpy()).max() <= 1e-3


def test_pad_hair_refuses_oversized_meshes():
    from head360cli.errors import BadInputError
    from head360cli.export.onnx import HAIR_FACES, HAIR_VERTS, pad_hair

    v, f = pad_hair(np.ones((1, 5, 3)), np.array([[0, 1, 2]]))
    assert v.shape == (1, HAIR_VERTS, 3) and f.shape == (HAIR_FACES, 3)
    assert (f[1:] == 0).all() and (v[0, 5:] == 0).all()
    with pytest.raises(BadInputError, match="at most"):
        pad_hair(np.zeros((1, HAIR_VERTS + 1, 3)), f)


def test_export_refuses_bad_targets(head_file, tmp_path):
    from head360cli.errors import BadInputError
    from head360cli.export.onnx import export_onnx
    from head360cli.fitting.pipeline import load_head_renderer

    r = load_head_renderer(head_file, samples=2, size=32)
    with pytest.raises(BadInputError, match=r"\.onnx"):
        export_onnx(r, tmp_path / "x.pt")
    with pytest.raises(BadInputError, match="does not exist"):
        export_onnx(r, tmp_path / "no" / "x.onnx")


@pytest.mark.slow
def test_cli_export_onnx_writes_both_graphs_and_the_head_inputs(run_cli, head_file,
                                                                 tmp_path):
    import json

    out = tmp_path / "g.onnx"
    r = run_cli("export-onnx", "--head", head_file, "--samples", "2", "--size", "32",
                "-o", out, "--json")
    assert r.code == 0, r.err
    files = json.loads(r.out)["files"]
    assert out.is_file() and (tmp_path / "g_bald.onnx").is_file()
    inputs = np.load(files[-1])
    assert inputs["deltas"].shape[0] == 52 and inputs["texture"].ndim == 4
    assert run_cli("export-onnx", "--size", "33", "-o", tmp_path / "x.onnx").code == 3


@pytest.mark.slow
def test_runner_needs_no_torch(exported, tmp_path):
    """The runner renders in a process where importing torch fails."""
    import subprocess
    import sys

    from head360cli.drive.views import view_cameras, view_intrinsics
    from head360cli.export.onnx import head_inputs

    r, out, _ = exported
    np.savez(tmp_path / "inputs.npz", **head_inputs(r),
             c2w=view_cameras(30.0, 0.0).numpy(), k=view_intrinsics(48).numpy())
    code = (
        "import sys\n"
        "sys.modules['torch'] = None  # any import of torch now raises\n"
        "import numpy as np\n"
        "from head360cli.export.onnx import OnnxFrameRunner\n"
        f"d = dict(np.load({str(tmp_path / 'inputs.npz')!r}))\n"
        f"img = OnnxFrameRunner({str(out)!r}).render(d, np.zeros(52), d['c2w'], d['k'])\n"
        "assert img.shape == (1, 3, 48, 48) and np.isfinite(img).all()\n"
        "print('ok', float(img.mean()))\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr[-2000:]
    assert p.stdout.startswith("ok")
