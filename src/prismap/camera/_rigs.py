"""The stereo rigs prismap knows by name: one definition each, imported by readers, simulators and studies."""

from prismap.camera._stereo_camera import StereoCamera

MOTORCYCLE_CAMERA = StereoCamera(
    focal_px=994.978, cx_px=311.193, cy_px=254.877, baseline_m=0.193001, doffs_px=31.086, width=741, height=500
)
"""The quarter-resolution Middlebury 2014 Motorcycle rig bundled in scikit-image (DESIGN.md)."""

TSUKUBA_CAMERA = StereoCamera(focal_px=615.0, cx_px=320.0, cy_px=240.0, baseline_m=0.10, width=640, height=480)
"""New Tsukuba's rectified rig: f = 615 px, principal point (320, 240), baseline 10 cm, 640x480."""

KITTI_CAMERA = StereoCamera(focal_px=721.5377, cx_px=609.5593, cy_px=172.854, baseline_m=0.5327, width=1242, height=375)
"""KITTI 2011_09_26 colour cameras 2 and 3 (``P_rect_02``/``P_rect_03``, as in KITTI stereo 2015), 1242x375."""

KITTI_LIKE_CAMERA = StereoCamera(focal_px=720.0, cx_px=620.5, cy_px=187.0, baseline_m=0.54, width=1242, height=375)
"""The simulated street's idealised KITTI-like rig: 1242x375, f = 720 px, principal point at the image centre,
baseline 0.54 m (``prismap.sim.kitti_camera`` scales it)."""

AVENUE_CAMERA = StereoCamera(focal_px=358.0, cx_px=311.2, cy_px=92.0, baseline_m=0.54, width=620, height=188)
"""The simulated avenue's rig (``prismap.sim.avenue_camera`` scales it): 620x188, f = 358 px, baseline 0.54 m,
principal point off the image centre; close to the street's half-size KITTI-like rig, not equal to it."""
