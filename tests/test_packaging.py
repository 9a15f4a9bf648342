"""The README's two set-up commands, CI and the package metadata stay consistent."""

from __future__ import annotations

import importlib.metadata
import os
import re
import subprocess
import sys

import pytest

from tests.conftest import REPO


def readme_commands() -> list[str]:
    text = (REPO / "README.md").read_text()
    section = text.split("## Install", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"```bash\n(.+?)\n```", section, flags=re.S)


def test_readme_has_exactly_two_setup_commands():
    commands = readme_commands()
    assert len(commands) == 2
    install_run, install_test = commands
    assert "\n" not in install_run and "\n" not in install_test
    for cmd in commands:
        # the pinned CPU torch goes first, before the project pulls in a torch range
        assert cmd.index("pip install torch==2.13.0") < cmd.rindex("pip install")
    assert "head360 " in install_run
    assert install_test.endswith("python -m pytest")


def test_ci_runs_the_readme_test_command_verbatim():
    ci = (REPO / ".ci" / "run").read_text()
    match = re.search(r"^README_TEST_COMMAND='(.+)'$", ci, flags=re.M)
    assert match is not None
    assert match.group(1) == readme_commands()[1]
    assert "ruff check" in ci
    assert ci.index("torch==2.13.0") < ci.index('-e ".[test]"')


def test_bundled_input_of_the_main_command_exists():
    main = readme_commands()[0]
    for token in main.split():
        if token.startswith("examples/"):
            assert (REPO / token).is_file(), token


def test_installed_metadata_and_dependencies():
    dist = importlib.metadata.distribution("head360")
    requires = dist.requires or []
    deps = {re.split(r"[<>=!; \[]", d, maxsplit=1)[0]: d for d in requires if "extra ==" not in d}
    extras = {re.search(r'extra == "(\w+)"', d).group(1) for d in requires if "extra ==" in d}
    for name in ("numpy", "scipy", "torch", "onnxruntime", "opencv-contrib-python-headless",
                 "trimesh", "scikit-image", "imageio", "imageio-ffmpeg", "click", "tqdm",
                 "dlib-bin", "face-recognition-models"):
        assert name in deps, name
    assert "==" not in deps["torch"] and "<" in deps["torch"]  # a range, not a pin
    assert dist.metadata["Requires-Python"] == ">=3.10"
    assert extras == {"test", "export", "heic"}
    scripts = {ep.name: ep.value for ep in dist.entry_points if ep.group == "console_scripts"}
    assert scripts == {"head360": "head360cli.cli:main"}


def test_every_subpackage_is_listed_for_installation():
    text = (REPO / "pyproject.toml").read_text()
    listed = set(re.findall(r'^\s+"(head360cli[\w.]*)",$', text, flags=re.M))
    on_disk = {
        ".".join(p.parent.relative_to(REPO).parts)
        for p in (REPO / "head360cli").rglob("__init__.py")
    }
    assert on_disk <= listed, f"add to [tool.setuptools] packages: {sorted(on_disk - listed)}"
    assert "head360cli._models" in listed


def _slug(heading: str) -> str:
    """GitHub's anchor for a Markdown heading: lower case, punctuation dropped, spaces as
    hyphens."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def test_readme_links_resolve():
    """Every relative link and picture in the README, the model card and the docs names a file
    that exists, and every #anchor one of that file's headings."""
    pages = [REPO / "README.md", REPO / "models" / "MODEL_CARD.md",
             *sorted((REPO / "docs").glob("*.md"))]
    assert len(pages) >= 5  # the README, the card, benchmarks, architecture, decisions
    checked = 0
    for page in pages:
        for target in re.findall(r"\]\(([^)\s]+)\)", page.read_text()):
            if re.match(r"[a-z]+:", target):
                continue  # http(s), mailto: not ours to check offline
            path, _, anchor = target.partition("#")
            dest = (page.parent / path).resolve() if path else page
            assert dest.exists(), f"{page.name}: link to missing {target}"
            if anchor and dest.suffix == ".md":
                slugs = {_slug(h) for h in re.findall(r"^#+ (.+)$", dest.read_text(), re.M)}
                assert anchor in slugs, f"{page.name}: no heading for #{anchor} in {dest.name}"
            checked += 1
    assert checked >= 15  # the pictures and the links between the pages


@pytest.mark.slow
def test_onnxruntime_keeps_no_telemetry_in_the_users_home(tmp_path):
    """onnxruntime 1.32 wrote a device identifier and a SQLite queue of usage events to
    ~/.cache/Microsoft on its first import, to upload when online, each time head360
    ran ``info``, ``inspect`` of a graph or ``--backend onnx``. Importing head360 first
    turns that off; a user who sets ORT_DISABLE_TELEMETRY keeps their own choice."""
    pytest.importorskip("onnxruntime")

    def home_after(code: str, **extra: str):
        home = tmp_path / f"home{len(list(tmp_path.iterdir()))}"
        home.mkdir()
        # onnxruntime keeps no telemetry on a CI service (its own list, which .ci/run's
        # CI=1 is on), so the variables go for the control to mean anything there
        env = {k: v for k, v in os.environ.items() if k not in {
            "ORT_DISABLE_TELEMETRY", "XDG_CACHE_HOME", "CI", "TF_BUILD", "GITHUB_ACTIONS",
            "GITLAB_CI", "CIRCLECI", "TRAVIS", "JENKINS_URL", "CODEBUILD_BUILD_ID",
            "BUILDKITE", "TEAMCITY_VERSION", "APPVEYOR", "BITBUCKET_BUILD_NUMBER",
            "ORT_RUNNING_UNIT_TESTS"}}
        env.update(HOME=str(home), **extra)
        subprocess.run([sys.executable, "-c", code], env=env, check=True, timeout=120,
                       capture_output=True)
        return home / ".cache" / "Microsoft"

    if not home_after("import onnxruntime").exists():
        pytest.skip("this onnxruntime keeps no telemetry folder to check against")
    assert not home_after("import head360cli, onnxruntime").exists()
    assert not home_after("from head360cli.cli import main; main(['info'])").exists()
    assert home_after("import head360cli, onnxruntime",
                      ORT_DISABLE_TELEMETRY="0").exists()
