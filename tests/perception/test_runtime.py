"""The perception model files: checked by SHA-256, clear errors when missing, damaged or
unsupported."""

import shutil

import pytest

from head360cli.errors import FileFormatError, ModelNotFoundError, UnsupportedPlatformError
from head360cli.perception import runtime


@pytest.fixture
def models_copy(tmp_path, monkeypatch):
    """A models folder with a copy of the shipped perception files, used instead."""
    from head360cli.paths import models_dir

    ours = {spec.filename for spec in runtime.PERCEPTION_FILES.values()}
    for path in models_dir().iterdir():
        if path.name in ours:
            shutil.copy(path, tmp_path / path.name)
        else:
            (tmp_path / path.name).symlink_to(path)
    monkeypatch.setenv("HEAD360_MODELS", str(tmp_path))
    _forget()
    yield tmp_path
    _forget()


def _forget():
    """Forget the files and models loaded so far in this process."""
    from head360cli.perception import faces
    from head360cli.perception.ibug68 import load_ibug68_map

    for cached in (runtime.perception_file, runtime._tflite_model, faces._yunet,
                   load_ibug68_map):
        cached.cache_clear()


def test_every_shipped_file_matches_its_recorded_digest():
    for role in runtime.PERCEPTION_FILES:
        assert runtime.perception_file(role).is_file()


def test_a_missing_file_names_itself_and_what_to_do(models_copy):
    (models_copy / "hair_segmentation.tflite").unlink()
    with pytest.raises(ModelNotFoundError, match=r"hair_segmentation\.tflite .*reinstall"):
        runtime.perception_file("hair_segmenter")


def test_a_damaged_file_is_refused_by_its_digest(models_copy):
    path = models_copy / "face_landmarker.task"
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))
    with pytest.raises(FileFormatError, match="damaged or replaced"):
        runtime.tflite_model("face_landmarker", "face_landmarks_detector.tflite")


def test_a_cpu_without_avx_is_refused_before_litert_is_imported(monkeypatch, tmp_path):
    cpuinfo = tmp_path / "cpuinfo"
    cpuinfo.write_text("processor: 0\nflags\t\t: fpu sse sse2 ssse3 sse4_1\n")
    real = runtime.Path

    def fake_path(p, *a):
        return real(cpuinfo) if str(p) == "/proc/cpuinfo" else real(p, *a)

    monkeypatch.setattr(runtime.platform, "machine", lambda: "x86_64")
    monkeypatch.setattr(runtime, "Path", fake_path)
    with pytest.raises(UnsupportedPlatformError, match="without"):
        runtime.check_cpu()
    cpuinfo.write_text("processor: 0\nflags\t\t: fpu sse avx avx2\n")
    runtime.check_cpu()  # no error


def test_quiet_stderr_hides_what_c_libraries_print(capfd):
    import os

    with runtime.quiet_stderr():
        os.write(2, b"from C\n")
    os.write(2, b"after\n")
    assert capfd.readouterr().err == "after\n"


def test_a_damaged_model_is_a_one_line_error_of_the_cli(models_copy, run_cli, tmp_path):
    import skimage.data
    import skimage.io

    photo = tmp_path / "a.png"
    skimage.io.imsave(photo, skimage.data.astronaut())
    (models_copy / "face_landmarker.task").write_bytes(b"not a model")
    r = run_cli("fit", photo, "--stage", "shape", "-o", tmp_path / "out")
    assert r.code == 5 and r.err.count("\n") == 1 and "damaged or replaced" in r.err, r.err
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())
