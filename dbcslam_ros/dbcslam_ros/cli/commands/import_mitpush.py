"""``dbcslam import-mitpush H5 ... -o DIR``: MIT MCube push files -> bags of the contract.

The command line only: reading, resampling and aligning are in
:mod:`dbcslam_ros.importers.mitpush`, the bag layout and writing in
:mod:`dbcslam_ros.importers.mitpush_bag`.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from dbcslam_ros.cli.registry import Command
from dbcslam_ros.errors import UsageError
from dbcslam_ros.importers.mitpush_bag import write_push_bag

if TYPE_CHECKING:
    from dbcslam_ros.importers.mitpush import AlignmentCheck, ImportConfig, PushSeries
    from dbcslam_ros.importers.mitpush_align import AlignmentFit

__all__ = ["COMMAND"]

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
is imported alone or with the others (see dbcslam_ros.importers.mitpush_align). The fit is
printed per shape. Optional Gaussian noise is added to the observed pose (--noise-position,
--noise-yaw, seeded by --seed and the file name) while /truth/object/pose keeps the clean pose.

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


def _run(args: argparse.Namespace) -> int:
    from dbcslam_ros.importers.mitpush import ImportConfig, MitPushError, push_files

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
    from dbcslam_ros.importers.mitpush import alignment_check

    return alignment_check(series)


def _read_all(files: list[Path], args: argparse.Namespace, config: ImportConfig) -> list[Any]:
    """Read, align and resample every file before anything is written (progress on stderr)."""
    from dbcslam_ros.importers.mitpush import (
        MitPushError,
        Outline,
        find_shapes_dir,
        load_outline,
        load_push,
        mass_properties,
        resample_push,
    )
    from dbcslam_ros.importers.mitpush_align import shape_alignment

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
    _add_files(parser)
    _add_sampling(parser)
    _add_scenario(parser)
    _add_mass_properties(parser)
    parser.add_argument("--overwrite", action="store_true", help="replace existing bags")


def _add_files(parser: argparse.ArgumentParser) -> None:
    """The push files in, the bag directory out."""
    parser.add_argument(
        "h5", nargs="+", metavar="H5", help="push file (.h5) or directory of push files"
    )
    parser.add_argument(
        "-o", "--output", required=True, metavar="DIR", help="directory for the bags"
    )


def _add_sampling(parser: argparse.ArgumentParser) -> None:
    """Resampling step, the noise added to the observed pose, and the contact threshold."""
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


def _add_scenario(parser: argparse.ArgumentParser) -> None:
    """What the /scenario says: friction candidates, push model, the outlines' directory."""
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
        "dbcslam_ros.importers.mitpush.DEFAULT_PUSH_MODEL",
    )
    parser.add_argument(
        "--shapes",
        metavar="DIR",
        help="directory with <shape>_ext.npy outlines (default: the dataset's shapes/)",
    )


def _add_mass_properties(parser: argparse.ArgumentParser) -> None:
    """Mass and inertia: of a uniform plate cut to the outline, or given."""
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


COMMAND = Command(
    name="import-mitpush",
    help="convert MIT MCube push files (.h5) into bags, one per file",
    description=_DESCRIPTION,
    examples=_EXAMPLES,
    configure=_configure,
    run=_run,
)
