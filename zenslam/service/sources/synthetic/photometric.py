"""Photometric effects on rendered images: motion and defocus blur, exposure gain change, Gaussian noise."""

from __future__ import annotations

import math

import cv2
import numpy as np

from zenslam.service.sources.synthetic.config import PhotometricConfig


def motion_blur_kernel(flow_px: tuple[float, float]) -> np.ndarray | None:
    """A normalised line kernel along the image motion ``flow_px`` (dx, dy) in pixels; None below 1 px."""
    dx, dy = flow_px
    length = math.hypot(dx, dy)
    if length < 1.0:
        return None
    half = math.ceil(length / 2)
    size = 2 * half + 1
    kernel = np.zeros((size, size), np.float32)
    p0 = (round((half - dx / 2) * 16), round((half - dy / 2) * 16))
    p1 = (round((half + dx / 2) * 16), round((half + dy / 2) * 16))
    cv2.line(kernel, p0, p1, 1.0, 1, cv2.LINE_AA, 4)
    return kernel / kernel.sum()


def exposure_gain(config: PhotometricConfig, t_s: float) -> float:
    """Image gain at time ``t_s`` (seconds): 1 + amplitude * sin(2 pi t / period)."""
    return 1.0 + config.gain_amplitude * math.sin(2.0 * math.pi * t_s / config.gain_period_s)


def apply_photometric(
    grey: np.ndarray,
    config: PhotometricConfig,
    t_s: float,
    flow_px: tuple[float, float],
    rng: np.random.Generator,
) -> np.ndarray:
    """The degraded copy of ``grey`` (uint8): motion blur along ``flow_px``, defocus, gain, then noise.

    ``flow_px`` is the image motion (pixels) during the exposure; ``rng`` draws the noise, so the same
    generator state gives the same image.
    """
    if not config.enabled:
        return grey
    img = grey.astype(np.float32)
    if config.motion_blur_exposure_s > 0:
        kernel = motion_blur_kernel(flow_px)
        if kernel is not None:
            img = cv2.filter2D(img, -1, kernel, borderType=cv2.BORDER_REFLECT_101)
    if config.defocus_sigma_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), config.defocus_sigma_px, borderType=cv2.BORDER_REFLECT_101)
    if config.gain_amplitude > 0:
        img *= np.float32(exposure_gain(config, t_s))
    if config.noise_sigma > 0:
        img += rng.normal(0.0, config.noise_sigma, size=img.shape).astype(np.float32)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)
