"""The stereo rigs of the simulated worlds at any image scale (the rigs themselves live in :mod:`prismap.camera`)."""

from __future__ import annotations

from prismap._validate import check_positive
from prismap.camera import AVENUE_CAMERA, KITTI_LIKE_CAMERA, TSUKUBA_CAMERA, StereoCamera


def scaled_camera(camera: StereoCamera, scale: float) -> StereoCamera:
    """``camera`` with its image resized by ``scale``: focal length and size scaled, pixel centres kept.

    The principal point maps as ``(c + 0.5) scale - 0.5`` (pixel centres at integers), the size as
    ``round(size * scale)``; the baseline is unchanged.
    """
    scale = check_positive(scale, "scale")
    if scale == 1.0:
        return camera
    return StereoCamera(
        camera.focal_px * scale,
        (camera.cx_px + 0.5) * scale - 0.5,
        (camera.cy_px + 0.5) * scale - 0.5,
        camera.baseline_m,
        doffs_px=camera.doffs_px * scale,
        width=round(camera.width * scale),
        height=round(camera.height * scale),
    )


def tsukuba_camera(*, scale: float = 1.0) -> StereoCamera:
    """The New Tsukuba rig (:data:`prismap.camera.TSUKUBA_CAMERA`) with its image scaled by ``scale``."""
    return scaled_camera(TSUKUBA_CAMERA, scale)


def kitti_camera(*, scale: float = 1.0) -> StereoCamera:
    """The KITTI-like rig (:data:`prismap.camera.KITTI_LIKE_CAMERA`: 1242x375, f = 720 px, b = 0.54 m), scaled.

    ``scale=0.5`` gives KITTI's half size, 621x188 (f = 360 px).
    """
    return scaled_camera(KITTI_LIKE_CAMERA, scale)


def avenue_camera(*, scale: float = 1.0) -> StereoCamera:
    """The avenue's rig (:data:`prismap.camera.AVENUE_CAMERA`: 620x188, f = 358 px, b = 0.54 m), scaled."""
    return scaled_camera(AVENUE_CAMERA, scale)
