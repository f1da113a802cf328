"""Stereo camera geometry: intrinsics, disparity <-> depth, rays, triangulation, rectification."""

from prismap.camera._stereo_camera import StereoCamera

__all__ = ["StereoCamera"]
