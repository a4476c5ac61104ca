"""One imported MIT MCube push as a bag of the contract (what ``dbcslam import-mitpush`` writes).

One bag per push file, named after the file (``DIR/<file stem>``). Every bag holds, on one
clock of step ``--dt`` (stamps = the data's Unix time in ns, log time = stamp):

* ``/scenario`` (latched, first message): ``push`` scenario with the shape's outline (body
  frame about the centroid; alignment estimated from the data, see
  :mod:`dbcslam_ros.importers.mitpush_align`), mass and inertia of a uniform plate cut to the
  outline (:func:`dbcslam_ros.importers.mitpush.mass_properties`), pusher radius 4.75 mm, dt,
  friction pairs ``pusher`` and ``surface`` with the candidate lists and uniform priors,
  observation noise std = the added noise (or the floor 1 mm / 0.01 rad when none is added),
  contacts ``[pusher]``.
* ``/joint_states``: ``pusher_x``, ``pusher_y`` (tip centre, world, m).
* ``/object/pose``: aligned Vicon pose plus the added noise; ``/truth/object/pose``: the same
  without noise (the best available truth: Vicon).
* ``/object/wrench``: zero (no known wrench acts on the object; the pusher is a moving
  obstacle).
* ``/pusher/wrench``: F/T force on the pusher, world axes (mean over each step), tau_z as
  measured. Omitted when the file's F/T stream is stale (all ``rect1`` files here).
* ``/pusher/contact`` (std_msgs/Float64MultiArray, reliable): the contact flag, dims
  ``contacts`` (size 1: ``pusher``) x ``state`` (size 2: ``separated``, ``in_contact``),
  one-hot. Sticking vs sliding is not observable from the F/T sensor, so the flag does not
  pretend to be a ``/truth/contact_modes`` message: only "separated" has the meaning it has
  there (``1 - data[0]`` = in contact). Source: F/T force magnitude > ``--contact-threshold``
  (default 0.25 N), or geometry (tip-outline gap within 1 mm of its value while the object
  moves, :func:`dbcslam_ros.importers.mitpush.geometric_contact`) when the F/T stream is stale; the
  bag's ``custom_data`` says which.

Per step the messages are written in the order joints, wrenches, contact, pose, truth, all
at the step's stamp. ``metadata.yaml`` ``custom_data`` records the source file, shape,
fitted alignment, mass properties (and the dataset table's where it has them), dt, noise,
seed and contact source.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import TYPE_CHECKING

from dbcslam_core.angles import wrap_angle
from dbcslam_ros.contract import (
    JOINT_STATES,
    OBJECT_POSE,
    OBJECT_WRENCH,
    PUSHER_CONTACT,
    PUSHER_WRENCH,
    SCENARIO,
    TRUTH_POSE,
    message_type,
)

if TYPE_CHECKING:
    from dbcslam_core.scenario import Scenario
    from dbcslam_ros.bag.metadata import BagMetadata
    from dbcslam_ros.importers.mitpush import ImportConfig, PushSeries

__all__ = ["CONTACT_TOPIC", "TOPICS", "make_scenario", "write_push_bag", "zero_wrench"]

#: Topic of the contact flag (see the module docstring for its layout).
CONTACT_TOPIC = PUSHER_CONTACT
#: Topics an imported bag holds (``/pusher/wrench`` only with a usable F/T stream).
TOPICS: tuple[str, ...] = (
    SCENARIO,
    JOINT_STATES,
    OBJECT_WRENCH,
    PUSHER_WRENCH,
    CONTACT_TOPIC,
    OBJECT_POSE,
    TRUTH_POSE,
)


def make_scenario(series: PushSeries, config: ImportConfig) -> Scenario:
    """The ``/scenario`` of an imported push (validated by the core's Scenario)."""
    import dataclasses

    from dbcslam_core.scenario import FrictionSpec, push_scenario
    from dbcslam_ros.importers.mitpush import PUSHER_RADIUS, mass_properties

    mass, inertia, _ = mass_properties(series.outline, config)
    base = push_scenario(
        [tuple(v) for v in series.outline.vertices.tolist()],
        mass=mass,
        inertia=inertia,
        dt=config.dt,
        pusher_radius=PUSHER_RADIUS,
        candidates=config.pusher_candidates,
        position_noise=config.position_std,
        yaw_noise=config.yaw_std,
        support_pair="surface",
        model=config.push_model,
    )
    cands = (tuple(config.pusher_candidates), tuple(config.surface_candidates))
    friction = FrictionSpec(
        pairs=("pusher", "surface"),
        candidates=cands,
        prior=tuple(tuple(1.0 / len(c) for _ in c) for c in cands),
    )
    noise = dataclasses.replace(base.noise, joint=config.joint_noise)  # measured tip noise
    return dataclasses.replace(base, friction=friction, noise=noise)


def _custom_data(series: PushSeries, config: ImportConfig) -> dict[str, str]:
    from dbcslam_ros.importers.mitpush import find_shapes_dir, mass_properties, read_shape_table

    info = series.raw.info
    mass, inertia, source = mass_properties(series.outline, config)
    extra = {
        "mass_kg": repr(mass),
        "inertia_kg_m2": repr(inertia),
        "mass_source": source,
        "density_kg_m3": repr(config.density),
        "thickness_m": repr(config.thickness),
        "alignment_mirrored": str(series.alignment.mirrored).lower(),
    }
    shapes_dir = find_shapes_dir(series.raw.path)
    table = read_shape_table(shapes_dir.parent / "README.md") if shapes_dir else {}
    if info.shape in table:
        extra["table_mass_kg"] = repr(table[info.shape].mass)
        extra["table_inertia_kg_m2"] = repr(table[info.shape].inertia)
    return extra | {
        "source": "MIT MCube push dataset (Yu et al., IROS 2016)",
        "source_file": series.raw.path.name,
        "shape": info.shape,
        "surface": info.surface,
        "push_speed_m_s": repr(info.speed),
        "push_side": str(info.side),
        "push_position": repr(info.position),
        "push_angle_rad": repr(info.angle),
        "dt_s": repr(config.dt),
        "alignment_yaw_offset_rad": repr(series.alignment.yaw_offset),
        "alignment_offset_m": repr(list(series.alignment.offset)),
        "noise_position_m": repr(config.noise_position),
        "noise_yaw_rad": repr(config.noise_yaw),
        "seed": str(config.seed),
        "contact_source": series.contact_source,
        "contact_threshold_n": repr(config.contact_threshold),
        "ft_stale": str(series.force is None).lower(),
    }


def write_push_bag(
    series: PushSeries, config: ImportConfig, path: Path, *, overwrite: bool = False
) -> BagMetadata:
    """Write one imported push as a bag (see the module docstring for the topics)."""
    from dbcslam_ros import runtime as rt
    from dbcslam_ros.bag import BagWriter
    from dbcslam_ros.bag.qos import RELIABLE_QOS, contract_qos
    from dbcslam_ros.convert import (
        float64_multiarray,
        ns_to_stamp,
        pose_stamped,
        wrench_stamped,
    )

    scenario = make_scenario(series, config)
    string_cls = rt.message_class("std_msgs/msg/String")
    joint_cls = rt.message_class("sensor_msgs/msg/JointState")
    header_cls = rt.message_class("std_msgs/msg/Header")
    names = list(scenario.joints)
    types = {
        t: "std_msgs/msg/Float64MultiArray" if t == CONTACT_TOPIC else message_type(t)
        for t in TOPICS
    }
    if series.force is None:
        del types[PUSHER_WRENCH]
    created = not (path.exists() or path.is_symlink())
    try:
        with BagWriter(path, overwrite=overwrite, custom_data=_custom_data(series, config)) as bag:
            for topic, msgtype in types.items():
                qos = RELIABLE_QOS if topic == CONTACT_TOPIC else contract_qos(topic)
                bag.add_topic(topic, msgtype, [qos])
            stamps = [int(s) for s in series.stamps_ns]
            bag.write(SCENARIO, rt.encode(string_cls(data=scenario.to_yaml())), stamps[0])
            for k, ns in enumerate(stamps):
                tx, ty = (float(v) for v in series.tip[k])
                joints = joint_cls(
                    header=header_cls(stamp=ns_to_stamp(ns), frame_id="world"),
                    name=names,
                    position=[tx, ty],
                    velocity=[],
                    effort=[],
                )
                bag.write(JOINT_STATES, rt.encode(joints), ns)
                bag.write(OBJECT_WRENCH, zero_wrench(ns), ns)
                if series.force is not None:
                    fx, fy, tau = (float(v) for v in series.force[k])
                    bag.write(PUSHER_WRENCH, rt.encode(wrench_stamped(ns, fx, fy, tau)), ns)
                flag = [[0.0, 1.0]] if series.contact[k] else [[1.0, 0.0]]
                bag.write(
                    CONTACT_TOPIC, rt.encode(float64_multiarray(flag, ("contacts", "state"))), ns
                )
                ox, oy, oyaw = (float(v) for v in series.observed[k])
                bag.write(
                    OBJECT_POSE,
                    rt.encode(pose_stamped(ns, ox, oy, float(wrap_angle(oyaw)))),
                    ns,
                )
                x, y, yaw = (float(v) for v in series.pose[k])
                bag.write(
                    TRUTH_POSE,
                    rt.encode(pose_stamped(ns, x, y, float(wrap_angle(yaw)))),
                    ns,
                )
            return bag.close()
    except BaseException:
        # Never leave a half-written bag behind (a re-run would refuse to overwrite it).
        if created:
            shutil.rmtree(path, ignore_errors=True)
        raise


def zero_wrench(stamp_ns: int) -> bytes:
    """CDR bytes of a zero geometry_msgs/WrenchStamped in ``world`` at ``stamp_ns``."""
    from dbcslam_ros import runtime as rt
    from dbcslam_ros.convert import wrench_stamped

    return bytes(rt.encode(wrench_stamped(stamp_ns, 0.0, 0.0, 0.0)))
