"""Missing, empty, truncated and corrupt bags: exit code 2 naming the file; --salvage."""

from __future__ import annotations

import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from dbcslam_ros.bag import BagWriter, jazzy_typestore, open_bag, read_bag, serialize
from dbcslam_ros.cli import main
from dbcslam_ros.errors import BagError

N = 40


def _payload(i: int) -> bytes:
    string = jazzy_typestore().types["std_msgs/msg/String"]
    return serialize(string(data=f"message {i:03d} " + "x" * 50))[1]


@pytest.fixture
def good_bag(tmp_path: Path) -> Path:
    """A bag of N String messages in several small chunks."""
    path = tmp_path / "good"
    with BagWriter(path, chunk_size=512) as writer:
        writer.add_topic("/chatter", "std_msgs/msg/String")
        for i in range(N):
            writer.write("/chatter", _payload(i), 1_000 + i)
    return path


def _mcap(bag: Path) -> Path:
    return next(bag.glob("*.mcap"))


def _info(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(["bag", "info", *args])
    out, err = capsys.readouterr()
    return code, out, err


def _truncate(tmp_path: Path, bag: Path, keep: float) -> Path:
    """A copy of the bag's MCAP cut to ``keep`` of its size, without metadata (a killed
    recorder leaves exactly this)."""
    data = _mcap(bag).read_bytes()
    target = tmp_path / "cut"
    target.mkdir()
    (target / "cut_0.mcap").write_bytes(data[: int(len(data) * keep)])
    return target


def _corrupt_chunk(tmp_path: Path, bag: Path) -> Path:
    """A copy of the bag with message bytes in the middle of the data section altered."""
    target = tmp_path / "corrupt"
    shutil.copytree(bag, target)
    mcap = _mcap(target)
    data = bytearray(mcap.read_bytes())
    pos = data.find(b"message 020")
    assert pos > 0
    data[pos : pos + 11] = b"MESSAGE 020"
    mcap.write_bytes(bytes(data))
    return target


def _bad(kind: str, tmp_path: Path, good_bag: Path) -> tuple[Path, str]:
    """(path given to the CLI, path that the message must name)."""
    if kind == "missing":
        p = tmp_path / "nope"
        return p, str(p)
    if kind == "empty_dir":
        p = tmp_path / "emptydir"
        p.mkdir()
        return p, str(p)
    if kind == "empty_file":
        p = tmp_path / "empty.mcap"
        p.write_bytes(b"")
        return p, str(p)
    if kind == "truncated":
        p = _truncate(tmp_path, good_bag, 0.6)
        return p, str(p / "cut_0.mcap")
    if kind == "corrupt_chunk":
        p = _corrupt_chunk(tmp_path, good_bag)
        return p, str(_mcap(p))
    if kind == "not_mcap":
        p = tmp_path / "text.mcap"
        p.write_text("hello, I am not a bag\n" * 10)
        return p, str(p)
    if kind == "bad_metadata":
        p = tmp_path / "badmeta"
        shutil.copytree(good_bag, p)
        (p / "metadata.yaml").write_text("rosbag2_bagfile_information: [unclosed\n")
        return p, str(p / "metadata.yaml")
    if kind == "count_mismatch":
        p = tmp_path / "mismatch"
        shutil.copytree(good_bag, p)
        meta = p / "metadata.yaml"
        meta.write_text(meta.read_text().replace(f"message_count: {N}", f"message_count: {N + 1}"))
        return p, str(meta)
    raise AssertionError(kind)


BAD_KINDS = [
    "missing",
    "empty_dir",
    "empty_file",
    "truncated",
    "corrupt_chunk",
    "not_mcap",
    "bad_metadata",
    "count_mismatch",
]


@pytest.mark.parametrize("kind", BAD_KINDS)
def test_bad_bag_gives_exit_2_and_one_line_naming_the_file(
    kind: str, tmp_path: Path, good_bag: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path, named = _bad(kind, tmp_path, good_bag)
    code, out, err = _info([str(path)], capsys)
    assert code == 2
    assert out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("dbcslam bag: error: ")
    assert named in lines[0]


@pytest.mark.parametrize("kind", ["truncated", "corrupt_chunk", "empty_file"])
def test_bad_bag_raises_bag_error_in_the_api(kind: str, tmp_path: Path, good_bag: Path) -> None:
    path, named = _bad(kind, tmp_path, good_bag)
    with pytest.raises(BagError, match=named):
        read_bag(path)


def test_truncation_hint_names_salvage(tmp_path: Path, good_bag: Path) -> None:
    with pytest.raises(BagError, match=r"truncated.*--salvage"):
        open_bag(_truncate(tmp_path, good_bag, 0.5))


def test_console_script_exit_code_for_a_missing_bag(tmp_path: Path) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "dbcslam_ros.cli", "bag", "info", str(tmp_path / "gone")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2
    assert str(tmp_path / "gone") in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1


def _expected_prefix(bag_file_bytes: bytes, cut: int) -> list[bytes]:
    """Payloads whose complete bytes lie before ``cut`` (message records hold them last)."""
    out = []
    for i in range(N):
        pos = bag_file_bytes.find(_payload(i))
        assert pos > 0
        if pos + len(_payload(i)) <= cut:
            out.append(_payload(i))
    return out


@pytest.mark.parametrize("keep", [0.15, 0.5, 0.83, 0.99])
def test_salvage_yields_every_message_before_the_damage(
    keep: float, tmp_path: Path, good_bag: Path
) -> None:
    data = _mcap(good_bag).read_bytes()
    cut_dir = _truncate(tmp_path, good_bag, keep)
    expected = _expected_prefix(data, int(len(data) * keep))
    with open_bag(cut_dir, salvage=True) as bag:
        got = [m.data for m in bag.messages()]
        assert bag.damage is not None
        assert "cut_0.mcap" in bag.damage
        assert bag.counts() == ({"/chatter": len(got)} if got else {})
    assert got == expected
    assert len(got) >= int(N * keep) - 12  # small chunks: little is lost


def test_salvage_of_a_corrupt_chunk_stops_before_it(
    tmp_path: Path, good_bag: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    corrupt = _corrupt_chunk(tmp_path, good_bag)
    got = read_bag(corrupt, salvage=True)
    assert 0 < len(got) < 20
    assert [m.data for m in got] == [_payload(i) for i in range(len(got))]
    code, out, _ = _info(["--salvage", str(corrupt)], capsys)
    assert code == 0
    assert f"Messages:          {len(got)}" in out
    assert "CRC" in out


def test_bag_info_reports_counts_topics_and_duration(
    good_bag: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, err = _info([str(good_bag)], capsys)
    assert code == 0, err
    assert f"Messages:          {N}" in out
    assert "Topic: /chatter | Type: std_msgs/msg/String | Count: 40" in out
    assert f"Duration:          {(N - 1) / 1e9:.9f}s" in out
    assert "good_0.mcap" in out


def test_salvaged_bag_plays_and_reads_in_bag_info(
    tmp_path: Path, good_bag: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cut_dir = _truncate(tmp_path, good_bag, 0.7)
    code, out, _ = _info(["--salvage", str(cut_dir)], capsys)
    assert code == 0
    assert "Damage:" in out
    assert "Topic: /chatter" in out


@pytest.mark.parametrize("make", [lambda p: p, lambda p: p / "metadata.yaml"])
def test_bag_can_be_named_by_directory_or_metadata_file(
    good_bag: Path, make: Callable[[Path], Any]
) -> None:
    assert len(read_bag(make(good_bag))) == N


@pytest.mark.parametrize("kind", ["missing", "truncated", "corrupt_chunk", "empty_file"])
def test_play_of_a_bad_bag_fails_with_2_before_any_dds_work(
    kind: str, tmp_path: Path, good_bag: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path, named = _bad(kind, tmp_path, good_bag)
    assert main(["play", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert named in err[0]


def test_play_of_a_bag_without_messages_is_bad_input(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with BagWriter(tmp_path / "nothing") as writer:
        writer.add_topic("/chatter", "std_msgs/msg/String")
    assert main(["play", str(tmp_path / "nothing")]) == 2
    assert "no messages" in capsys.readouterr().err
    # bag info of the same bag is fine: it reports zero messages.
    code, out, _ = _info([str(tmp_path / "nothing")], capsys)
    assert code == 0
    assert "Messages:          0" in out


def test_play_of_an_unknown_topic_names_it(
    good_bag: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["play", str(good_bag), "--topics", "/nope"]) == 2
    err = capsys.readouterr().err
    assert "/nope" in err
    assert "/chatter" in err


def test_bag_info_of_a_directory_of_bags_reports_each(
    tmp_path: Path, good_bag: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    many = tmp_path / "many"
    many.mkdir()
    shutil.copytree(good_bag, many / "a")
    shutil.copytree(good_bag, many / "b")
    code, out, err = _info([str(many)], capsys)
    assert code == 0, err
    assert f"== {many / 'a'} ==" in out
    assert f"== {many / 'b'} ==" in out
    assert out.count(f"Messages:          {N}") == 2
