"""ONNX export: the exported graphs run in onnxruntime and match the torch generator."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest


@pytest.fixture(scope="module")
def exported(head_file, tmp_path_factory):
    """The graphs of ``head360 export-onnx --head``, exported once for the module (an
    export takes over a minute on a 2-core CPU): the renderer they were traced from, the
    graph path, the command's exit code and its JSON."""
    import contextlib
    import io
    import json

    from head360cli.cli import main
    from head360cli.fitting.pipeline import load_head_renderer

    r = load_head_renderer(head_file, samples=1, size=48, precision="fp32")
    out = tmp_path_factory.mktemp("onnx") / "gen.onnx"
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        code = main(["export-onnx", "--head", str(head_file), "--samples", "1", "--size",
                     "48", "-o", str(out), "--json"])
    return r, out, code, json.loads(stdout.getvalue()) if code == 0 else None


@pytest.mark.slow
def test_onnx_matches_torch_with_and_without_hair(exported):
    import onnxruntime as ort

    from head360cli.drive.views import view_cameras, view_intrinsics
    from head360cli.export.onnx import OnnxFrameRunner, head_inputs

    r, out, code, res = exported
    assert code == 0
    assert [p.split("/")[-1] for p in res["files"]][:2] == ["gen.onnx", "gen_bald.onnx"]
    from head360cli.devices import usable_cpus

    # with two cores the bald graph was traced by a spawned process, not by the fallback
    assert res["parallel"] is (usable_cpus() >= 2)
    # tidied after the export (export_onnx's _tidy): constants folded and lifted to
    # initializers, so no Constant or CastLike node is left for onnxruntime to warn about
    import onnx

    for f in res["files"][:2]:
        ops = {n.op_type for n in onnx.load(f).graph.node}
        assert not ops & {"Constant", "CastLike"}, f
    runner = OnnxFrameRunner(out)
    assert runner.provider == "CPUExecutionProvider"
    if "CUDAExecutionProvider" not in ort.get_available_providers():  # asked, not there
        assert OnnxFrameRunner(out, providers=["CUDAExecutionProvider"]).provider == \
            "CPUExecutionProvider"
    assert runner.size == 48 and runner.meta["samples"] == 1
    from head360cli.export.onnx import GRAPH_FORMAT

    assert runner.format_version == runner.meta["format_version"] == GRAPH_FORMAT
    assert runner.has_alpha
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
    # a camera whose rays all miss: the graph's culled ray set is empty but for ray 0
    from tests.hard.test_named_cases import looking_away

    away, k = looking_away(), view_intrinsics(48)
    got = runner.render(inputs, np.zeros(52), away.numpy(), k.numpy())
    assert np.isfinite(got).all() and got.min() > 0.97
    assert np.abs(got - r.render(away, k, np.zeros(52)).numpy()).max() <= 1e-3
    # one graph for every hairstyle: another style's mesh, padded, renders like torch
    other = r.with_hair(9 if r.hair_style != 9 else 17, r.hair_colour)
    cam, k = view_cameras(20.0, 5.0), view_intrinsics(48)
    got = runner.render(head_inputs(other), np.zeros(52), cam.numpy(), k.numpy())
    assert np.abs(got - other.render(cam, k, np.zeros(52)).numpy()).max() <= 1e-3
    # a head with eyes of its own (a fit's): the runner drives them as torch does
    from head360cli.mesh.arkit52 import INDEX
    from head360cli.model.head_render import HeadRenderer

    own = np.zeros(52)
    own[[INDEX["eyeBlinkLeft"], INDEX["eyeWideRight"]]] = 0.7, 0.6
    fitted = HeadRenderer(r.gen, r.shape, r.texture[0], r.hair_style, r.hair_colour, own,
                          samples=1, size=48, precision="fp32")
    w = np.zeros(52)
    w[INDEX["eyeBlinkRight"]] = 0.5
    ref = fitted.render(cam, k, w).numpy()
    assert np.abs(ref - r.render(cam, k, w).numpy()).max() > 1e-2  # the eyes moved
    got = runner.render(head_inputs(fitted), w, cam.numpy(), k.numpy())
    assert np.abs(got - ref).max() <= 1e-3
    # a head with a hair detail of its own (a fit's): the same graph draws its strands
    from head360cli.model.deferred import HAIR_TEXTURE_SIDE

    side = HAIR_TEXTURE_SIDE
    strands = HeadRenderer(r.gen, r.shape, r.texture[0], r.hair_style, r.hair_colour,
                           samples=1, size=48, precision="fp32",
                           hair_detail=rng.uniform(0.3, 2.0, (side, side, 3)))
    ref = strands.render(cam, k, w).numpy()
    assert np.abs(ref - r.render(cam, k, w).numpy()).max() > 1e-2  # the strands show
    got = runner.render(head_inputs(strands), w, cam.numpy(), k.numpy())
    assert np.abs(got - ref).max() <= 1e-3
    # a head with a light of its own (a fit's colour_gain): drawn from the graph's alpha,
    # by the torch-free runner and through HeadRenderer.use_runner alike
    lit = HeadRenderer(r.gen, r.shape, r.texture[0], r.hair_style, r.hair_colour,
                       samples=1, size=48, precision="fp32", colour_gain=[0.7, 1.0, 1.3])
    assert runner.has_alpha
    ref = lit.render(cam, k, w).numpy()
    assert np.abs(ref - r.render(cam, k, w).numpy()).max() > 5e-2  # the light shows
    got = runner.render(head_inputs(lit), w, cam.numpy(), k.numpy())
    assert np.abs(got - ref).max() <= 1e-3
    lit.use_runner(runner)
    assert np.abs(lit.render(cam, k, w).numpy() - ref).max() <= 1e-3


def test_a_graph_without_alpha_cannot_draw_a_heads_light(head_file):
    """Graphs of format 1 (no format version stored) give only rgb: a head with a light is
    refused with what to do, before any frame; a head without one renders from them as before."""
    from head360cli.errors import FileFormatError
    from head360cli.fitting.pipeline import load_head_renderer
    from head360cli.model.head_render import HeadRenderer

    class OldRunner:
        size, has_alpha = 48, False

        def __call__(self, *args):
            return np.ones((1, 3, 48, 48), np.float32)

    r = load_head_renderer(head_file, samples=1, size=48, precision="fp32")
    lit = HeadRenderer(r.gen, r.shape, r.texture[0], r.hair_style, r.hair_colour,
                       samples=1, size=48, precision="fp32", colour_gain=[0.7, 1.0, 1.3])
    with pytest.raises(FileFormatError, match="export it again with head360 export-onnx"):
        lit.use_runner(OldRunner())
    r.use_runner(OldRunner())
    # a graph's frames carry no hair coverage: asking for it is refused, not guessed
    from head360cli.drive.views import view_cameras, view_intrinsics

    with pytest.raises(ValueError, match="torch generator for the hair's coverage"):
        r.render(view_cameras([0.0], 0.0), view_intrinsics(48), hair_alpha=True)


def _tiny_graph_pair(folder, meta: dict | None, outputs: int):
    """``g.onnx`` and ``g_bald.onnx``: identity graphs with ``outputs`` outputs and, when
    ``meta`` is given, head360's export metadata."""
    import json

    onnx = pytest.importorskip("onnx")
    from onnx import TensorProto, helper

    from head360cli.export.onnx import META_KEY

    x = helper.make_tensor_value_info("verts", TensorProto.FLOAT, [1, 3])
    names = ["rgb", "alpha"][:outputs]
    outs = [helper.make_tensor_value_info(n, TensorProto.FLOAT, [1, 3]) for n in names]
    nodes = [helper.make_node("Identity", ["verts"], [n]) for n in names]
    model = helper.make_model(helper.make_graph(nodes, "g", [x], outs),
                              opset_imports=[helper.make_opsetid("", 18)])
    model.ir_version = 8
    if meta is not None:
        helper.set_model_props(model, {META_KEY: json.dumps(meta)})
    for name in ("g.onnx", "g_bald.onnx"):
        onnx.save(model, folder / name)
    return folder / "g.onnx"


def test_graph_format_versions_are_read_and_newer_ones_refused(tmp_path):
    """Graphs store their format version; one without it is format 1 (rgb only), and a
    graph of a newer format is refused with what to do."""
    pytest.importorskip("onnxruntime")
    from head360cli.errors import FileFormatError
    from head360cli.export.onnx import GRAPH_FORMAT, OnnxFrameRunner

    old = OnnxFrameRunner(_tiny_graph_pair(tmp_path, {"size": 8}, outputs=1))
    assert (old.format_version, old.has_alpha, old.size) == (1, False, 8)
    now = OnnxFrameRunner(_tiny_graph_pair(
        tmp_path, {"size": 8, "format_version": GRAPH_FORMAT}, outputs=2))
    assert (now.format_version, now.has_alpha) == (GRAPH_FORMAT, True)
    newer = _tiny_graph_pair(tmp_path, {"size": 8, "format_version": GRAPH_FORMAT + 1}, 2)
    with pytest.raises(FileFormatError, match=r"newer head360, upgrade head360"):
        OnnxFrameRunner(newer)
    with pytest.raises(FileFormatError, match="export metadata, found none"):
        OnnxFrameRunner(_tiny_graph_pair(tmp_path, None, outputs=2))


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
def test_cli_export_onnx_writes_both_graphs_and_the_head_inputs(run_cli, exported,
                                                                 head_file, tmp_path):
    _, out, code, res = exported
    assert code == 0
    files = res["files"]
    assert files[:2] == [str(out), str(out.with_name("gen_bald.onnx"))]
    assert all(Path(f).is_file() for f in files)
    assert Path(files[-1]).name == f"{head_file.stem}_inputs.npz"
    inputs = np.load(files[-1])
    assert inputs["deltas"].shape[0] == 52 and inputs["texture"].ndim == 4
    assert res["samples"] == 1 and res["size"] == 48
    assert run_cli("export-onnx", "--size", "33", "-o", tmp_path / "x.onnx").code == 3
    assert not (tmp_path / "x.onnx").exists()


@pytest.mark.slow
def test_runner_needs_no_torch(exported, tmp_path):
    """The runner renders in a process where importing torch fails."""
    import subprocess
    import sys

    from head360cli.drive.views import view_cameras, view_intrinsics
    from head360cli.export.onnx import head_inputs

    r, out, _, _ = exported
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


@pytest.mark.slow
def test_cli_backend_onnx_renders_what_torch_renders(run_cli, exported, head_file, tmp_path):
    """``render`` and ``animate`` with ``--backend onnx`` give torch's frames (to one
    8-bit level); samples and size come from the graph, and conflicts are refused."""
    import imageio.v3 as iio

    from head360cli.io.arkit import ArkitStream, write_arkit_csv
    from head360cli.mesh.arkit52 import INDEX

    _, out, _, _ = exported
    view = ("--yaw", "30", "--pitch", "10", "--expr", "JawOpen=0.7,EyeBlinkLeft=1")
    a, b = tmp_path / "onnx.png", tmp_path / "torch.png"
    r = run_cli("render", head_file, *view, "--backend", "onnx", "--onnx", out, "-o", a)
    assert r.code == 0, r.err
    assert run_cli("render", head_file, *view, "--samples", "1", "--size", "48",
                   "--precision", "fp32", "-o", b).code == 0
    ia, ib = iio.imread(a).astype(int), iio.imread(b).astype(int)
    assert ia.shape == (48, 48, 3) and np.abs(ia - ib).max() <= 1
    w = np.zeros((4, 52), np.float32)
    w[:, INDEX["jawOpen"]] = np.linspace(0, 1, 4)
    csv = tmp_path / "s.csv"
    write_arkit_csv(ArkitStream(w, np.arange(4) / 30.0, 30.0), csv)
    frames = {}
    for backend in ("onnx", "torch"):
        d = tmp_path / backend
        args = ["--samples", "1", "--size", "48", "--precision", "fp32"]
        r = run_cli("animate", head_file, "--arkit", csv, "-o", d, "--backend", backend,
                    "--onnx", out, *(args if backend == "torch" else []))
        assert r.code == 0, r.err
        frames[backend] = np.stack([iio.imread(p) for p in sorted(d.glob("*.png"))])
    assert frames["onnx"].shape == (4, 48, 48, 3)
    assert np.abs(frames["onnx"].astype(int) - frames["torch"]).max() <= 1
    # the graph fixes samples and size; bf16 does not apply; a missing graph is named
    assert run_cli("render", head_file, "--backend", "onnx", "--onnx", out, "--size", "64",
                   "-o", a).code == 3
    assert run_cli("render", head_file, "--backend", "onnx", "--onnx", out, "--precision",
                   "bf16", "-o", a).code == 3
    r = run_cli("render", head_file, "--backend", "onnx", "--onnx", tmp_path / "no.onnx",
                "-o", a)
    assert r.code == 3 and "export-onnx" in r.err


@pytest.mark.slow
def test_runner_names_the_graph_to_give_for_the_bald_one_or_a_lone_one(exported, tmp_path):
    """--onnx gen_bald.onnx was refused as 'gen_bald_bald.onnx: expected an exported
    head360 generator ([ONNXRuntimeError] ... NO_SUCHFILE ...)'."""
    import shutil

    from head360cli.errors import FileFormatError
    from head360cli.export.onnx import OnnxFrameRunner

    _, out, _, _ = exported
    with pytest.raises(FileFormatError, match=r"found the bald one: give .*gen\.onnx$"):
        OnnxFrameRunner(out.with_name("gen_bald.onnx"))
    lone = tmp_path / "lone.onnx"
    shutil.copy(out, lone)
    with pytest.raises(FileFormatError, match=r"expected its bald graph lone_bald\.onnx"):
        OnnxFrameRunner(lone)


@pytest.mark.slow
def test_bench_onnx_on_the_exported_graph(exported):
    """The benchmark's parity rows are real comparisons (tiny: two heads)."""
    from head360cli.bench.onnx import bench_onnx, random_expression

    _, out, _, _ = exported
    result, md = bench_onnx(heads=2, repeats=1, graph=out, rounds=2)
    assert result["size"] == 48 and result["samples"] == 1
    assert result["parity"]["all_finite"] and len(result["parity"]["rows"]) == 2
    assert 0 <= result["parity"]["max_abs_diff"] <= 1e-3
    backends = {(s["backend"], s["hair"]) for s in result["speed"]}
    assert {("torch", "yes"), ("onnxruntime", "yes"), ("onnxruntime", "no")} <= backends
    assert result["timing"] == {"rounds": 2, "frames_per_block": 1}
    for s in result["speed"]:  # the median of two blocks lies between their frame times
        lo, hi = s["spread_ms"]
        assert 0 < lo <= s["ms_per_frame"] <= hi
    assert "onnxruntime" in md and "2 blocks of 1 frame(s)" in md
    assert {(s["backend"], s["on"]) for s in result["speed"]} >= {
        ("torch", "cpu"), ("onnxruntime", "CPU")}
    w = random_expression(np.random.default_rng(0))
    assert w.shape == (52,) and w.min() >= 0 and w.max() <= 1


def test_export_without_the_export_extra_says_what_to_install(run_cli, monkeypatch,
                                                              tmp_path):
    import importlib.util

    real = importlib.util.find_spec
    for gone, said in ((("onnxscript",), "found onnxscript not installed"),
                       (("onnx", "onnxscript"), "found onnx and onnxscript not installed")):
        monkeypatch.setattr(importlib.util, "find_spec",
                            lambda name, *a, gone=gone: None if name in gone else real(name, *a))
        r = run_cli("export-onnx", "--samples", "2", "--size", "32", "-o", tmp_path / "g.onnx")
        assert r.code == 7 and "head360[export]" in r.err, r.err
        assert said in r.err, r.err  # both named when both are missing
        assert not (tmp_path / "g.onnx").exists()


def test_export_traces_on_the_cpu_whatever_the_device(run_cli, monkeypatch, tmp_path):
    """torch's exporter failed to trace a CUDA renderer (torch 2.11 on an H200, 2026-12-04)
    and traced the same head on that machine's CPU: ``--device cuda`` is not used, and
    the command says so (here, with no GPU, it would otherwise fail to find one)."""
    import head360cli.export.onnx as onnx_export

    seen = []

    def fake_export(renderer, out, progress=None, inputs=None):
        seen.append(renderer.device.type)
        return {"files": [str(out)], "seconds": 0.0}

    monkeypatch.setattr(onnx_export, "export_onnx", fake_export)
    r = run_cli("export-onnx", "--samples", "2", "--size", "32", "-o", tmp_path / "g.onnx",
                "--device", "cuda")
    assert r.code == 0, r.err
    assert seen == ["cpu"]
    assert "export-onnx traces on the CPU" in r.err and "--device cuda is not used" in r.err
    r = run_cli("export-onnx", "--samples", "2", "--size", "32", "-o", tmp_path / "h.onnx")
    assert r.code == 0 and seen == ["cpu", "cpu"] and "traces on the CPU" not in r.err


@pytest.mark.slow
def test_export_reads_the_head_once_so_a_pipe_works(run_cli, monkeypatch, tmp_path, pipe,
                                                    head_file):
    """``export-onnx --head <(...)``: the head is read once (it was read again for its
    inputs file, and a pipe read twice waits forever), the inputs are the head's own, and
    the file is named after the pipe as other outputs are (``pipe_inputs.npz``)."""
    import head360cli.export.onnx as onnx_export
    from head360cli.export.onnx import head_inputs
    from head360cli.fitting.pipeline import load_head_renderer

    asked = []

    def fake_export(renderer, out, progress=None, inputs=None):
        asked.append(inputs)
        return {"files": [str(out)], "seconds": 0.0}

    monkeypatch.setattr(onnx_export, "export_onnx", fake_export)
    r = run_cli("export-onnx", "--head", pipe(head_file.read_bytes(), "63"), "--samples",
                "2", "--size", "32", "-o", tmp_path / "g.onnx")
    assert r.code == 0, r.err
    (path, got), = asked  # written by export_onnx, with the graphs, as one set
    assert path == tmp_path / "pipe_inputs.npz"
    want = head_inputs(load_head_renderer(head_file, samples=2, size=32, precision="fp32"))
    assert set(got) == set(want)
    for key, value in want.items():
        np.testing.assert_array_equal(got[key], value)


@pytest.mark.slow
def test_export_writes_the_graphs_and_inputs_as_one_set(head_file, tmp_path, monkeypatch):
    """The two graphs and the head's inputs are renamed together: a failure at the last
    one (a full disk) left the new graphs beside an older export's inputs. Names made
    from the output's (``_bald``) are checked before the trace."""
    import head360cli.export.onnx as onnx_export
    from head360cli.errors import BadInputError
    from head360cli.fitting.pipeline import load_head_renderer

    traced = []

    def fake_graph(renderer, hair, path, cull, meta):
        traced.append(hair)
        Path(path).write_bytes(b"new graph")

    monkeypatch.setattr(onnx_export, "_export_graph", fake_graph)
    r = load_head_renderer(head_file, samples=2, size=32)
    old = {tmp_path / n: b"old" for n in ("g.onnx", "g_bald.onnx", "me_inputs.npz")}
    for path, data in old.items():
        path.write_bytes(data)

    def full_disk(*args, **kwargs):
        raise OSError(28, "No space left on device")

    with monkeypatch.context() as m:
        m.setattr(np, "savez", full_disk)
        with pytest.raises(OSError, match="No space"):
            onnx_export.export_onnx(r, tmp_path / "g.onnx", parallel=False,
                                    inputs=(tmp_path / "me_inputs.npz", {"a": np.ones(3)}))
    assert traced == [True, False]
    assert {p: p.read_bytes() for p in tmp_path.iterdir()} == old  # no temporary left
    res = onnx_export.export_onnx(r, tmp_path / "g.onnx", parallel=False,
                                  inputs=(tmp_path / "me_inputs.npz", {"a": np.ones(3)}))
    assert res["files"] == [str(p) for p in old]
    assert (tmp_path / "g_bald.onnx").read_bytes() == b"new graph"
    with np.load(tmp_path / "me_inputs.npz") as got:
        np.testing.assert_array_equal(got["a"], np.ones(3))
    long = tmp_path / ("x" * 248 + ".onnx")  # fits, but its _bald graph's name does not
    with pytest.raises(BadInputError, match="at most 255 bytes"):
        onnx_export.export_onnx(r, long, parallel=False)
    assert len(traced) == 4 and not long.exists()


def test_no_room_in_shared_memory_traces_both_graphs_here(head_file, monkeypatch):
    """A container's small /dev/shm (16 MiB): pickling the head for the process tracing
    the bald graph failed with torch's "unable to allocate shared memory", and
    ``export-onnx`` stopped as an internal error. Both graphs are traced here, and the
    process waiting for the job is ended at once, not after the 30 s join."""
    import time
    from multiprocessing.reduction import ForkingPickler

    import head360cli.export.onnx as onnx_export
    from head360cli.fitting.pipeline import load_head_renderer

    traced = []
    monkeypatch.setattr(onnx_export, "_export_graph",
                        lambda renderer, hair, path, cull, meta: traced.append(hair))

    def full(*args, **kwargs):
        raise RuntimeError("unable to allocate shared memory(shm) for file "
                           "</torch_1_2_3>: No space left on device (28)")

    monkeypatch.setattr(ForkingPickler, "dumps", full)
    r = load_head_renderer(head_file, samples=2, size=32)
    start = time.perf_counter()
    spawned = onnx_export._export_pair(r, Path("g.onnx"), Path("g_bald.onnx"), True, {},
                                       None)
    assert spawned is False and traced == [True, False]
    assert time.perf_counter() - start < 20

    def other(*args, **kwargs):
        raise RuntimeError("a bug")

    monkeypatch.setattr(ForkingPickler, "dumps", other)
    with pytest.raises(RuntimeError, match="a bug"):
        onnx_export._export_pair(r, Path("g.onnx"), Path("g_bald.onnx"), True, {}, None)


@pytest.mark.slow
def test_inspect_tells_what_an_exported_graph_takes(run_cli, exported):
    """``head360 inspect gen.onnx``: the graph's inputs and head360's export metadata, as
    the runner reads them."""
    import json

    from head360cli.export.onnx import OnnxFrameRunner

    _, out, code, _ = exported
    assert code == 0
    r = run_cli("inspect", out, "--json")
    assert r.code == 0, r.err
    j = json.loads(r.out)
    runner = OnnxFrameRunner(out)
    assert (j["kind"], j["format"]) == ("model", "head360-onnx")
    assert j["export"] == {**runner.meta, "hair": True}
    assert list(j["inputs"]) == [i.name for i in runner.sessions[True].get_inputs()]
    assert j["export"]["size"] == 48


def test_a_graph_exported_with_another_hair_texture_side_gets_it_resized():
    """Graphs exported before renders read the hair texture at HAIR_TEXTURE_SIDE took
    the network's 64 texels a side: the runner resizes a head's texture to the side the
    graph asks for, and leaves it as it is where they agree."""
    from types import SimpleNamespace

    from head360cli.export.onnx import _planes_for

    def session(side):
        return SimpleNamespace(get_inputs=lambda: [SimpleNamespace(
            name="hair_planes", shape=[1, 16, side, side])])

    planes = np.random.default_rng(0).uniform(0, 1, (1, 16, 256, 256)).astype(np.float32)
    small = _planes_for(session(64), planes)
    assert small.shape == (1, 16, 64, 64)
    np.testing.assert_allclose(small[0, :, 0, 0], planes[0, :, :4, :4].mean((1, 2)),
                               atol=1e-5)  # area-averaged
    assert _planes_for(session(256), planes) is planes
