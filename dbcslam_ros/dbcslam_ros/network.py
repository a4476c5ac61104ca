"""Network defaults of every DBC-SLAM process: DDS traffic stays on this machine.

Call :func:`apply_loopback_defaults` before ``rclpy.init`` (every entry point of the project
does, through its one ROS initialisation function); processes it starts inherit the result.

What it does, in this order (the first rule that applies wins):

1. ``DBCSLAM_NETWORK=system``: nothing. The ROS/DDS environment is used exactly as the user
   set it up. This is *the* explicit way to leave loopback (talk to other machines).
2. The user names a Fast DDS profile of their own (``FASTRTPS_DEFAULT_PROFILES_FILE`` or
   ``FASTDDS_DEFAULT_PROFILES_FILE`` set): it is used untouched, and
   ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` is set unless the user set the range.
3. Another RMW than Fast DDS is selected (``RMW_IMPLEMENTATION``): the Fast DDS profile
   cannot act, so ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` is set unless the user set it.
4. Default: the shipped Fast DDS profile ``config/fastdds_loopback.xml`` is used (both profile
   variables point at it). Its participant has exactly two transports, UDPv4 restricted to
   the interface 127.0.0.1 and shared memory, no built-in transports, no multicast, and
   discovers peers by unicast to 127.0.0.1 only: every socket of the process is bound to
   127.0.0.1 (measured; ``tests/ros/test_network_loopback.py`` checks it on running nodes).
   ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` is replaced by ``SUBNET`` for this process
   (and the ones it starts), on purpose: with LOCALHOST ``rmw_fastrtps_cpp`` (Jazzy, 8.4)
   adds a wildcard metatraffic locator to the participant, and Fast DDS 2.14 then opens
   output sockets on 0.0.0.0 and on the machine's external address although the profile
   restricts the transports to 127.0.0.1 (measured with ``/proc/<pid>/net/udp``). With the
   profile, SUBNET adds nothing (no multicast, peers only 127.0.0.1): the profile alone
   confines discovery and data to this machine, and LOCALHOST peers (127.0.0.1) still find
   our nodes. Other ranges (``OFF``, ``SUBNET``) are kept.

Environment values are validated: a ``DBCSLAM_NETWORK`` other than ``loopback``/``system``, or
a profile file that does not exist, raises :class:`~dbcslam_ros.errors.UsageError` naming the
value and what would be valid.
"""

from __future__ import annotations

import os
from collections.abc import MutableMapping
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from dbcslam_ros.errors import UsageError

__all__ = [
    "DISCOVERY_RANGE_VAR",
    "NETWORK_MODE_VAR",
    "PROFILE_VARS",
    "NetworkSetup",
    "apply_loopback_defaults",
    "loopback_profile_path",
]

NETWORK_MODE_VAR = "DBCSLAM_NETWORK"
DISCOVERY_RANGE_VAR = "ROS_AUTOMATIC_DISCOVERY_RANGE"
PROFILE_VARS = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")
_MODES = ("loopback", "system")
_FASTDDS_RMWS = ("", "rmw_fastrtps_cpp", "rmw_fastrtps_dynamic_cpp")


@dataclass(frozen=True)
class NetworkSetup:
    """What :func:`apply_loopback_defaults` decided (for logs and tests).

    mode: ``shipped_profile`` (rule 4), ``user_profile`` (2), ``other_rmw`` (3) or ``system``
    (1). profile: the Fast DDS profile file in effect ("" if none). discovery_range: the
    value of ``ROS_AUTOMATIC_DISCOVERY_RANGE`` after the call ("" if unset).
    """

    mode: str
    profile: str
    discovery_range: str


def loopback_profile_path() -> Path:
    """Path of the shipped loopback-only Fast DDS XML profile (package data)."""
    ref = resources.files("dbcslam_ros").joinpath("config", "fastdds_loopback.xml")
    return Path(str(ref))


def apply_loopback_defaults(environ: MutableMapping[str, str] | None = None) -> NetworkSetup:
    """Set the loopback-only DDS defaults in ``environ`` (default: ``os.environ``).

    Call before ``rclpy.init``. Never overrides a value the user set, except a LOCALHOST
    discovery range under the shipped profile (see the module docstring for the rules).
    Raises UsageError on an invalid ``DBCSLAM_NETWORK`` or a missing profile file.
    """
    env = os.environ if environ is None else environ
    mode = env.get(NETWORK_MODE_VAR, "").strip().lower() or "loopback"
    if mode not in _MODES:
        msg = (
            f"{NETWORK_MODE_VAR}={env[NETWORK_MODE_VAR]!r} is not valid: use 'loopback' "
            "(default: DDS traffic stays on 127.0.0.1 and shared memory) or 'system' (use the "
            "ROS/DDS environment as it is, e.g. to reach other machines)"
        )
        raise UsageError(msg)
    if mode == "system":
        return _setup(env, "system")
    user_profile = next((env[v] for v in PROFILE_VARS if env.get(v)), "")
    if user_profile:
        if not Path(user_profile).is_file():
            msg = (
                f"Fast DDS profile {user_profile!r} (from the environment) does not exist: "
                f"unset {' / '.join(PROFILE_VARS)} to use the shipped loopback profile"
            )
            raise UsageError(msg)
        env.setdefault(DISCOVERY_RANGE_VAR, "LOCALHOST")
        return _setup(env, "user_profile")
    if env.get("RMW_IMPLEMENTATION", "") not in _FASTDDS_RMWS:
        env.setdefault(DISCOVERY_RANGE_VAR, "LOCALHOST")
        return _setup(env, "other_rmw")
    profile = loopback_profile_path()
    if not profile.is_file():  # a broken install: never fall back silently to all interfaces
        msg = f"the shipped Fast DDS profile {profile} is missing: reinstall dbcslam_ros"
        raise UsageError(msg)
    for var in PROFILE_VARS:
        env[var] = str(profile)
    if env.get(DISCOVERY_RANGE_VAR, "").strip().upper() == "LOCALHOST":
        env[DISCOVERY_RANGE_VAR] = "SUBNET"  # see rule 4: LOCALHOST would leave loopback
    return _setup(env, "shipped_profile")


def _setup(env: MutableMapping[str, str], mode: str) -> NetworkSetup:
    profile = next((env[v] for v in PROFILE_VARS if env.get(v)), "")
    return NetworkSetup(mode, profile, env.get(DISCOVERY_RANGE_VAR, ""))
