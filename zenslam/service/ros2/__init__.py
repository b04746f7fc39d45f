"""ROS 2 without ROS: zenoh keys, attachments, graph presence and CDR messages exactly as rmw_zenoh puts them.

A ROS 2 node running on rmw_zenoh (``RMW_IMPLEMENTATION=rmw_zenoh_cpp``) publishes each message as
one zenoh put of its CDR bytes on ``<domain>/<topic>/<type>/<type hash>``, with an attachment
(sequence number, source timestamp, publisher GID), and announces itself and every publisher and
subscription with liveliness tokens under ``@ros2_lv/<domain>/``. This package reads and writes
that layout, so zenslam can take frames from a ROS 2 camera driver and ``ros2 topic echo`` on a
robot sees zenslam's poses, without a ROS installation.
"""
