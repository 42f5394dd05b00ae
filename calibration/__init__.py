"""Stereo calibration, rectification and LiDAR-to-disparity projection."""
