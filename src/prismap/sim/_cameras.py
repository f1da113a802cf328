"""The stereo rigs of the simulated worlds, each defined once, at any image scale."""

from prismap._validate import check_positive
from prismap.camera import StereoCamera


def scaled_camera(camera, scale):
    """``camera`` with its image resized by ``scale``: focal length and size scaled, pixel centres kept.

    The principal point maps as ``(c + 0.5) scale - 0.5`` (pixel centres at integers), the size as
    ``round(size * scale)``; the baseline is unchanged.
    """
    scale = check_positive(scale, "scale")
    if scale == 1.0:
        return camera
    return StereoCamera(camera.focal_px * scale, (camera.cx_px + 0.5) * scale - 0.5, (camera.cy_px + 0.5) * scale - 0.5,
                        camera.baseline_m, doffs_px=camera.doffs_px * scale, width=round(camera.width * scale),
                        height=round(camera.height * scale))


def tsukuba_camera(*, scale=1.0):
    """The New Tsukuba rig: 640x480, f = 615 px, principal point (320, 240), baseline 0.10 m (times ``scale``)."""
    return scaled_camera(StereoCamera(615.0, 320.0, 240.0, 0.10, width=640, height=480), scale)


def kitti_camera(*, scale=1.0):
    """A KITTI-like rig: 1242x375, f = 720 px, principal point at the image centre, baseline 0.54 m.

    ``scale=0.5`` gives KITTI's half size, 621x188 (f = 360 px).
    """
    return scaled_camera(StereoCamera(720.0, 620.5, 187.0, 0.54, width=1242, height=375), scale)
