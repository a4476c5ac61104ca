"""``dbcslam import-mitpush H5 ... -o DIR``: MIT MCube push files -> bags of the contract.

One bag per push file, named after the file (``DIR/<file stem>``). Every bag holds, on one
clock of step ``--dt`` (stamps = the data's Unix time in ns, log time = stamp):

* ``/scenario`` (latched, first message): ``push`` scenario with the shape's outline (body
  frame about the centroid; alignment estimated from the data, see
  :mod:`dbcslam_ros.mitpush_align`), mass and inertia of a uniform plate cut to the outline
  (:func:`dbcslam_ros.mitpush.mass_properties`), pusher radius 4.75 mm, dt, friction pairs
  ``pusher`` and ``surface`` with the candidate lists and uniform priors, observation noise
  std = the added noise (or the floor 1 mm / 0.01 rad when none is added), contacts
  ``[pusher]``.
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
  moves, :func:`dbcslam_ros.mitpush.geometric_contact`) when the F/T stream is stale; the
  bag's ``custom_data`` says which.

Per step the messages are written in the order joints, wrenches, contact, pose, truth, all
at the step's stamp. ``metadata.yaml`` ``custom_data`` records the source file, shape,
fitted alignment, mass properties (and the dataset table's where it has them), dt, noise,
seed and contact source.
"""

from __future__ import annotations

import argparse
import math
import shutil
import statistics
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from dbcslam_core.angles import wrap_angle
from dbcslam_ros.cli.registry import Command
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
from dbcslam_ros.errors import UsageError

if TYPE_CHECKING:
    from dbcslam_core.scenario import Scenario
    from dbcslam_ros.bag.metadata import BagMetadata
    from dbcslam_ros.mitpush import AlignmentCheck, ImportConfig, PushSeries
    from dbcslam_ros.mitpush_align import AlignmentFit

__all__ = ["COMMAND", "CONTACT_TOPIC", "TOPICS", "make_scenario", "write_push_bag"]

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

_DESCRIPTION = """\
Convert MIT MCube planar-pushing files (motion_surface=S_shape=O_a=A_v=V_i=I_s=P_t=T.h5 with
tip_pose, object_pose, ft_wrench) into bags of the DBC-SLAM contract, one bag per file under
DIR (named after the file). H5 arguments may be files or directories (searched recursively
for .h5). Every shape with an outline <shape>_ext.npy in the dataset's shapes/ directory (the
nearest 'shapes' directory above each file, or --shapes DIR) can be imported.

The streams are resampled onto one clock of step --dt (linear interpolation, yaw unwrapped,
F/T averaged per step). Mass and inertia about the centroid are those of a uniform plate cut
to the outline (--density, --thickness; or --mass, --inertia). Frame alignment (where the
outline lies in the Vicon-tracked frame: yaw, offset, mirrored or not) is estimated from the
data: the pusher tip must touch the outline on in-contact steps and first touch it where the
file name says, fitted (Huber loss, global search over yaw and both conventions) over every
push file of the shape in the file's directory, so a file gets the same alignment whether it
is imported alone or with the others (see dbcslam_ros.mitpush_align). The fit is printed per
shape. Optional Gaussian noise is added to the observed pose (--noise-position, --noise-yaw,
seeded by --seed and the file name) while /truth/object/pose keeps the clean pose.

Topics: /scenario (latched), /joint_states (pusher_x, pusher_y), /object/pose,
/truth/object/pose, /object/wrench (zero), /pusher/wrench (F/T, world axes; omitted when the
file's F/T stream is stale), /pusher/contact (Float64MultiArray contacts x [separated,
in_contact], one-hot: F/T magnitude > --contact-threshold, or geometric for stale F/T).

All files are read and checked before any bag is written: a bad file (unreadable HDF5,
missing dataset, empty stream, a shape without outline) stops the import with exit code 2
naming the file. Existing bags are not overwritten without --overwrite."""

_EXAMPLES = """\
  dbcslam import-mitpush /data/mit-push/abs/train -o bags/mitpush
  dbcslam import-mitpush /data/mit-push/abs/train/motion_surface=abs_shape=butter_*.h5 \\
      -o bags/butter                      # any shape with an outline in shapes/
  dbcslam import-mitpush run.h5 -o out --mass 0.84 --inertia 1.13e-3   # measured values
  dbcslam import-mitpush run.h5 -o out --density 2700 --thickness 0.01 # an aluminium plate
  dbcslam import-mitpush push1.h5 push2.h5 -o out --dt 0.004 --overwrite
  dbcslam import-mitpush /data/mit-push/abs/train -o bags/noisy \\
      --noise-position 0.002 --noise-yaw 0.02 --seed 7
  dbcslam import-mitpush run.h5 -o out --shapes /data/mit-push/shapes \\
      --pusher-candidates 0.15 0.25 --surface-candidates 0.1 0.2 0.3
"""


def _nonneg_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError as err:
        msg = f"expected a number, got {text!r}"
        raise argparse.ArgumentTypeError(msg) from err
    if not (math.isfinite(value) and value >= 0.0):
        msg = f"expected a finite number >= 0, got {text!r}"
        raise argparse.ArgumentTypeError(msg)
    return value


def _positive_float(text: str) -> float:
    value = _nonneg_float(text)
    if value <= 0.0:
        msg = f"expected a number > 0, got {text!r}"
        raise argparse.ArgumentTypeError(msg)
    return value


def make_scenario(series: PushSeries, config: ImportConfig) -> Scenario:
    """The ``/scenario`` of an imported push (validated by the core's Scenario)."""
    import dataclasses

    from dbcslam_core.scenario import FrictionSpec, push_scenario
    from dbcslam_ros.mitpush import PUSHER_RADIUS, mass_properties

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
    from dbcslam_ros.mitpush import find_shapes_dir, mass_properties, read_shape_table

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


def _run(args: argparse.Namespace) -> int:
    from dbcslam_ros.mitpush import ImportConfig, MitPushError, push_files

    try:
        config = ImportConfig(
            dt=args.dt,
            noise_position=args.noise_position,
            noise_yaw=args.noise_yaw,
            seed=args.seed,
            contact_threshold=args.contact_threshold,
            pusher_candidates=tuple(args.pusher_candidates),
            surface_candidates=tuple(args.surface_candidates),
            density=args.density,
            thickness=args.thickness,
            mass=args.mass,
            inertia=args.inertia,
            **({} if args.push_model is None else {"push_model": args.push_model}),
        )
    except MitPushError as err:
        raise UsageError(str(err)) from err
    files = push_files(args.h5)
    out_dir = Path(args.output)
    targets = [out_dir / f.name.removesuffix(".h5") for f in files]
    seen: dict[Path, Path] = {}
    for f, target in zip(files, targets, strict=True):
        if target in seen:
            msg = f"{f}: same bag name as {seen[target]} ({target}); import them separately"
            raise UsageError(msg)
        seen[target] = f
        if (target.exists() or target.is_symlink()) and not args.overwrite:
            msg = f"{target}: already exists; not overwriting (pass --overwrite to replace)"
            raise UsageError(msg)
    series_list = _read_all(files, args, config)
    total = len(files)
    for i, (series, target) in enumerate(zip(series_list, targets, strict=True), start=1):
        meta = write_push_bag(series, config, target, overwrite=args.overwrite)
        check = _alignment_check(series)
        print(
            f"[{i}/{total}] {series.raw.path.name} -> {target}: {len(series)} steps "
            f"({series.t[-1]:.2f} s), {meta.message_count} messages, contact "
            f"{100.0 * float(series.contact.mean()):.0f}% ({series.contact_source}), "
            f"tip-outline gap while pushing {1000.0 * check.moving_gap:.2f} mm",
            file=sys.stderr,
        )
    print(f"imported {total} push file(s) into {out_dir}", file=sys.stderr)
    return 0


def _alignment_check(series: PushSeries) -> AlignmentCheck:
    from dbcslam_ros.mitpush import alignment_check

    return alignment_check(series)


def _read_all(files: list[Path], args: argparse.Namespace, config: ImportConfig) -> list[Any]:
    """Read, align and resample every file before anything is written (progress on stderr)."""
    from dbcslam_ros.mitpush import (
        MitPushError,
        Outline,
        find_shapes_dir,
        load_outline,
        load_push,
        mass_properties,
        resample_push,
    )
    from dbcslam_ros.mitpush_align import shape_alignment

    raws = [load_push(f) for f in files]
    shapes = sorted({r.info.shape for r in raws})
    if (args.mass is not None or args.inertia is not None) and len(shapes) > 1:
        msg = (
            f"--mass/--inertia describe one object, but the files hold {len(shapes)} shapes "
            f"({', '.join(shapes)}); import each shape separately"
        )
        raise UsageError(msg)
    outlines: dict[tuple[str, Path], Outline] = {}
    fits: dict[tuple[str, Path, Path], AlignmentFit] = {}
    series_list = []
    for f, raw in zip(files, raws, strict=True):
        shapes_dir = Path(args.shapes) if args.shapes else find_shapes_dir(f)
        if shapes_dir is None:
            msg = (
                f"{f}: no 'shapes' directory with the outline of {raw.info.shape!r} found "
                "above the file; pass --shapes DIR"
            )
            raise MitPushError(msg)
        key = (raw.info.shape, shapes_dir)
        if key not in outlines:
            try:
                outlines[key] = load_outline(raw.info.shape, shapes_dir)
            except MitPushError as err:
                msg = f"{f}: {err}"
                raise MitPushError(msg) from err
        fkey = (raw.info.shape, shapes_dir, f.parent)
        if fkey not in fits:
            fit = shape_alignment(
                raw, outlines[key].file_vertices, config.dt, config.contact_threshold
            )
            fits[fkey] = fit
            _report_fit(raw.info.shape, fit, *mass_properties(outlines[key], config))
        series_list.append(resample_push(raw, outlines[key], config, fits[fkey].alignment))
    return series_list


def _report_fit(shape: str, fit: AlignmentFit, mass: float, inertia: float, source: str) -> None:
    a = fit.alignment
    onset = [e for e in fit.onset_errors if math.isfinite(e)]
    first = f"{1e3 * statistics.median(onset):.2f} mm" if onset else "n/a"
    print(
        f"{shape}: alignment fitted on {len(fit.names)} push file(s): "
        f"{'mirrored' if a.mirrored else 'as stored'}, yaw {a.yaw_offset:+.4f} rad, offset "
        f"({1e3 * a.offset[0]:+.2f}, {1e3 * a.offset[1]:+.2f}) mm; median |gap| "
        f"{1e3 * fit.median_gap:.2f} mm, first contact off by {first} (median); "
        f"mass {mass:.4f} kg, inertia {inertia:.4e} kg m^2 ({source})",
        file=sys.stderr,
    )


def _configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "h5", nargs="+", metavar="H5", help="push file (.h5) or directory of push files"
    )
    parser.add_argument(
        "-o", "--output", required=True, metavar="DIR", help="directory for the bags"
    )
    parser.add_argument(
        "--dt",
        type=_positive_float,
        default=0.01,
        metavar="S",
        help="model step and resampling period, s (default 0.01; the data is ~250 Hz)",
    )
    parser.add_argument(
        "--noise-position",
        type=_nonneg_float,
        default=0.0,
        metavar="M",
        help="std of Gaussian noise added to the observed position, m (default 0)",
    )
    parser.add_argument(
        "--noise-yaw",
        type=_nonneg_float,
        default=0.0,
        metavar="RAD",
        help="std of Gaussian noise added to the observed yaw, rad (default 0)",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the added noise (default 0)")
    parser.add_argument(
        "--contact-threshold",
        type=_nonneg_float,
        default=0.25,
        metavar="N",
        help="F/T force magnitude above which the pusher is in contact, N (default 0.25)",
    )
    parser.add_argument(
        "--pusher-candidates",
        type=_nonneg_float,
        nargs="+",
        default=[0.1, 0.2, 0.3],
        metavar="MU",
        help="candidate pusher-object friction coefficients (default 0.1 0.2 0.3)",
    )
    parser.add_argument(
        "--surface-candidates",
        type=_nonneg_float,
        nargs="+",
        default=[0.1, 0.2, 0.3],
        metavar="MU",
        help="candidate object-surface friction coefficients (default 0.1 0.2 0.3)",
    )
    parser.add_argument(
        "--push-model",
        choices=("dynamic", "quasi_static"),
        default=None,
        help="the scenario's push model (surface.model): dynamic (rigid body with inertia and "
        "Coulomb support friction) or quasi_static (limit surface, no coasting); default: "
        "dbcslam_ros.mitpush.DEFAULT_PUSH_MODEL",
    )
    parser.add_argument(
        "--shapes",
        metavar="DIR",
        help="directory with <shape>_ext.npy outlines (default: the dataset's shapes/)",
    )
    plate = parser.add_argument_group(
        "mass properties (default: a uniform stainless-steel plate cut to the outline)"
    )
    plate.add_argument(
        "--density",
        type=_positive_float,
        default=7950.0,
        metavar="KG_M3",
        help="plate density, kg/m^3 (default 7950, stainless steel; fits the dataset's "
        "four tabulated masses within 0.33%%)",
    )
    plate.add_argument(
        "--thickness",
        type=_positive_float,
        default=0.013,
        metavar="M",
        help="plate thickness, m (default 0.013, the dataset's objects)",
    )
    plate.add_argument(
        "--mass",
        type=_positive_float,
        default=None,
        metavar="KG",
        help="object mass, kg, instead of the computed one (the computed inertia is scaled "
        "with it unless --inertia is given; files of one shape only)",
    )
    plate.add_argument(
        "--inertia",
        type=_positive_float,
        default=None,
        metavar="KG_M2",
        help="polar inertia about the centroid, kg m^2, instead of the computed one",
    )
    parser.add_argument("--overwrite", action="store_true", help="replace existing bags")


COMMAND = Command(
    name="import-mitpush",
    help="convert MIT MCube push files (.h5) into bags, one per file",
    description=_DESCRIPTION,
    examples=_EXAMPLES,
    configure=_configure,
    run=_run,
)
