"""``dbcslam import-mitpush`` and :mod:`dbcslam_ros.importers.mitpush` on real and synthetic
push files.

Real files: tests/data/mit-push (3 files of the MIT MCube push dataset, see its README).
"""

from __future__ import annotations

import math
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

import dbcslam_ros.importers.mitpush as mp
from dbcslam_core.scenario import Scenario
from dbcslam_ros.cli import main
from dbcslam_ros.importers.mitpush_bag import CONTACT_TOPIC

DATA = Path(__file__).resolve().parents[1] / "data" / "mit-push"
FILES = sorted((DATA / "abs" / "train").glob("*.h5"))
STEP_TOPICS = (
    "/joint_states",
    "/object/wrench",
    CONTACT_TOPIC,
    "/object/pose",
    "/truth/object/pose",
)
NOISE_POS = 0.002
NOISE_YAW = 0.02


def _stem(path: Path) -> str:
    return path.name.removesuffix(".h5")


def _read_bag(path: Path) -> dict[str, list[tuple[int, Any]]]:
    """topic -> [(log time ns, message)] via rosbags' AnyReader."""
    out: dict[str, list[tuple[int, Any]]] = {}
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        for conn, t, raw in reader.messages():
            out.setdefault(conn.topic, []).append((t, reader.deserialize(raw, conn.msgtype)))
    return out


def _stamp(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def _pose(msg: Any) -> tuple[float, float, float]:
    o = msg.pose.orientation
    yaw = math.atan2(2.0 * (o.w * o.z + o.x * o.y), 1.0 - 2.0 * (o.y * o.y + o.z * o.z))
    return (msg.pose.position.x, msg.pose.position.y, yaw)


@pytest.fixture(scope="module")
def noisy_import(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The three test files imported with noise (one CLI run)."""
    out = tmp_path_factory.mktemp("mitpush") / "bags"
    args = [str(f) for f in FILES]
    flags = ["--noise-position", str(NOISE_POS), "--noise-yaw", str(NOISE_YAW), "--seed", "3"]
    assert main(["import-mitpush", *args, "-o", str(out), *flags]) == 0
    return out


@pytest.fixture(scope="module")
def bags(noisy_import: Path) -> dict[str, dict[str, list[tuple[int, Any]]]]:
    return {_stem(f): _read_bag(noisy_import / _stem(f)) for f in FILES}


def test_test_data_present() -> None:
    assert len(FILES) == 3
    assert {mp.parse_push_name(f).shape for f in FILES} == {"ellip1", "hex", "rect1"}


def test_one_bag_per_file_with_every_topic(
    noisy_import: Path, bags: dict[str, dict[str, list[tuple[int, Any]]]]
) -> None:
    assert sorted(p.name for p in noisy_import.iterdir()) == sorted(_stem(f) for f in FILES)
    for f in FILES:
        topics = bags[_stem(f)]
        info = mp.parse_push_name(f)
        expected = {"/scenario", *STEP_TOPICS}
        if info.shape != "rect1":  # rect1's F/T stream is stale: no /pusher/wrench
            expected.add("/pusher/wrench")
        assert set(topics) == expected, f.name
        counts = {t: len(m) for t, m in topics.items()}
        assert counts.pop("/scenario") == 1
        assert len(set(counts.values())) == 1 and min(counts.values()) > 50
        scenario = Scenario.from_yaml(topics["/scenario"][0][1].data)
        assert scenario.kind == "push"
        assert scenario.contacts == ("pusher",)
        assert scenario.friction.pairs == ("pusher", "surface")
        assert scenario.friction.candidates == ((0.1, 0.2, 0.3), (0.1, 0.2, 0.3))
        assert scenario.pusher_radius == pytest.approx(0.00475)
        # A steel plate cut to the outline: within 0.4 % / 0.8 % of the dataset's table.
        assert scenario.body.mass == pytest.approx(mp.SHAPES[info.shape].mass, rel=0.004)
        assert scenario.body.inertia == pytest.approx(mp.SHAPES[info.shape].inertia, rel=0.008)
        assert scenario.dt == pytest.approx(0.01)
        joints = topics["/joint_states"][0][1]
        assert list(joints.name) == ["pusher_x", "pusher_y"]
        wrench = topics["/object/wrench"][5][1].wrench
        assert (wrench.force.x, wrench.force.y, wrench.torque.z) == (0.0, 0.0, 0.0)


def test_scenario_is_first_and_latched(noisy_import: Path) -> None:
    from dbcslam_ros.bag import open_bag
    from dbcslam_ros.bag.qos import QosDurability

    with open_bag(noisy_import / _stem(FILES[0])) as bag:
        first = next(iter(bag.messages()))
        assert first.topic == "/scenario"
        (qos,) = bag.topics()["/scenario"].offered_qos
        assert qos.durability == QosDurability.TRANSIENT_LOCAL


def test_streams_on_one_clock(bags: dict[str, dict[str, list[tuple[int, Any]]]]) -> None:
    for f in FILES:
        topics = bags[_stem(f)]
        raw = mp.load_push(f)
        ref: list[int] | None = None
        for topic in STEP_TOPICS:
            msgs = topics[topic]
            if topic == CONTACT_TOPIC:
                stamps = [t for t, _ in msgs]  # no header: log time is the stamp
            else:
                stamps = [_stamp(m) for _, m in msgs]
                assert stamps == [t for t, _ in msgs], topic  # log time == header stamp
            if ref is None:
                ref = stamps
            assert stamps == ref, topic
        assert ref is not None
        assert set(np.diff(ref).tolist()) == {10_000_000}
        # The clock lies where all three raw streams have data (Unix time).
        start = max(raw.tip[0, 0], raw.obj[0, 0], raw.ft[0, 0])
        end = min(raw.tip[-1, 0], raw.obj[-1, 0], raw.ft[-1, 0])
        assert abs(ref[0] * 1e-9 - start) < 1e-6
        assert start <= ref[-1] * 1e-9 <= end + 1e-6


@pytest.mark.parametrize("path", FILES, ids=lambda p: mp.parse_push_name(p).shape)
def test_alignment_puts_pusher_on_outline_at_first_contact(path: Path) -> None:
    raw = mp.load_push(path)
    outline = mp.load_outline(raw.info.shape, DATA / "shapes")
    series = mp.resample_push(raw, outline, mp.ImportConfig())
    check = mp.alignment_check(series)
    assert check.onset_index is not None
    # The tip circle touches the outline where the file name says (side i, position s) ...
    assert check.onset_error < 0.003
    assert abs(check.onset_gap) < 0.002
    # ... and stays tangent to it while the object moves.
    assert check.moving_gap < 0.002


@pytest.mark.parametrize("path", FILES, ids=lambda p: mp.parse_push_name(p).shape)
def test_without_yaw_offset_the_contact_is_elsewhere(path: Path) -> None:
    raw = mp.load_push(path)
    outline = mp.load_outline(raw.info.shape, DATA / "shapes")
    series = mp.resample_push(raw, outline, mp.ImportConfig(), mp.ShapeAlignment(0.0))
    check = mp.alignment_check(series)
    assert check.onset_error > 0.01


def test_observation_noise_matches_flags(
    bags: dict[str, dict[str, list[tuple[int, Any]]]],
) -> None:
    residuals = []
    for f in FILES:
        topics = bags[_stem(f)]
        scenario = Scenario.from_yaml(topics["/scenario"][0][1].data)
        assert scenario.noise.position == pytest.approx(NOISE_POS)
        assert scenario.noise.yaw == pytest.approx(NOISE_YAW)
        obs = np.array([_pose(m) for _, m in topics["/object/pose"]])
        truth = np.array([_pose(m) for _, m in topics["/truth/object/pose"]])
        d = obs - truth
        d[:, 2] = (d[:, 2] + np.pi) % (2 * np.pi) - np.pi
        residuals.append(d)
    res = np.vstack(residuals)
    assert res.shape[0] > 300
    assert np.std(res[:, 0]) == pytest.approx(NOISE_POS, rel=0.15)
    assert np.std(res[:, 1]) == pytest.approx(NOISE_POS, rel=0.15)
    assert np.std(res[:, 2]) == pytest.approx(NOISE_YAW, rel=0.15)
    assert abs(np.mean(res[:, 0])) < 4 * NOISE_POS / math.sqrt(res.shape[0])


def test_no_noise_gives_clean_pose_and_floor_std(tmp_path: Path) -> None:
    out = tmp_path / "clean"
    assert main(["import-mitpush", str(FILES[1]), "-o", str(out), "--dt", "0.004"]) == 0
    topics = _read_bag(out / _stem(FILES[1]))
    obs = np.array([_pose(m) for _, m in topics["/object/pose"]])
    truth = np.array([_pose(m) for _, m in topics["/truth/object/pose"]])
    np.testing.assert_array_equal(obs, truth)
    scenario = Scenario.from_yaml(topics["/scenario"][0][1].data)
    cfg = mp.ImportConfig()
    assert scenario.noise.position == pytest.approx(cfg.position_floor)
    assert scenario.noise.yaw == pytest.approx(cfg.yaw_floor)
    assert scenario.dt == pytest.approx(0.004)
    stamps = [t for t, _ in topics["/object/pose"]]
    assert set(np.diff(stamps).tolist()) == {4_000_000}


def test_noise_is_seeded() -> None:
    raw = mp.load_push(FILES[0])
    outline = mp.load_outline(raw.info.shape, DATA / "shapes")
    cfg = mp.ImportConfig(noise_position=0.001, noise_yaw=0.01, seed=5)
    a = mp.resample_push(raw, outline, cfg).observed
    b = mp.resample_push(raw, outline, cfg).observed
    c = mp.resample_push(raw, outline, mp.ImportConfig(noise_position=0.001, seed=6)).observed
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a[:, :2], c[:, :2])


def test_contact_flag_and_ft_frame(bags: dict[str, dict[str, list[tuple[int, Any]]]]) -> None:
    for f in FILES:
        topics = bags[_stem(f)]
        flags = np.array([np.asarray(m.data).reshape(1, 2)[0] for _, m in topics[CONTACT_TOPIC]])
        dims = topics[CONTACT_TOPIC][0][1].layout.dim
        assert [d.label for d in dims] == ["contacts", "state"]
        assert np.all(flags.sum(axis=1) == 1.0)
        touching = flags[:, 1] == 1.0
        assert 0.3 < touching.mean() <= 1.0
        if "/pusher/wrench" not in topics:
            continue
        force = np.array(
            [(m.wrench.force.x, m.wrench.force.y) for _, m in topics["/pusher/wrench"]]
        )
        np.testing.assert_array_equal(touching, np.hypot(*force.T) > mp.CONTACT_THRESHOLD)
        # F/T frame = world: the force on the pusher opposes the push while in contact.
        tip = np.array([m.position for _, m in topics["/joint_states"]])
        push = tip[-1] - tip[0]
        push /= np.linalg.norm(push)
        along = force[touching] @ push
        assert np.mean(along < 0.0) > 0.9


@pytest.mark.parametrize(
    "path", [f for f in FILES if "rect1" not in f.name], ids=lambda p: mp.parse_push_name(p).shape
)
def test_geometric_flag_is_a_touching_flag(path: Path) -> None:
    """Where both exist (live F/T), the geometric flag of the stale-F/T files agrees with the
    F/T flag while the object moves and never misses an F/T contact; at rest it also counts
    touches below the force threshold (documented in mitpush: specificity ~0)."""
    raw = mp.load_push(path)
    series = mp.resample_push(
        raw, mp.load_outline(raw.info.shape, DATA / "shapes"), mp.ImportConfig()
    )
    assert series.force is not None
    geo = mp.geometric_contact(series.pose, series.tip, series.outline, series.dt)
    speed = np.linalg.norm(np.gradient(series.pose[:, :2], series.dt, axis=0), axis=1)
    moving = speed > mp.MOVING_SPEED
    assert moving.sum() > 20
    assert np.mean(geo[moving] == series.contact[moving]) > 0.95
    assert np.mean(geo[series.contact]) > 0.95
    assert np.mean(geo[~series.contact]) > 0.5  # light touches at rest count as contact


def test_tip_readings_are_precise_and_declared(
    bags: dict[str, dict[str, list[tuple[int, Any]]]],
) -> None:
    """The scenario declares the tip noise the data has (tens of um, not the simulator's
    0.5 mm): residual of the tip about a quadratic fit at constant speed."""
    for f in FILES:
        scenario = Scenario.from_yaml(bags[_stem(f)]["/scenario"][0][1].data)
        assert scenario.noise.joint == pytest.approx(mp.JOINT_NOISE)
        raw = mp.load_push(f)
        t = raw.tip[:, 0] - raw.tip[0, 0]
        speed = np.linalg.norm(np.gradient(raw.tip[:, 1:3], t, axis=0), axis=1)
        fast = np.flatnonzero(speed > 0.8 * raw.info.speed)
        seg = fast[len(fast) // 3 : 2 * len(fast) // 3]
        res = [
            raw.tip[seg, j] - np.polyval(np.polyfit(t[seg], raw.tip[seg, j], 2), t[seg])
            for j in (1, 2)
        ]
        assert float(np.std(res)) < 3.0 * mp.JOINT_NOISE
    with pytest.raises(mp.MitPushError, match="joint_noise"):
        mp.ImportConfig(joint_noise=-1e-5)


def test_stale_ft_uses_geometric_contact(noisy_import: Path) -> None:
    import yaml

    rect = next(f for f in FILES if "rect1" in f.name)
    meta = yaml.safe_load((noisy_import / _stem(rect) / "metadata.yaml").read_text())
    custom = meta["rosbag2_bagfile_information"]["custom_data"]
    assert custom["contact_source"] == "geometry"
    assert custom["ft_stale"] == "true"
    assert mp.ft_is_stale(mp.load_push(rect).ft)
    assert not mp.ft_is_stale(mp.load_push(next(f for f in FILES if "hex" in f.name)).ft)


# ------------------------------------------------------------------------------ synthetic
SYN_NAME = "motion_surface=abs_shape=hex_a=0_v=20_i=1.000_s=0.500_t=0.000.h5"


def _write_h5(path: Path, **streams: Any) -> Path:
    with h5py.File(path, "w") as h5:
        for key, value in streams.items():
            h5.create_dataset(key, data=value)
    return path


def _synthetic(n: int = 200, t0: float = 1.5e9) -> dict[str, np.ndarray]:
    t = t0 + 0.004 * np.arange(n)
    yaw = np.pi - 0.5 + 1.0 * (t - t0)  # crosses +pi -> -pi in the middle
    yaw_wrapped = (yaw + np.pi) % (2 * np.pi) - np.pi
    obj = np.column_stack([t, 0.3 + 0.01 * (t - t0), np.zeros(n), yaw_wrapped])
    tip = np.column_stack([t + 0.001, 0.2 + 0.01 * (t - t0), np.zeros(n), np.zeros(n)])
    ft = np.column_stack([t + 0.002, -1.0 - (t - t0), np.zeros(n), np.zeros(n)])
    return {"tip_pose": tip, "object_pose": obj, "ft_wrench": ft}


@pytest.fixture
def syn_dir(tmp_path: Path) -> Path:
    d = tmp_path / "data"
    (d / "train").mkdir(parents=True)
    shutil.copytree(DATA / "shapes", d / "shapes")
    return d


def test_resampling_unwraps_yaw_and_interpolates(syn_dir: Path) -> None:
    path = _write_h5(syn_dir / "train" / SYN_NAME, **_synthetic())
    raw = mp.load_push(path)
    outline = mp.load_outline("hex", mp.find_shapes_dir(path) or syn_dir)
    series = mp.resample_push(raw, outline, mp.ImportConfig(dt=0.01), mp.ALIGNMENTS["hex"])
    t = series.stamps_ns * 1e-9 - 1.5e9
    assert t[0] == pytest.approx(0.002, abs=1e-6)  # common interval starts with the F/T
    yaw_v = np.pi - 0.5 + t
    expected = yaw_v + mp.ALIGNMENTS["hex"].yaw_offset
    np.testing.assert_allclose(series.pose[:, 2], expected, atol=1e-6)
    assert np.all(np.diff(series.pose[:, 2]) > 0)  # continuous through +-pi
    np.testing.assert_allclose(series.tip[:, 0], 0.2 + 0.01 * (t - 0.001), atol=1e-9)
    assert series.force is not None
    np.testing.assert_allclose(series.force[:, 0], -1.0 - (t - 0.002), atol=3e-3)  # step mean
    assert series.contact.all()
    assert series.start_offsets == pytest.approx(
        {"tip_pose": 0.001, "object_pose": 0.0, "ft_wrench": 0.002}, abs=1e-6
    )


def _missing_key(d: Path) -> Path:
    s = _synthetic()
    del s["ft_wrench"]
    return _write_h5(d / SYN_NAME, **s)


def _empty_stream(d: Path) -> Path:
    s = _synthetic()
    s["object_pose"] = np.zeros((0, 4))
    return _write_h5(d / SYN_NAME, **s)


def _wrong_columns(d: Path) -> Path:
    s = _synthetic()
    s["tip_pose"] = s["tip_pose"][:, :3]
    return _write_h5(d / SYN_NAME, **s)


def _wrong_shape(d: Path) -> Path:
    return _write_h5(d / SYN_NAME.replace("hex", "tri9"), **_synthetic())


def _not_hdf5(d: Path) -> Path:
    path = d / SYN_NAME
    path.write_bytes(b"this is not an HDF5 file" * 10)
    return path


def _no_overlap(d: Path) -> Path:
    s = _synthetic()
    s["ft_wrench"][:, 0] += 100.0
    return _write_h5(d / SYN_NAME, **s)


def _bad_name(d: Path) -> Path:
    return _write_h5(d / "push.h5", **_synthetic())


@pytest.mark.parametrize(
    ("make", "problem"),
    [
        (_missing_key, "missing dataset 'ft_wrench'"),
        (_empty_stream, "'object_pose' is empty"),
        (_wrong_columns, "N x 4"),
        (_wrong_shape, "unknown shape 'tri9'"),
        (_not_hdf5, "cannot read HDF5"),
        (_no_overlap, "overlap"),
        (_bad_name, "file name does not follow"),
    ],
)
def test_bad_file_exits_2_naming_it(
    make: Callable[[Path], Path],
    problem: str,
    syn_dir: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    bad = make(syn_dir / "train")
    out = tmp_path / "out"
    assert main(["import-mitpush", str(FILES[0]), str(bad), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err
    assert problem in err
    assert not out.exists() or not any(out.iterdir())  # nothing written


def test_refuses_to_overwrite(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    args = ["import-mitpush", str(FILES[0]), "-o", str(out)]
    assert main(args) == 0
    assert "[1/1]" in capsys.readouterr().err
    assert main(args) == 2
    assert "already exists" in capsys.readouterr().err
    assert main([*args, "--overwrite"]) == 0


def test_directory_argument_and_missing_shapes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    assert main(["import-mitpush", str(DATA), "-o", str(out)]) == 0
    assert len(list(out.iterdir())) == len(FILES)
    lonely = tmp_path / "lonely"
    lonely.mkdir()
    shutil.copy(FILES[0], lonely)
    assert main(["import-mitpush", str(lonely), "-o", str(tmp_path / "o2")]) == 2
    assert "--shapes" in capsys.readouterr().err
    assert (
        main(
            [
                "import-mitpush",
                str(lonely),
                "-o",
                str(tmp_path / "o3"),
                "--shapes",
                str(DATA / "shapes"),
            ]
        )
        == 0
    )


def test_help_lists_options_and_examples(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["import-mitpush", "--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    for needle in ("examples:", "--noise-position", "--noise-yaw", "--seed", "--overwrite"):
        assert needle in text


# ------------------------------------------------------------------------------ geometry
def test_expected_contact_conventions() -> None:
    hexagon = mp.load_outline("hex", DATA / "shapes")
    centre, normal = mp.expected_contact(hexagon, 1, 0.5)
    apothem = 0.0605 * math.cos(math.pi / 6)
    assert np.linalg.norm(centre) == pytest.approx(apothem + mp.PUSHER_RADIUS, abs=2e-4)
    assert float(centre @ normal) > 0.0  # outward
    circle = mp.load_outline("ellip1", DATA / "shapes")
    p0, _ = mp.expected_contact(circle, 0, 0.0)
    p1, _ = mp.expected_contact(circle, 0, 0.25)
    angle = math.atan2(p1[1], p1[0]) - math.atan2(p0[1], p0[0])
    assert (angle % (2 * math.pi)) == pytest.approx(math.pi / 2, abs=0.02)  # CCW quarter turn
    with pytest.raises(mp.MitPushError, match="out of range"):
        mp.expected_contact(hexagon, 6, 0.5)


def test_signed_distance_of_outline() -> None:
    square = mp.load_outline("rect1", DATA / "shapes").vertices
    pts = np.array([[0.0, 0.0], [0.045, 0.0], [0.05, 0.0], [0.05, 0.05], [0.0, -0.04]])
    d = mp.signed_distance(square, pts)
    np.testing.assert_allclose(d, [-0.045, 0.0, 0.005, math.hypot(0.005, 0.005), -0.005])


# ------------------------------------------------------------------------------ any shape
ALL_SHAPES = sorted(p.name.removesuffix("_ext.npy") for p in (DATA / "shapes").glob("*_ext.npy"))


def _boundary(hull: np.ndarray, start: np.ndarray, arc: np.ndarray) -> np.ndarray:
    """Tip centres (K, 2) touching the CCW hull at arc lengths ``arc`` from its point nearest
    to ``start`` (one tip radius along the edge's outward normal)."""
    e = np.roll(hull, -1, axis=0) - hull
    seg = np.linalg.norm(e, axis=1)
    ap = start - hull
    u = np.clip(np.einsum("nk,nk->n", ap, e) / seg**2, 0.0, 1.0)
    k = int(np.argmin(np.linalg.norm(hull + u[:, None] * e - start, axis=1)))
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    pos = (cum[k] + u[k] * seg[k] + arc) % cum[-1]
    j = np.clip(np.searchsorted(cum, pos, side="right") - 1, 0, len(hull) - 1)
    w = (pos - cum[j]) / seg[j]
    normal = np.column_stack([e[j, 1], -e[j, 0]]) / seg[j, None]
    return hull[j] + w[:, None] * e[j] + mp.PUSHER_RADIUS * normal


def _map(points: np.ndarray, yaw: float, offset: tuple[float, float], mirrored: bool):
    q = points * np.array([-1.0, 1.0]) if mirrored else points
    c, s = math.cos(yaw), math.sin(yaw)
    return q @ np.array([[c, s], [-s, c]]) + np.array(offset)


def _world(pose: np.ndarray, p: np.ndarray) -> np.ndarray:
    c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
    x, y = p[:, 0], p[:, 1]
    return pose[:, :2] + np.column_stack([c * x - s * y, s * x + c * y])


def _synthetic_push(
    vertices: np.ndarray, side: int, position: float, truth: mp.ShapeAlignment, slide: float
) -> dict[str, np.ndarray]:
    """A push of an outline (file frame) whose place in the tracked frame is ``truth``: the
    tip approaches the named contact point along its inward normal for 0.4 s, then the object
    moves and turns while the tip slides ``slide`` m along the outline; F/T 2 N in contact."""
    from dbcslam_ros.importers.mitpush_align import named_contact

    n, t0 = 300, 1.6e9
    t = 0.004 * np.arange(n)
    tc = 0.4
    hull = mp.convex_hull(_map(vertices, truth.yaw_offset, truth.offset, truth.mirrored))
    contact = _map(
        named_contact(vertices, side, position)[None],
        truth.yaw_offset,
        truth.offset,
        truth.mirrored,
    )[0]
    outward = (
        contact
        - _map(
            named_contact(vertices, side, position, 0.0)[None],
            truth.yaw_offset,
            truth.offset,
            truth.mirrored,
        )[0]
    )
    outward /= np.linalg.norm(outward)
    after = np.clip(t - tc, 0.0, None)
    tip_tracked = _boundary(hull, contact, slide * after / after[-1])
    before = t < tc
    tip_tracked[before] = contact + outward * (0.05 * (tc - t[before]))[:, None]
    pose = np.column_stack([0.4 + 0.05 * after, -0.1 + 0.01 * after, 0.3 + 0.2 * after])
    tip = _world(pose, tip_tracked)
    force = np.where(before, 0.0, 2.0)[:, None] * -np.array([1.0, 0.0])
    stamps = t0 + t
    return {
        "tip_pose": np.column_stack([stamps, tip, np.zeros(n)]),
        "object_pose": np.column_stack([stamps, pose]),
        "ft_wrench": np.column_stack([stamps, force, np.zeros(n)]),
    }


def _contacts(vertices: np.ndarray) -> list[tuple[int, float]]:
    sides = len(vertices) if len(vertices) <= 8 else 1
    return [(k % sides, s) for k, s in [(0, 0.3), (1, 0.7), (2, 0.5), (3, 0.2)]]


def _write_pushes(
    root: Path, shape: str, truth: mp.ShapeAlignment
) -> tuple[list[Path], np.ndarray]:
    (root / "train").mkdir(parents=True, exist_ok=True)
    if not (root / "shapes").exists():
        shutil.copytree(DATA / "shapes", root / "shapes")
    vertices = np.load(DATA / "shapes" / f"{shape}_ext.npy")
    paths = []
    for j, (side, pos) in enumerate(_contacts(vertices)):
        name = f"motion_surface=abs_shape={shape}_a=0_v=50_i={side}.000_s={pos:.3f}_t=0.000.h5"
        push = _synthetic_push(vertices, side, pos, truth, 0.01 if j % 2 else -0.01)
        paths.append(_write_h5(root / "train" / name, **push))
    return paths, vertices


def _hausdorff(a: np.ndarray, b: np.ndarray) -> float:
    d = np.linalg.norm(a[:, None] - b[None], axis=-1)
    return float(max(d.min(axis=0).max(), d.min(axis=1).max()))


CASES = [(s, True) for s in ALL_SHAPES] + [(s, False) for s in ("tri2", "butter", "rect2")]


@pytest.mark.parametrize(("shape", "mirrored"), CASES, ids=str)
def test_alignment_is_recovered_for_every_shape(
    shape: str, mirrored: bool, tmp_path: Path
) -> None:
    """One procedure for every outline: the fitted map puts the outline where the synthetic
    truth put it (within 0.3 mm) and the named first contacts on the measured ones."""
    from dbcslam_ros.importers.mitpush_align import shape_alignment

    truth = mp.ShapeAlignment(1.2, (0.0012, -0.0008), mirrored)
    paths, vertices = _write_pushes(tmp_path, shape, truth)
    fit = shape_alignment(mp.load_push(paths[0]), vertices)
    assert len(fit.names) == 4
    a = fit.alignment
    dense = _boundary(mp.convex_hull(vertices), vertices[0], np.linspace(0.0, 1.0, 200))
    placed = _map(dense, a.yaw_offset, a.offset, a.mirrored)
    true = _map(dense, truth.yaw_offset, truth.offset, truth.mirrored)
    assert _hausdorff(placed, true) < 3e-4
    # The named first contacts where the tip first touched (outlines that are their own
    # convex hull: on butter's the synthetic tip slides on the hull instead; not at tri3's
    # 0.15 mm side 1, a corner).
    if len(mp.convex_hull(vertices)) == len(vertices):
        sides = np.linalg.norm(np.roll(vertices, -1, axis=0) - vertices, axis=1)
        for (side, _), err in zip(_contacts(vertices), fit.onset_errors, strict=True):
            if len(vertices) > 8 or sides[side] > 0.005:
                assert err < 3e-4
    assert fit.median_gap < 1e-4
    if shape in ("tri2", "butter") or mirrored:  # asymmetric outlines fix the convention
        assert a.mirrored == mirrored
        assert math.remainder(a.yaw_offset - truth.yaw_offset, 2 * math.pi) == pytest.approx(
            0.0, abs=5e-3
        )
        assert a.offset == pytest.approx(truth.offset, abs=3e-4)


def test_any_shape_imports_end_to_end(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A shape the dataset has no push of (butter) imports: outline from shapes/, mass from
    the plate, the truth pose is the centroid where the synthetic push put it."""
    from dbcslam_core.mass_properties import plate_properties

    truth = mp.ShapeAlignment(-0.7, (0.001, 0.002), True)
    paths, vertices = _write_pushes(tmp_path / "data", "butter", truth)
    out = tmp_path / "bags"
    assert main(["import-mitpush", str(paths[1]), "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert "butter: alignment fitted on 4 push file(s): mirrored" in err
    topics = _read_bag(out / _stem(paths[1]))
    scenario = Scenario.from_yaml(topics["/scenario"][0][1].data)
    plate = plate_properties(vertices)
    assert scenario.body.mass == pytest.approx(plate.mass)
    assert scenario.body.inertia == pytest.approx(plate.inertia)
    assert 0.5 < plate.mass < 2.0
    raw = mp.load_push(paths[1])
    centroid = _map(np.array([plate.centroid]), truth.yaw_offset, truth.offset, True)[0]
    clock = mp.common_clock(raw, 0.01)
    expected = _world(clock.vicon, np.repeat(centroid[None], len(clock.grid), axis=0))
    got = np.array([_pose(m)[:2] for _, m in topics["/truth/object/pose"]])
    np.testing.assert_allclose(got, expected, atol=3e-4)
    # Mass flags override the plate; bad values are refused with exit code 2.
    out2 = tmp_path / "bags2"
    flags = ["--mass", "1.5", "--overwrite"]
    assert main(["import-mitpush", str(paths[1]), "-o", str(out2), *flags]) == 0
    scenario = Scenario.from_yaml(_read_bag(out2 / _stem(paths[1]))["/scenario"][0][1].data)
    assert scenario.body.mass == pytest.approx(1.5)
    assert scenario.body.inertia == pytest.approx(plate.inertia * 1.5 / plate.mass)
    capsys.readouterr()
    for bad in (["--mass", "-1"], ["--density", "0"], ["--thickness", "nan"]):
        with pytest.raises(SystemExit) as exc:
            main(["import-mitpush", str(paths[1]), "-o", str(tmp_path / "o3"), *bad])
        assert exc.value.code == 2
        assert "expected" in capsys.readouterr().err


def test_mass_flag_refuses_mixed_shapes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = ["import-mitpush", str(FILES[0]), str(FILES[1]), "-o", str(tmp_path / "o")]
    assert main([*args, "--mass", "1.0"]) == 2
    assert "import each shape separately" in capsys.readouterr().err


def test_read_shape_table(tmp_path: Path) -> None:
    readme = tmp_path / "README.md"
    readme.write_text(
        "| shape | size (mm) | mass (kg) | I_z (kg m^2) |\n|---|---|---|---|\n"
        "| rect1 | 90 x 90 square | 0.8374 | 1.131e-3 |\n| hex | hexagon | 0.9827 | 1.497e-3 |\n"
    )
    table = mp.read_shape_table(readme)
    assert table == {"rect1": mp.SHAPES["rect1"], "hex": mp.SHAPES["hex"]}
    assert mp.read_shape_table(tmp_path / "missing.md") == {}
    assert mp.shape_names(DATA / "shapes") == ALL_SHAPES
    assert len(ALL_SHAPES) == 11


def test_alignment_is_deterministic_and_the_same_for_every_file_of_a_set(tmp_path: Path) -> None:
    import dbcslam_ros.importers.mitpush_align as ma

    truth = mp.ShapeAlignment(2.0, (0.0005, 0.001), True)
    paths, vertices = _write_pushes(tmp_path, "hex", truth)
    first = ma.shape_alignment(mp.load_push(paths[0]), vertices)
    ma._CACHE.clear()
    again = ma.shape_alignment(mp.load_push(paths[3]), vertices)
    assert again == first
    cfg = mp.ImportConfig()
    outline = mp.load_outline("hex", tmp_path / "shapes")
    series = mp.resample_push(mp.load_push(paths[2]), outline, cfg)  # default: the set's fit
    assert series.alignment == first.alignment


SHARED = Path(__file__).resolve().parents[3] / "shared" / "data" / "mit-push"


@pytest.mark.skipif(not (SHARED / "abs" / "train").is_dir(), reason="full MIT subset absent")
@pytest.mark.parametrize("shape", sorted(mp.ALIGNMENTS))
def test_pooled_fit_near_the_hand_constants_on_the_full_subset(shape: str) -> None:
    """On the 50 training pushes (when present): mirrored, offsets within 1 mm and yaw within
    30 mrad of the first importer's constants, at no higher robust cost than they have."""
    import dbcslam_ros.importers.mitpush_align as ma

    files = sorted((SHARED / "abs" / "train").glob(f"*_shape={shape}_*.h5"))
    outline = mp.load_outline(shape, SHARED / "shapes")
    fit = ma.shape_alignment(mp.load_push(files[0]), outline.file_vertices)
    ref = mp.ALIGNMENTS[shape]
    a = fit.alignment
    assert a.mirrored
    assert fit.cost < fit.other_cost
    assert abs(a.yaw_offset - ref.yaw_offset) < 0.03
    assert np.hypot(a.offset[0] - ref.offset[0], a.offset[1] - ref.offset[1]) < 0.001
    evidence = [ma.push_evidence(mp.load_push(f), outline.file_vertices) for f in files]
    ref_cost, _, _ = ma._reference_stats(evidence, mp.convex_hull(outline.file_vertices), ref)
    assert fit.cost <= ref_cost * 1.0001
    assert fit.median_gap < 0.001


@pytest.mark.parametrize("model", ["dynamic", "quasi_static"])
def test_push_model_flag_sets_the_scenario_model(tmp_path: Path, model: str) -> None:
    out = tmp_path / model
    assert main(["import-mitpush", str(FILES[1]), "-o", str(out), "--push-model", model]) == 0
    topics = _read_bag(out / _stem(FILES[1]))
    scenario = Scenario.from_yaml(topics["/scenario"][0][1].data)
    assert scenario.surface.push_model == model


def test_push_model_is_validated() -> None:
    with pytest.raises(mp.MitPushError, match="push_model"):
        mp.ImportConfig(push_model="quasistatic")
