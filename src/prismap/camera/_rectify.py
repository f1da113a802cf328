"""Rectification of two calibrated cameras by the thesis construction (eq. 3.4-3.6)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from prismap._validate import as_float_array
from prismap.camera._stereo_camera import StereoCamera
from prismap.errors import PrismapInputError


@dataclass(frozen=True)
class Rectification:
    """A rectified pair: its camera, the two image homographies and the rectified pose.

    Attributes
    ----------
    camera : StereoCamera
        Shared intrinsics ``Kn`` and baseline ``|C' - C|`` of the rectified pair (``doffs = 0``).
    H_left, H_right : (3, 3) float64
        Homographies ``T1 = Kn Rn R^T K^-1`` and ``T2 = Kn Rn R'^T K'^-1`` (eq. 3.6): original
        pixel (homogeneous) -> rectified pixel.
    T_world_cam : (4, 4) float64, metres
        Pose of the rectified left camera: rotation ``Rn^T``, centre ``C`` of the original left camera.
    """

    camera: StereoCamera
    H_left: np.ndarray
    H_right: np.ndarray
    T_world_cam: np.ndarray


def rectify_stereo(
    K_left: npt.ArrayLike,
    T_world_left: npt.ArrayLike,
    K_right: npt.ArrayLike,
    T_world_right: npt.ArrayLike,
    *,
    width: int | None = None,
    height: int | None = None,
) -> Rectification:
    """Rectify two calibrated pinhole cameras (thesis eq. 3.4-3.6).

    The cameras are ``P = K R [I | -C]`` with ``R`` world -> camera and ``C`` the centre in the
    world. The rectified pair keeps both centres and shares one orientation ``Rn`` whose x axis
    points along ``C' - C`` and whose z axis is the mean optical axis made orthogonal to it, and
    one intrinsic matrix ``Kn``: the average ``0.5 (K + K')`` with its two focal lengths averaged
    and its skew dropped, so that pixels stay square (identical to the average for square-pixel,
    zero-skew inputs). Corresponding points then share a row; the right camera's centre must lie
    on the +x side of the left camera.

    Parameters
    ----------
    K_left, K_right : (3, 3) float, pixels
        Intrinsic matrices of the original cameras (no lens distortion).
    T_world_left, T_world_right : (4, 4) float, metres
        Camera-to-world poses of the original cameras (OpenCV axes).
    width, height : int or None, pixels
        Size of the rectified images, stored on the returned camera.

    Returns
    -------
    Rectification
    """
    K1 = _intrinsics(K_left, "K_left")
    K2 = _intrinsics(K_right, "K_right")
    R1, C1 = _pose(T_world_left, "T_world_left")
    R2, C2 = _pose(T_world_right, "T_world_right")
    baseline_w = C2 - C1
    baseline_m = float(np.linalg.norm(baseline_w))
    if baseline_m == 0.0:
        raise PrismapInputError("the two camera centres coincide: a stereo pair needs a baseline > 0")
    x_axis = baseline_w / baseline_m
    if x_axis @ R1[0] <= 0:
        raise PrismapInputError(
            "the right camera's centre must lie on the +x side of the left camera; got C' - C = "
            f"{baseline_w.tolist()} (world) against the left x axis {R1[0].tolist()}: swap the cameras"
        )
    z_mean = R1[2] + R2[2]
    y_axis = np.cross(z_mean, x_axis)
    y_axis /= np.linalg.norm(y_axis)
    z_axis = np.cross(x_axis, y_axis)
    Rn = np.stack([x_axis, y_axis, z_axis])
    K_mean = 0.5 * (K1 + K2)
    focal = 0.5 * (K_mean[0, 0] + K_mean[1, 1])
    camera = StereoCamera(focal, K_mean[0, 2], K_mean[1, 2], baseline_m, width=width, height=height)
    Kn = camera.K
    H_left = Kn @ Rn @ R1.T @ np.linalg.inv(K1)
    H_right = Kn @ Rn @ R2.T @ np.linalg.inv(K2)
    T_world_cam = np.eye(4)
    T_world_cam[:3, :3] = Rn.T
    T_world_cam[:3, 3] = C1
    return Rectification(camera=camera, H_left=H_left, H_right=H_right, T_world_cam=T_world_cam)


def warp_pair(
    left: np.ndarray, right: np.ndarray, rectification: Rectification, *, interpolation: int = cv2.INTER_LINEAR
) -> tuple[np.ndarray, np.ndarray]:
    """Resample an original image pair into the rectified views (``cv2.warpPerspective``).

    Parameters
    ----------
    left, right : (H, W) or (H, W, 3) array
        Original images of the left and right cameras.
    rectification : Rectification
        From :func:`rectify_stereo`; its camera's ``width`` and ``height`` set the output size
        (default: the input size).
    interpolation : int
        OpenCV interpolation flag.

    Returns
    -------
    left_rect, right_rect : arrays of the input dtype, pixels outside the originals are 0.
    """
    images = []
    for name, image, H in (("left", left, rectification.H_left), ("right", right, rectification.H_right)):
        image = np.asarray(image)
        if image.ndim not in (2, 3):
            raise PrismapInputError(f"`{name}` must be an (H, W) or (H, W, C) image; got shape {image.shape}")
        camera = rectification.camera
        size = (camera.width or image.shape[1], camera.height or image.shape[0])
        images.append(cv2.warpPerspective(image, H, size, flags=interpolation, borderMode=cv2.BORDER_CONSTANT))
    return tuple(images)


def _intrinsics(K, name):
    K = as_float_array(K, name, shape=(3, 3), allow_nan=False)
    if not (K[0, 0] > 0 and K[1, 1] > 0 and np.allclose(K[1, 0], 0) and np.allclose(K[2], [0, 0, 1])):
        raise PrismapInputError(f"`{name}` must be [fx s cx; 0 fy cy; 0 0 1] with fx, fy > 0; got {K.tolist()}")
    return K


def _pose(T, name):
    T = as_float_array(T, name, shape=(4, 4), allow_nan=False)
    R = T[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) <= 0:
        raise PrismapInputError(f"`{name}` must hold a rotation in its top-left 3x3 block; got {R.tolist()}")
    return R.T, T[:3, 3].copy()
