"""`dbcslam discrepancy`: bags in, verdict + JSON + Markdown + model YAML out.

Synthetic edge bags (core model, 0.5 mm noise, nominal friction = the single candidate)
with one hidden effect (never written to /scenario); the truth topics are deleted in one
copy and the verdict must not change; bad input exits 2 naming the file.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from edge_data import hidden_effect_trajectory, single_mu_edge_scenario

from dbcslam_core.extensions import ModelExtension
from dbcslam_core.scenario import Scenario
from dbcslam_core.synthetic import Trajectory
from dbcslam_ros.bag import BagWriter, open_bag
from dbcslam_ros.cli import main as cli_main
from dbcslam_ros.filter_node import load_extensions
from dbcslam_ros.replay import write_trajectory_bag


def _scenario() -> Scenario:
    return single_mu_edge_scenario(0.0005)


def _trajectory(extensions: tuple[ModelExtension, ...], seed: int) -> Trajectory:
    return hidden_effect_trajectory(extensions, seed, duration=4.0, position_noise=0.0005)


def _strip_truth(src: Path, dst: Path) -> Path:
    with open_bag(src) as reader, BagWriter(dst) as writer:
        for raw in reader.messages():
            if not raw.topic.startswith("/truth/"):
                writer.add_topic(raw.topic, raw.msgtype, raw.qos)
                writer.write(raw.topic, raw.data, raw.log_time_ns)
    return dst


@pytest.fixture(scope="module")
def damped(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, ModelExtension]:
    rng = np.random.default_rng(20261121)
    ext = ModelExtension.make("viscous_damping", b=float(rng.uniform(0.7, 1.4)))
    base = tmp_path_factory.mktemp("disc")
    bag = write_trajectory_bag(_trajectory((ext,), seed=int(rng.integers(100))), base / "edge")
    return bag, ext


def test_cli_names_the_hidden_effect_and_writes_the_model(
    damped: tuple[Path, ModelExtension], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag, ext = damped
    out = tmp_path / "rep" / "edge.json"
    rc = cli_main(["discrepancy", str(bag), "--json", str(out)])
    assert rc == 0
    data = json.loads(out.read_text())
    assert data["verdict"] == "viscous_damping"
    assert data["extended"]["params"]["b"] == pytest.approx(ext.param("b"), rel=0.25)
    assert data["gain"] >= 1.5
    assert data["nominal"]["heldout_rmse"] > data["extended"]["heldout_rmse"]
    assert "held out" in data["heldout"]
    names = {c["effect"] for c in data["candidates"]}
    assert {"friction_scale", "viscous_damping", "sensor_delay", "sensor_bias"} <= names
    md = out.with_suffix(".md")
    assert "viscous_damping" in md.read_text()
    assert (tmp_path / "rep" / "edge_residuals.png").stat().st_size > 0
    exts = load_extensions(str(tmp_path / "rep" / "edge_model.yaml"))
    assert [e.effect for e in exts] == ["viscous_damping"]
    assert exts[0].param("b") == pytest.approx(data["extended"]["params"]["b"], rel=1e-5)
    assert "verdict: viscous_damping" in capsys.readouterr().out


def test_truth_topics_do_not_matter(damped: tuple[Path, ModelExtension], tmp_path: Path) -> None:
    bag, _ = damped
    stripped = _strip_truth(bag, tmp_path / "notruth")
    with open_bag(stripped) as reader:
        assert not any(t.startswith("/truth/") for t in reader.counts())
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    assert cli_main(["discrepancy", str(bag), "--json", str(a), "--no-plots"]) == 0
    assert cli_main(["discrepancy", str(stripped), "--json", str(b), "--no-plots"]) == 0
    da, db = json.loads(a.read_text()), json.loads(b.read_text())
    assert da["verdict"] == db["verdict"] == "viscous_damping"
    assert da["extended"]["params"] == db["extended"]["params"]


def test_no_effect_bag_gives_none_and_an_empty_model(tmp_path: Path) -> None:
    bag = write_trajectory_bag(_trajectory((), seed=11), tmp_path / "plain")
    out = tmp_path / "plain.json"
    assert cli_main(["discrepancy", str(bag), "--json", str(out), "--no-plots"]) == 0
    data = json.loads(out.read_text())
    assert data["verdict"] == "none"
    assert data["gain"] == 1.0
    assert load_extensions(str(tmp_path / "plain_model.yaml")) == ()


def test_bad_bag_exits_2_naming_the_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "broken"
    bad.mkdir()
    (bad / "metadata.yaml").write_text("not: a bag\n")
    rc = cli_main(["discrepancy", str(bad), "--json", str(tmp_path / "x.json")])
    assert rc == 2
    assert "broken" in capsys.readouterr().err
