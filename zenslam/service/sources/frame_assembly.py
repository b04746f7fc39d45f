"""Frames from separate bus messages: images paired by stamp, the sensor chosen, the calibration built.

``FrameAssembler`` takes decoded messages as they arrive (any family, see bus_messages.py) and hands
out the newest complete frame when asked: tracking takes the newest, so frames that arrived while
it was busy are *dropped* (counted). A frame is complete when its images are there (stereo: a left
and a right image whose stamps differ by at most ``pair_tolerance_ns``; RGB-D: an image and a
depth image likewise) and the calibration is known. Messages that cannot be used are *rejected*
and counted by reason: ``unpaired`` (an image whose partner never came), ``wrong_size`` (an image
of another size than the calibration's), ``bad_calibration`` (a calibration that does not give a
usable rectified camera), ``camera_changed`` (a frame message with another camera than the first).

The layout is set by the first image or frame message: ``frame`` (whole zenslam frames),
``stereo`` (left/right keys) or ``camera`` (the image key: mono, or RGB-D once a depth image
arrives before the second image); messages of another layout are then ignored.
"""

from __future__ import annotations

import dataclasses
import logging
from collections import Counter, deque
from typing import Literal

from zenslam.camera import PinholeCalibration, SensorKind
from zenslam.errors import CalibrationError
from zenslam.schemas import codec
from zenslam.schemas.sensor_data import SensorFrame
from zenslam.service.sources.bus_messages import BusCalibration, BusImage, BusMessage, Role, baseline_of, pinhole_of
from zenslam.service.sources.sensor_selection import mono_calibration

logger = logging.getLogger(__name__)

Layout = Literal["frame", "stereo", "camera"]
_LAYOUT_OF: dict[Role, Layout] = {"frame": "frame", "left_image": "stereo", "right_image": "stereo", "image": "camera", "depth": "camera"}
_PRIMARY: dict[Layout, Role] = {"frame": "frame", "stereo": "left_image", "camera": "image"}


def _stamp(message: BusImage | codec.FrameMessage) -> int:
    return message.frame.stamp_ns if isinstance(message, codec.FrameMessage) else message.stamp_ns


class FrameAssembler:
    """Builds frames from messages (``add``) and gives the newest complete one (``take_newest``).

    ``keys``: role -> key expression, for messages people read. ``calibration``: an override
    (``--orbslam-settings``) that replaces every calibration message. ``sensor``: play the input as
    this sensor (mono takes the left images alone). ``pending_limit``: images kept per role while
    waiting for a partner, images.
    """

    def __init__(
        self,
        name: str,
        keys: dict[Role, str],
        calibration: PinholeCalibration | None = None,
        sensor: SensorKind | None = None,
        pair_tolerance_ns: int = 0,
        pending_limit: int = 8,
    ):
        self.name = name
        self._keys = keys
        self._override = calibration
        self._sensor_choice = sensor
        self._tolerance_ns = pair_tolerance_ns
        self._layout: Layout | None = None
        self._sensor: SensorKind | None = None  # chosen with the layout (camera layout: once mono vs RGB-D is known)
        self._primary: deque[tuple[int, BusImage | codec.FrameMessage]] = deque()  # (index, message), oldest first
        self._secondary: deque[BusImage] = deque()  # right or depth images, oldest first
        self._pending_limit = pending_limit
        self._calibrations: dict[Role, BusCalibration] = {}
        self.calibration: PinholeCalibration | None = None  # fixed by the first frame handed out
        self.calibration_problem: str | None = None  # why the calibration messages so far give no camera
        self.received = 0  # frames that arrived (primary images or frame messages)
        self.dropped = 0  # complete frames passed over for a newer one
        self.rejected: Counter[str] = Counter()  # messages that could not be used, by reason
        self._warned: set[str] = set()

    @property
    def sensor(self) -> SensorKind | None:
        """The sensor the frames are played as, once known."""
        return self._sensor

    def reject(self, reason: str, detail: str) -> None:
        """Count a message that cannot be used; the first of each reason is a warning."""
        self.rejected[reason] += 1
        level = logging.DEBUG if reason in self._warned else logging.WARNING
        self._warned.add(reason)
        logger.log(level, "%s: %s [%s; %d such message(s) so far]", self.name, detail, reason, self.rejected[reason])

    def add(self, role: Role, message: BusMessage) -> None:
        """Take one decoded message of ``role``."""
        if isinstance(message, BusCalibration):
            self._add_calibration(role, message)
            return
        layout = _LAYOUT_OF[role]
        if self._layout is None:
            self._choose_layout(layout)
        if layout != self._layout:
            self._warn_once(f"layout-{role}", "%s: ignoring %s messages: the input is a %s stream", role, self._layout)
            return
        if role == _PRIMARY[layout]:
            self._primary.append((self.received, message))
            self.received += 1
            if self._layout == "camera" and self._sensor is None and len(self._primary) > 1:
                self._sensor = "mono"  # a second image before any depth image
            while len(self._primary) > self._pending_limit:
                _, old = self._primary.popleft()
                self._pass_over(old)
        elif self._uses_secondary(role):
            if self._layout == "camera" and self._sensor is None:
                self._sensor = "rgbd"
            self._secondary.append(message)
            while len(self._secondary) > self._pending_limit:
                self._secondary.popleft()

    def _choose_layout(self, layout: Layout) -> None:
        self._layout = layout
        if layout == "stereo":
            self._sensor = "mono" if self._sensor_choice == "mono" else "stereo"
        elif layout == "camera" and self._sensor_choice is not None:
            self._sensor = self._sensor_choice
        logger.info("%s: %s input", self.name, {"frame": "zenslam frame", "stereo": "stereo image", "camera": "camera image"}[layout])

    def _uses_secondary(self, role: Role) -> bool:
        return (role == "right_image" and self._sensor == "stereo") or (role == "depth" and self._sensor in (None, "rgbd"))

    def _warn_once(self, what: str, message: str, *args: object) -> None:
        if what not in self._warned:
            self._warned.add(what)
            logger.warning("%s: " + message, self.name, *args)

    def _add_calibration(self, role: Role, calibration: BusCalibration) -> None:
        if self._override is not None:
            return
        try:
            pinhole_of(calibration, self._keys[role])
        except CalibrationError as exc:
            self.calibration_problem = str(exc)
            self.reject("bad_calibration", str(exc))
            return
        self._calibrations[role] = calibration

    def _partner(self, stamp_ns: int) -> BusImage | None:
        best = None
        for image in self._secondary:
            gap = abs(image.stamp_ns - stamp_ns)
            if gap <= self._tolerance_ns and (best is None or gap < abs(best.stamp_ns - stamp_ns)):
                best = image
        return best

    def _needs_partner(self) -> bool:
        return self._sensor in ("stereo", "rgbd") and self._layout != "frame"

    def _pass_over(self, message: BusImage | codec.FrameMessage) -> None:
        """Count a primary message that will never be handed out: dropped, or unpaired without a partner."""
        key = self._keys[_PRIMARY[self._layout or "frame"]]
        if isinstance(message, BusImage) and self._needs_partner() and self._partner(message.stamp_ns) is None:
            self.reject("unpaired", f"{key}: image stamped {message.stamp_ns} ns has no partner within {self._tolerance_ns} ns")
        elif isinstance(message, BusImage) and self.calibration is None and self._camera() is None:
            self.reject("no_calibration", f"{key}: image stamped {message.stamp_ns} ns passed over: no calibration yet")
        else:
            self.dropped += 1

    def take_newest(self) -> codec.FrameMessage | None:
        """The newest complete frame (older ones dropped), or None when there is none yet."""
        if self._layout is None or self._sensor is None and self._layout != "frame":
            return None
        chosen = None
        for index, message in sorted(self._primary, key=lambda item: _stamp(item[1]), reverse=True):
            partner = self._partner(message.stamp_ns) if self._needs_partner() else None
            if not self._needs_partner() or partner is not None:
                chosen = (index, message, partner)
                break
        if chosen is None:
            return None
        index, message, partner = chosen
        if isinstance(message, BusImage) and self._camera() is None:
            return None  # kept, with the older ones, until a calibration arrives
        stamp_ns = _stamp(message)
        older = [item for item in self._primary if _stamp(item[1]) <= stamp_ns and item[1] is not message]
        self._primary = deque(item for item in self._primary if _stamp(item[1]) > stamp_ns)
        for _, old in older:
            self._pass_over(old)
        self._drop_secondaries_until(stamp_ns + self._tolerance_ns)
        if isinstance(message, codec.FrameMessage):
            return self._from_frame_message(index, message)
        return self._frame(index, message, partner)

    def _drop_secondaries_until(self, stamp_ns: int) -> None:
        while self._secondary and self._secondary[0].stamp_ns <= stamp_ns:
            self._secondary.popleft()

    def camera_known(self) -> bool:
        """True once the calibration messages (or the override) give a camera."""
        return self._camera() is not None

    def _camera(self) -> PinholeCalibration | None:
        """The calibration of the frames (an override, or from the calibration messages), or None yet."""
        if self.calibration is not None or self._override is not None:
            return self.calibration or self._override
        main = self._calibrations.get("left_calibration" if self._layout == "stereo" else "calibration")
        if main is None:
            return None
        camera = pinhole_of(main, self._keys["left_calibration" if self._layout == "stereo" else "calibration"])
        if self._sensor == "mono":
            return camera
        right = self._calibrations.get("right_calibration") if self._sensor == "stereo" else main
        baseline = None if right is None else baseline_of(right)
        if baseline is None:
            where = self._keys["right_calibration" if self._sensor == "stereo" else "calibration"]
            self.calibration_problem = (
                f"no baseline yet: {where} must state it as P[0][3] = -fx * baseline (metres)"
            )
            return None
        return dataclasses.replace(camera, baseline_m=baseline)

    def _fix_camera(self, width: int, height: int) -> PinholeCalibration | None:
        """The calibration of images of ``width`` x ``height``, fixed for the stream at the first frame."""
        if self.calibration is not None:
            return self.calibration if (self.calibration.width, self.calibration.height) == (width, height) else None
        camera = self._camera()
        if camera is None:
            return None
        if self._override is not None:
            camera = camera.fitted_to(width, height)  # a settings file for other images is the user's to fix
        elif (camera.width, camera.height) != (width, height):
            return None
        self.calibration = mono_calibration(camera) if self._sensor == "mono" else camera
        logger.info("%s: %s camera, %s", self.name, self._sensor, self.calibration.summary())
        return self.calibration

    def _frame(self, index: int, image: BusImage, partner: BusImage | None) -> codec.FrameMessage | None:
        height, width = image.pixels.shape[:2]
        camera = self._fix_camera(width, height)
        sizes_ok = partner is None or partner.pixels.shape == image.pixels.shape
        if camera is None or not sizes_ok or image.pixels.dtype.kind != "u":
            stated = self.calibration or self._camera()
            if self.calibration is None and stated is not None:
                self.calibration_problem = f"the calibration states {stated.width}x{stated.height} images, they are {width}x{height}"
            self.reject("wrong_size", f"frame stamped {image.stamp_ns} ns: images {image.pixels.shape}"
                        f"{'' if partner is None else f' and {partner.pixels.shape}'} do not match the camera "
                        f"{stated.summary() if stated else '(none)'}")  # fmt: skip
            return None
        right = partner.pixels if self._sensor == "stereo" and partner is not None else None
        depth = partner.pixels if self._sensor == "rgbd" and partner is not None else None
        frame = SensorFrame(index=index, stamp_ns=image.stamp_ns, left=image.pixels, right=right, depth_m=depth)
        return codec.FrameMessage(frame, camera, self._sensor, self.name)

    def _from_frame_message(self, index: int, message: codec.FrameMessage) -> codec.FrameMessage | None:
        sensor = message.sensor if self._sensor_choice is None else self._sensor_choice
        frame = dataclasses.replace(message.frame, index=index)
        if sensor == "mono" and message.sensor != "mono":
            frame = dataclasses.replace(frame, right=None, depth_m=None)
        elif sensor != message.sensor:
            self.reject("camera_changed", f"a {message.sensor} frame cannot be played as {sensor}")
            return None
        camera = self._override.fitted_to(message.calibration.width, message.calibration.height) if self._override else message.calibration
        camera = mono_calibration(camera) if sensor == "mono" else camera
        if self.calibration is None:
            self.calibration, self._sensor = camera, sensor
            logger.info("%s: %s camera, %s", self.name, sensor, camera.summary())
        elif (camera, sensor) != (self.calibration, self._sensor):
            self.reject("camera_changed", f"frame with {sensor} {camera.summary()} after frames of {self.calibration.summary()}")
            return None
        return codec.FrameMessage(frame, camera, sensor, message.source_name or self.name)
