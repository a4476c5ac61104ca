"""``dbcslam`` argument parsing: subcommand table, --help of every command, usage errors."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from dbcslam_ros.cli import build_parser, main
from dbcslam_ros.cli.registry import discover_commands

# (argv prefix, words the help must contain)
HELP_CASES = [
    (["record"], ["Record live topics", "--overwrite", "--duration", "dbcslam record -o"]),
    (["play"], ["--rate", "--loop", "--clock", "--salvage", "latched", "dbcslam play"]),
    (["topic"], ["list", "echo", "hz", "dbcslam topic"]),
    (["topic", "list"], ["-t", "--spin-time", "dbcslam topic list"]),
    (["topic", "echo"], ["--once", "--field", "--qos", "---", "dbcslam topic echo"]),
    (["topic", "hz"], ["--window", "dbcslam topic hz"]),
    (["bag"], ["info", "dbcslam bag info"]),
    (["bag", "info"], ["ros2 bag info", "--salvage", "dbcslam bag info"]),
]


def test_commands_of_this_issue_are_registered() -> None:
    names = set(discover_commands())
    assert {"record", "play", "topic", "bag"} <= names


@pytest.mark.parametrize(("argv", "words"), HELP_CASES, ids=[" ".join(c[0]) for c in HELP_CASES])
def test_help_explains_and_shows_an_example(
    argv: list[str], words: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        main([*argv, "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "examples:" in out
    flat = " ".join(out.split())  # help text is wrapped at any space
    for word in words:
        assert word in flat, f"{word!r} missing from help of {argv}"


def test_top_level_help_lists_every_registered_command(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for name in discover_commands():
        assert f"    {name}" in out
    assert "exit codes" in out


@pytest.mark.parametrize(
    "argv",
    [
        [],
        ["no-such-command"],
        ["play"],
        ["play", "bag", "--rate", "0"],
        ["play", "bag", "--rate", "-1"],
        ["record"],
        ["record", "-o", "x", "--duration", "nan"],
        ["topic", "hz"],
        ["bag"],
    ],
)
def test_bad_usage_exits_with_2(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert "usage:" in capsys.readouterr().err


def test_relative_topic_name_is_bad_usage(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(["record", "-o", f"{tmp_path}/b", "chatter"])
    assert code == 2
    assert "'chatter'" in capsys.readouterr().err


def test_record_refuses_an_existing_bag_before_touching_dds(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    target = tmp_path / "exists"
    target.mkdir()
    code = main(["record", "-o", str(target)])
    err = capsys.readouterr().err
    assert code == 2
    assert str(target) in err
    assert "--overwrite" in err


def test_parser_builds_with_an_explicit_table() -> None:
    table = discover_commands()
    parser = build_parser({"bag": table["bag"]})
    args = parser.parse_args(["bag", "info", "x"])
    assert args.bag == "x"
    with pytest.raises(SystemExit):
        parser.parse_args(["record", "-o", "x"])


def test_console_script_help_runs_in_a_fresh_process() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "dbcslam_ros.cli", "--help"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0
    assert "record" in proc.stdout


@pytest.mark.parametrize("name", sorted(discover_commands()))
def test_every_registered_command_has_help_with_examples(
    name: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        main([name, "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert f"dbcslam {name}" in out
    assert "examples:" in out


@pytest.mark.parametrize("command", ["demo", "filter"])
def test_help_texts_name_the_live_defaults(
    command: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """The live particle defaults quoted by `dbcslam demo --help` and `dbcslam filter --help`
    are the node's (`LIVE_PARTICLES`): a changed default must change the texts too."""
    from dbcslam_ros.node.params import LIVE_PARTICLES

    with pytest.raises(SystemExit):
        main([command, "--help"])
    flat = " ".join(capsys.readouterr().out.split())
    quoted = ", ".join(f"{kind} {n}" for kind, n in LIVE_PARTICLES.items())
    assert quoted in flat, f"{command} --help does not quote the live defaults ({quoted})"
