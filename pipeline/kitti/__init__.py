"""Readers and writers of KITTI's file formats (calibrations, poses, times, Velodyne scans, 8-bit
images, 16-bit depth/disparity/flow PNGs) and of the KITTI-odometry folder layout; KITTI Scene Flow 2015's
disparity and flow maps turned into point pairs in HPLFlowNet's test layout (:mod:`pipeline.kitti.stereo_flow`).

Every reader raises :class:`core.errors.InputError` naming the file on bad input.
"""

from pipeline.kitti.calib import (
    ObjectCalib,
    OdometryCalib,
    RawCamToCam,
    read_object_calib,
    read_odometry_calib,
    read_raw_cam_to_cam,
    read_raw_imu_to_velo,
    read_raw_velo_to_cam,
    write_odometry_calib,
)
from pipeline.kitti.images import image_size, read_image, write_image
from pipeline.kitti.odometry import OdometrySequence, find_sequences
from pipeline.kitti.png16 import (
    disparity_to_depth,
    read_depth_png,
    read_disparity_png,
    read_flow_png,
    write_depth_png,
    write_disparity_png,
    write_flow_png,
)
from pipeline.kitti.poses import read_poses, read_times, write_poses, write_times
from pipeline.kitti.velodyne import read_velodyne_bin, write_velodyne_bin

__all__ = [
    "ObjectCalib",
    "OdometryCalib",
    "OdometrySequence",
    "RawCamToCam",
    "disparity_to_depth",
    "find_sequences",
    "image_size",
    "read_depth_png",
    "read_disparity_png",
    "read_flow_png",
    "read_image",
    "read_object_calib",
    "read_odometry_calib",
    "read_poses",
    "read_raw_cam_to_cam",
    "read_raw_imu_to_velo",
    "read_raw_velo_to_cam",
    "read_times",
    "read_velodyne_bin",
    "write_depth_png",
    "write_disparity_png",
    "write_flow_png",
    "write_image",
    "write_odometry_calib",
    "write_poses",
    "write_times",
    "write_velodyne_bin",
]
