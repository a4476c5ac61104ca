"""rosbag2 bags (metadata version 9, MCAP storage, CDR messages): write, read, salvage.

Write::

    from dbcslam_ros.bag import BagWriter, write_bag
    with BagWriter("out/run1") as bag:                      # refuses an existing path
        bag.add_topic("/scenario", "std_msgs/msg/String", [LATCHED_QOS])
        bag.write("/scenario", cdr_bytes, log_time_ns)
        bag.write_message("/object/pose", pose_msg, log_time_ns)   # rosbags dataclass

Read (log-time order; ``BagError`` names the file and the problem)::

    from dbcslam_ros.bag import open_bag
    with open_bag("out/run1") as bag:                       # or a bare .mcap file
        for msg, obj in bag.decoded(["/object/pose"]):
            ...

Compatibility: the bags open in rosbags (``AnyReader([path])``), in the mcap tools
(``mcap.reader.make_reader`` + ``mcap_ros2.decoder.DecoderFactory``; tests prove both) and in
ROS 2 Jazzy's ``ros2 bag play BAG_DIR`` / ``ros2 bag info BAG_DIR`` (storage ``mcap`` is read
from metadata.yaml; for the bare file use ``ros2 bag play -s mcap BAG_DIR/NAME_0.mcap``). The
layout follows rosbag2 Jazzy: metadata version 9 with ``offered_qos_profiles`` as a YAML
sequence (enum names as strings), MCAP channel metadata ``offered_qos_profiles`` (YAML
string) and ``topic_type_hash`` (RIHS01), ``ros2msg`` schemas with the concatenated
definitions.
"""

from __future__ import annotations

from dbcslam_ros.bag.metadata import METADATA_VERSION, BagMetadata, TopicInfo
from dbcslam_ros.bag.qos import (
    LATCHED_QOS,
    RELIABLE_QOS,
    SENSOR_DATA_QOS,
    Qos,
    contract_qos,
    make_qos,
    qos_from_yaml,
    qos_to_yaml_string,
)
from dbcslam_ros.bag.reader import (
    BagMessage,
    BagReader,
    TopicSummary,
    find_bags,
    open_bag,
    read_bag,
)
from dbcslam_ros.bag.types import deserialize, jazzy_typestore, message_definition, serialize
from dbcslam_ros.bag.writer import BagWriter, TopicSpec, write_bag

__all__ = [
    "LATCHED_QOS",
    "METADATA_VERSION",
    "RELIABLE_QOS",
    "SENSOR_DATA_QOS",
    "BagMessage",
    "BagMetadata",
    "BagReader",
    "BagWriter",
    "Qos",
    "TopicInfo",
    "TopicSpec",
    "TopicSummary",
    "contract_qos",
    "deserialize",
    "find_bags",
    "jazzy_typestore",
    "make_qos",
    "message_definition",
    "open_bag",
    "qos_from_yaml",
    "qos_to_yaml_string",
    "read_bag",
    "serialize",
    "write_bag",
]
