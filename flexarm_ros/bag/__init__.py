"""rosbag2-compatible MCAP bags without ROS: write with :class:`BagWriter`, read with
:func:`read_bag` / :func:`iter_messages`, build messages with :mod:`.messages`.

The module needs only numpy, PyYAML, ``mcap`` and ``mcap-ros2-support`` (no rclpy).
See :mod:`.writer` for what "rosbag2-compatible" means and what a killed writer loses,
:mod:`.reader` for how damaged files are read (:mod:`.salvage`: the scanner that finds
their intact records), :mod:`.msgdefs` for the message types; what the twin's recordings
hold (scene, namespace, sensor batches) is read by :mod:`flexarm_ros.twin.recording`.
"""

from flexarm_ros.bag import messages, msgdefs
from flexarm_ros.bag.msgdefs import KNOWN_TYPES
from flexarm_ros.bag.reader import (Bag, BagError, BagMessage, CorruptChunkWarning, Damage, TruncatedBagWarning, iter_messages, read_bag, to_dict)
from flexarm_ros.bag.writer import INFO_METADATA_NAME, ROSBAG2_METADATA_NAME, BagWriter

__all__ = [
    "Bag",
    "BagError",
    "BagMessage",
    "BagWriter",
    "CorruptChunkWarning",
    "Damage",
    "INFO_METADATA_NAME",
    "KNOWN_TYPES",
    "ROSBAG2_METADATA_NAME",
    "TruncatedBagWarning",
    "iter_messages",
    "messages",
    "msgdefs",
    "read_bag",
    "to_dict",
]
