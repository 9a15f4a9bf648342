"""The commands the README and the ``--help`` examples show name real subcommands and
options, so the documentation cannot drift from the CLI unnoticed."""

from __future__ import annotations

import re
import shlex

import click

from head360cli.cli import cli
from tests.conftest import REPO

_GLOBAL_WITH_VALUE = {"--device", "--threads"}


def _check(args: list[str]) -> str | None:
    """What is wrong with ``head360 ARGS`` (an unknown command or option), or ``None``."""
    command: click.Command = cli
    rest = list(args)
    while rest and rest[0].startswith("-"):  # the group's own options
        if rest.pop(0) in _GLOBAL_WITH_VALUE and rest:
            rest.pop(0)
    while isinstance(command, click.Group) and rest:
        name = rest.pop(0)
        if name in ("-h", "--help", "-V", "--version"):
            return None
        if name not in command.commands:
            return f"no command {name!r}"
        command = command.commands[name]
    known = {o for p in command.params for o in (*p.opts, *p.secondary_opts)}
    for arg in rest:
        option = arg.split("=")[0]
        if arg.startswith("-") and arg != "-" and not re.match(r"-\.?\d", arg) \
                and option not in known:
            return f"{command.name}: no option {option!r}"
    return None


def _invocations(lines: list[str]) -> list[list[str]]:
    """``head360 ...`` invocations in shell lines, cut at pipes, redirections and
    comments; a process substitution ``<(...)`` stands for a file."""
    found = []
    for line in lines:
        line = re.sub(r"<\([^)]*\)", "FILE", line.strip())
        for m in re.finditer(r"(?:^|[|;&(]\s*|\$ )head360 ([^|;&#>)]*)", line):
            text = re.split(r"\s{2,}|\s2>", m.group(1))[0]
            try:
                found.append(shlex.split(text))
            except ValueError:  # an unbalanced quote in prose
                continue
    return found


def test_readme_commands_name_real_commands_and_options():
    text = (REPO / "README.md").read_text()
    blocks = re.findall(r"```[a-z]*\n(.*?)```", text, flags=re.S)
    lines = [line for block in blocks for line in block.splitlines()]
    lines += re.findall(r"`(head360 [^`]+)`", re.sub(r"```.*?```", "", text, flags=re.S))
    calls = _invocations(lines)
    problems = [(" ".join(c), why) for c in calls if (why := _check(c))]
    assert problems == []
    # every command is shown at least once (bench's subcommands under `bench`)
    shown = {c[0] for c in calls if c}
    assert set(cli.commands) <= shown, sorted(set(cli.commands) - shown)


def test_help_examples_name_real_commands_and_options():
    calls = []

    def walk(command: click.Command) -> None:
        lines = [ln for ln in (command.help or "").splitlines()
                 if ln.strip().startswith(("head360 ", "cat "))]
        calls.extend(_invocations(lines))
        for sub in getattr(command, "commands", {}).values():
            walk(sub)

    walk(cli)
    assert len(calls) >= 60
    problems = [(" ".join(c), why) for c in calls if (why := _check(c))]
    assert problems == []


def test_the_check_finds_a_stale_example():
    """The checks above can fail: an option or command that is not there is reported."""
    assert _check(["render", "me.h360", "--yaw", "30"]) is None
    assert _check(["--device", "cuda", "bench", "all", "--quick"]) is None
    assert _check(["render", "me.h360", "--angle", "30"]) == "render: no option '--angle'"
    assert _check(["morph", "me.h360"]) == "no command 'morph'"
    assert _check(["bench", "speed"]) == "no command 'speed'"
    assert _invocations(["cat t.csv | head360 inspect - --json > out.json  # a comment"]) == [
        ["inspect", "-", "--json"]]
    assert _invocations(["head360 fit <(curl -s https://x.org/me.jpg) -o me.h360"]) == [
        ["fit", "FILE", "-o", "me.h360"]]
