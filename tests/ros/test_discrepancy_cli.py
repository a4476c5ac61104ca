"""`dbcslam discrepancy`: bags in, verdict + JSON + Markdown + model YAML out.

Synthetic edge bags as in the paper (rough mu 0.9 region between smooth mu 0.3 edge, 1 cm
pose noise, 6 s; `synthetic.edge_sweep_trajectory`) with one hidden effect of a seeded
random size (never written to /scenario), a training and a held-out bag; the truth topics
are deleted in one copy and the verdict must not change; bad input exits 2 naming the file.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from dbcslam_core.extensions import ModelExtension
from dbcslam_core.synthetic import Trajectory, edge_sweep_trajectory
from dbcslam_ros.bag import BagWriter, open_bag
from dbcslam_ros.cli import main as cli_main
from dbcslam_ros.node.params import load_extensions
from dbcslam_ros.offline.discrepancy_report import load_run
from dbcslam_ros.offline.replay import write_trajectory_bag


def _trajectory(extensions: tuple[ModelExtension, ...], seed: int) -> Trajectory:
    return edge_sweep_trajectory(seed, duration=6.0, extensions=extensions)


PARTICLES = ["--particles", "200"]


def _strip_truth(src: Path, dst: Path) -> Path:
    with open_bag(src) as reader, BagWriter(dst) as writer:
        for raw in reader.messages():
            if not raw.topic.startswith("/truth/"):
                writer.add_topic(raw.topic, raw.msgtype, raw.qos)
                writer.write(raw.topic, raw.data, raw.log_time_ns)
    return dst


@pytest.fixture(scope="module")
def damped(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, ModelExtension]:
    rng = np.random.default_rng(20261125)
    ext = ModelExtension.make("viscous_damping", b=float(rng.uniform(2.0, 3.5)))
    base = tmp_path_factory.mktemp("disc")
    seed = int(rng.integers(100))
    bag = write_trajectory_bag(_trajectory((ext,), seed=seed), base / "edge")
    held = write_trajectory_bag(_trajectory((ext,), seed=seed + 1), base / "edge_held")
    return bag, held, ext


@pytest.mark.timeout(900)  # one analysis: ~20 filter runs, 2 processes
def test_cli_names_the_hidden_effect_and_writes_the_model(
    damped: tuple[Path, Path, ModelExtension],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    bag, held, ext = damped
    out = tmp_path / "rep" / "edge.json"
    rc = cli_main(
        ["discrepancy", str(bag), "--heldout", str(held), "--json", str(out), *PARTICLES]
    )
    assert rc == 0
    data = json.loads(out.read_text())
    assert data["verdict"] == "viscous_damping"
    assert data["extended"]["params"]["b"] == pytest.approx(ext.param("b"), rel=0.25)
    assert data["loglik_gain"] > 0.0
    assert data["nominal"]["heldout_rmse"] > data["extended"]["heldout_rmse"]
    assert data["gain"] > 1.0
    assert "held-out runs" in data["heldout"]
    names = {c["effect"] for c in data["candidates"]}
    assert {"friction_scale", "viscous_damping", "sensor_delay", "sensor_bias"} <= names
    md = out.with_suffix(".md")
    assert "viscous_damping" in md.read_text()
    assert (tmp_path / "rep" / "edge_residuals.png").stat().st_size > 0
    exts = load_extensions(str(tmp_path / "rep" / "edge_model.yaml"))
    assert [e.effect for e in exts] == ["viscous_damping"]
    assert exts[0].param("b") == pytest.approx(data["extended"]["params"]["b"], rel=1e-5)
    assert "verdict: viscous_damping" in capsys.readouterr().out


@pytest.mark.timeout(600)
def test_truth_topics_do_not_matter(
    damped: tuple[Path, Path, ModelExtension], tmp_path: Path
) -> None:
    """The analysis reads the same data without /truth/* (every array equal), and the
    stripped bag still gives the hidden effect."""
    bag, held, ext = damped
    stripped = _strip_truth(bag, tmp_path / "notruth")
    with open_bag(stripped) as reader:
        assert not any(t.startswith("/truth/") for t in reader.counts())
    a, b = load_run(bag), load_run(stripped)
    for name in ("t", "obs", "u", "env"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert a.scenario == b.scenario
    out = tmp_path / "b.json"
    common = ["--heldout", str(held), "--no-plots", "--effects", "viscous_damping"]
    assert cli_main(["discrepancy", str(stripped), "--json", str(out), *common, *PARTICLES]) == 0
    data = json.loads(out.read_text())
    assert data["verdict"] == "viscous_damping"
    assert data["extended"]["params"]["b"] == pytest.approx(ext.param("b"), rel=0.25)


@pytest.mark.timeout(600)
def test_no_effect_bag_gives_none_and_an_empty_model(tmp_path: Path) -> None:
    bag = write_trajectory_bag(_trajectory((), seed=11), tmp_path / "plain")
    out = tmp_path / "plain.json"
    args = ["discrepancy", str(bag), "--json", str(out), "--no-plots", *PARTICLES]
    assert cli_main(args) == 0
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
