"""Cyclone DDS configuration of the ``dds`` backend: loopback only unless the user says so.

Default (no environment variables set): interface ``lo``, multicast off
(``AllowMulticast false``), discovery by unicast to the peer ``127.0.0.1``, participant index
``auto`` with ``MaxAutoParticipantIndex`` 64 (so up to ~64 processes per host and domain), domain
``ROS_DOMAIN_ID`` (default 0). The XML is generated here and handed to Cyclone when the domain is
created; a ``CYCLONEDDS_URI`` in the environment is ignored by default.

Leaving loopback is an explicit user choice, by one of:

- ``DBCSLAM_DDS_INTERFACE=eth0`` (an interface name or address): use that interface with
  multicast discovery, like a stock ROS 2 install (talks to other machines on that network).
  ``DBCSLAM_DDS_PEERS=host1,host2`` adds unicast peers.
- ``DBCSLAM_DDS_RESPECT_URI=1``: use the user's own ``CYCLONEDDS_URI`` configuration untouched.

``DBCSLAM_DDS_TRACE=FILE`` adds Cyclone tracing (config + discovery) to FILE; tests use it to
check that every locator is a loopback address.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from xml.sax.saxutils import quoteattr

from dbcslam_ros.errors import UsageError

__all__ = ["DdsConfig", "config_from_env", "domain_id_from_env"]

MAX_AUTO_PARTICIPANT_INDEX = 64


@dataclass(frozen=True)
class DdsConfig:
    """What the generated Cyclone XML says.

    Attributes:
        interface: network interface name or address (``lo`` by default).
        multicast: whether multicast (and so multicast discovery) is allowed.
        peers: unicast discovery peers (``127.0.0.1`` by default).
        trace_file: optional Cyclone trace output file.
        respect_uri: use the environment's ``CYCLONEDDS_URI`` instead of generated XML.
    """

    interface: str = "lo"
    multicast: bool = False
    peers: tuple[str, ...] = ("127.0.0.1",)
    trace_file: str | None = None
    respect_uri: bool = False

    def to_xml(self) -> str | None:
        """The Cyclone configuration XML, or ``None`` when the user's URI is respected."""
        if self.respect_uri:
            return None
        is_addr = self.interface.replace(".", "").isdigit()
        iface = (
            f"<NetworkInterface address={quoteattr(self.interface)}/>"
            if is_addr
            else f"<NetworkInterface name={quoteattr(self.interface)}/>"
        )
        peers = "".join(f"<Peer address={quoteattr(p)}/>" for p in self.peers)
        trace = (
            "<Tracing><Category>config,discovery</Category>"
            f"<OutputFile>{self.trace_file}</OutputFile></Tracing>"
            if self.trace_file
            else ""
        )
        return (
            '<CycloneDDS xmlns="https://cdds.io/config"><Domain Id="any">'
            f"<General><Interfaces>{iface}</Interfaces>"
            f"<AllowMulticast>{'true' if self.multicast else 'false'}</AllowMulticast></General>"
            f"<Discovery>{f'<Peers>{peers}</Peers>' if peers else ''}"
            "<ParticipantIndex>auto</ParticipantIndex>"
            f"<MaxAutoParticipantIndex>{MAX_AUTO_PARTICIPANT_INDEX}</MaxAutoParticipantIndex>"
            "</Discovery>"
            f"{trace}</Domain></CycloneDDS>"
        )


def domain_id_from_env() -> int:
    """``ROS_DOMAIN_ID`` (0..232), default 0.

    Raises:
        UsageError: not an integer in range.
    """
    text = os.environ.get("ROS_DOMAIN_ID", "").strip() or "0"
    try:
        dom = int(text)
    except ValueError as err:
        msg = f"bad ROS_DOMAIN_ID {text!r}: expected an integer 0..232"
        raise UsageError(msg) from err
    if not 0 <= dom <= 232:
        msg = f"bad ROS_DOMAIN_ID {dom}: expected 0..232"
        raise UsageError(msg)
    return dom


def config_from_env() -> DdsConfig:
    """Build the configuration from the ``DBCSLAM_DDS_*`` environment variables."""
    respect = os.environ.get("DBCSLAM_DDS_RESPECT_URI", "") not in ("", "0", "false")
    trace = os.environ.get("DBCSLAM_DDS_TRACE") or None
    iface = os.environ.get("DBCSLAM_DDS_INTERFACE", "").strip()
    extra = tuple(
        p.strip() for p in os.environ.get("DBCSLAM_DDS_PEERS", "").split(",") if p.strip()
    )
    if not iface or iface in ("lo", "127.0.0.1"):
        return DdsConfig("lo", False, ("127.0.0.1", *extra), trace_file=trace, respect_uri=respect)
    return DdsConfig(iface, True, extra, trace_file=trace, respect_uri=respect)
