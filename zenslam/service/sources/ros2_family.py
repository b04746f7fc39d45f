"""``ros2:<namespace>``: the camera topics a ROS 2 driver on rmw_zenoh publishes, as a bus source.

The topics follow image_transport's convention (what ``zenslam publish --ros2`` sends, see
ros2/frames.py): ``<namespace>/image_rect`` + ``<namespace>/camera_info`` for a mono camera (RGB-D
adds ``<namespace>/depth/image_rect``), ``<namespace>/left/...`` and ``<namespace>/right/...`` for a
stereo pair; sensor_msgs/Image or, on ``.../image_rect/compressed``, CompressedImage. The keys and CDR
payloads are rmw_zenoh's (ros2/keys.py, ros2/messages.py), in the ROS domain ``source.ros_domain``.
Everything after decoding is shared with ``zenoh:`` sources (frame_assembly.py, bus_source.py).
"""

from __future__ import annotations

import numpy as np

from zenslam.errors import MessageError
from zenslam.schemas import codec
from zenslam.service.ros2 import keys as ros_keys
from zenslam.service.ros2 import messages
from zenslam.service.sources.bus_messages import BusCalibration, BusImage, BusMessage, Role

_TOPICS: dict[str, Role] = {
    "/image_rect": "image",
    "/camera_info": "calibration",
    "/depth/image_rect": "depth",
    "/left/image_rect": "left_image",
    "/left/camera_info": "left_calibration",
    "/right/image_rect": "right_image",
    "/right/camera_info": "right_calibration",
}


class Ros2Family:
    """The camera topics under ``namespace`` in ROS domain ``domain_id`` (spec ``ros2:<namespace>``)."""

    def __init__(self, namespace: str, domain_id: int):
        self.namespace = ros_keys.check_topic("/" + namespace.strip("/"))
        self.domain_id = ros_keys.check_domain_id(domain_id)

    @property
    def name(self) -> str:
        return f"ros2:{self.namespace}"

    def subscriptions(self) -> dict[str, Role]:
        out: dict[str, Role] = {}
        for suffix, role in _TOPICS.items():
            out[ros_keys.topic_subscription_key(self.domain_id, self.namespace + suffix)] = role
            if suffix.endswith("image_rect"):
                out[ros_keys.topic_subscription_key(self.domain_id, self.namespace + suffix + "/compressed")] = role
        return out

    def liveliness_key(self) -> str:
        # rmw_zenoh's publisher tokens (MP) of the topics under the namespace (their names mangled into one chunk).
        return f"@ros2_lv/{self.domain_id}/**/MP/**/{ros_keys.mangle(self.namespace)}$*/**"

    def decode(self, role: Role, key: str, payload: bytes, schema: str | None) -> BusMessage | codec.EndOfStream:
        topic = ros_keys.topic_of_key(key)
        type_name = ros_keys.type_name_of_key(key)
        if role.endswith("calibration"):
            if type_name != "sensor_msgs/msg/CameraInfo":
                raise MessageError(f"{topic}: expected sensor_msgs/msg/CameraInfo, the key says {type_name}")
            info = messages.decode_camera_info(payload, topic)
            return BusCalibration(info.stamp_ns, info.width, info.height, info.k, info.d, info.p)
        if type_name == "sensor_msgs/msg/Image":
            image = messages.decode_image(payload, topic)
        elif type_name == "sensor_msgs/msg/CompressedImage":
            image = messages.decode_compressed_image(payload, topic)
        else:
            raise MessageError(f"{topic}: expected sensor_msgs/msg/Image or CompressedImage, the key says {type_name}")
        if role == "depth":
            if not image.is_depth:
                raise MessageError(f"{topic}: a depth topic needs 16UC1 or 32FC1 images, got {image.encoding}")
            return BusImage(image.stamp_ns, np.asarray(image.image, np.float32))
        return BusImage(image.stamp_ns, image.grey())
