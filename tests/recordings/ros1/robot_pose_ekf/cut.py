"""Cut ``gps_data.bag`` of robot_pose_ekf (3.4 MB, 38 s) to its first 10 s: ``gps_data_10s.bag``.

Run once with the project's environment (``rosbags``), from a copy of the source bag in this folder:

    python tests/recordings/ros1/robot_pose_ekf/cut.py

Every message recorded in the first 10 s of the bag, on every connection, is copied with its record time and its
bytes unchanged, under the connection's own message definition, md5sum, caller id and latching; the rest is left out.
The bag is written by rosbags (ROS 1 format 2.0, chunks uncompressed, as the source's).
"""

from __future__ import annotations

from pathlib import Path

from rosbags.rosbag1 import Reader, Writer

HERE = Path(__file__).parent
SOURCE = HERE / "gps_data.bag"
TARGET = HERE / "gps_data_10s.bag"
SECONDS = 10

with Reader(SOURCE) as reader, Writer(TARGET) as writer:
    end = reader.start_time + SECONDS * 10**9
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
