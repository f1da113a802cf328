"""Stereo camera geometry: intrinsics, disparity <-> depth, rays, triangulation, rectification."""

from prismap.camera._rectify import Rectification, rectify_stereo, warp_pair
from prismap.camera._stereo_camera import StereoCamera

__all__ = ["Rectification", "StereoCamera", "rectify_stereo", "warp_pair"]
