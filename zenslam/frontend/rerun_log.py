"""What the frontend process logs to its rerun recording per frame, beside its node.

Entity paths (the recording itself, its timelines and blueprint are ``zenslam.runtime.rerun_log``'s)::

    frontend/camera/left            the left image tracked (every ``image_every_n``-th frame)
    frontend/keypoints              every ORB keypoint of the frame (Points2D, level-0 pixels)
    frontend/matches                the keypoints tracked to map points (Points2D)
    frontend/pose                   T_world_cam (Transform3D), with a camera frustum below it
    frontend/state                  the tracking state when it changes (TextLog)
    frontend/counts/<name>          tracked points, keypoints (Scalars)
    frontend/timing/<stage>         milliseconds per tracking stage (Scalars)
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np
import rerun as rr

from zenslam.camera import PinholeCalibration
from zenslam.runtime.rerun_log import StageRecording, log_world_axes

if TYPE_CHECKING:
    from zenslam.frontend.pipeline import FrontendPipeline, TrackingOutput

# Colours (RGB) the blueprint's image view shows; fixed so two recordings look alike.
_KEYPOINT_RGB = (150, 150, 150)
_MATCH_RGB = (40, 220, 60)


def _jpeg_image(grey: np.ndarray, quality: int) -> rr.EncodedImage:
    """``grey`` (uint8) as a JPEG-encoded image, compressed by OpenCV. rerun's own ``Image.compress``
    goes through Pillow, whose first save loads every image plugin into the logging process."""
    encoded, data = cv2.imencode(".jpg", grey, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not encoded:
        raise ValueError(f"OpenCV could not JPEG-encode a {grey.shape} {grey.dtype} image")
    return rr.EncodedImage(contents=data.tobytes(), media_type="image/jpeg")


class FrontendLog:
    """What the frontend process logs per frame: the image, keypoints, tracked points, pose, state, counts, timings."""

    def __init__(self, recording: StageRecording) -> None:
        self.recording = recording
        self._camera: PinholeCalibration | None = None
        self._last_state: tuple[str, str | None] | None = None
        log_world_axes(recording)

    def log_camera(self, calibration: PinholeCalibration) -> None:
        """The camera frustum under frontend/pose (static; logged again only if the calibration changes)."""
        if calibration == self._camera:
            return
        self._camera = calibration
        pinhole = rr.Pinhole(
            image_from_camera=calibration.K,
            resolution=[calibration.width, calibration.height],
            camera_xyz=rr.ViewCoordinates.RDF,
            image_plane_distance=0.3,
        )
        self.recording.log("frontend/pose/camera", pinhole, static=True)

    def log_frame(
        self, output: TrackingOutput, keypoints: tuple[np.ndarray, np.ndarray] | None = None, left: np.ndarray | None = None
    ) -> None:
        """Log one frame's output; ``keypoints`` = (px (N, 2) level-0 pixels, tracked (N,) bool) when known;
        ``left``: the frame's left image (uint8), logged on every ``image_every_n``-th frame."""
        rec = self.recording
        rec.at(output.index, output.stamp_ns)
        config = rec.config
        if left is not None and output.index % config.image_every_n == 0:
            image = _jpeg_image(left, config.jpeg_quality) if config.jpeg else rr.Image(left, color_model="L")
            rec.log("frontend/camera/left", image)
        if keypoints is not None:
            px, tracked = keypoints
            rec.log("frontend/keypoints", rr.Points2D(px, radii=1.5, colors=_KEYPOINT_RGB))
            rec.log("frontend/matches", rr.Points2D(px[tracked], radii=2.5, colors=_MATCH_RGB))
            rec.log("frontend/counts/keypoints", rr.Scalars(float(len(px))))
        if output.T_world_cam is not None:
            T = np.asarray(output.T_world_cam, dtype=float)
            rec.log("frontend/pose", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
        state = (output.state, output.lost_reason)
        if state != self._last_state:
            self._last_state = state
            text = output.state if output.lost_reason is None else f"{output.state}: {output.lost_reason}"
            rec.log("frontend/state", rr.TextLog(text, level="INFO" if output.state == "ok" else "WARN"))
        rec.log("frontend/counts/tracked", rr.Scalars(float(output.n_tracked)))
        rec.scalars("frontend/timing", output.timings_ms)


def tracked_keypoints(pipeline: FrontendPipeline, index: int) -> tuple[np.ndarray, np.ndarray] | None:
    """(px (N, 2), tracked (N,) bool) of frame ``index`` from the tracker's last frame; None when not at hand.

    The output does not carry the keypoints; the tracker keeps the last tracked frame with the
    map-point row of each keypoint (-1: none). A lost frame is not kept: None.
    """
    last = pipeline.tracker.last_frame
    if last is None or last.frame.index != index:
        return None
    px = np.asarray(last.frame.features.px, dtype=np.float32).reshape(-1, 2)
    return px, np.asarray(last.rows) >= 0
