"""Cut a ROS 1 bag to its first seconds: ``python tests/recordings/cut.py SOURCE TARGET SECONDS``.

Every message recorded in the first SECONDS of SOURCE, on every connection, is copied to TARGET with its record time
and its bytes unchanged, under the connection's own message definition, md5sum, caller id and latching; the rest is
left out. TARGET is written by rosbags (ROS 1 format 2.0, chunks uncompressed). Made so (rosbags 0.11.9):

    ros1/robot_pose_ekf/gps_data_10s.bag    from robot_pose_ekf's gps_data.bag, 10 s
    ros1/rotors/waypoint_example_15s.bag    from rotors_evaluation's waypoint_example.bag, 15 s
"""

from __future__ import annotations

import sys
from pathlib import Path

from rosbags.rosbag1 import Reader, Writer


def cut(source: Path, target: Path, seconds: float) -> None:
    with Reader(source) as reader, Writer(target) as writer:
        end = reader.start_time + int(seconds * 10**9)
        copies = {
            connection.id: writer.add_connection(
                connection.topic,
                connection.msgtype,
                msgdef=connection.msgdef.data,
                md5sum=connection.digest,
                callerid=connection.ext.callerid,  # type: ignore[union-attr]
                latching=connection.ext.latching,  # type: ignore[union-attr]
            )
            for connection in reader.connections
        }
        for connection, time, data in reader.messages(stop=end):
            writer.write(copies[connection.id], time, data)


if __name__ == "__main__":
    cut(Path(sys.argv[1]), Path(sys.argv[2]), float(sys.argv[3]))
