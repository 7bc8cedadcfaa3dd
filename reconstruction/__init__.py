"""Reconstruction: camera calibration, marker detection, correspondence, triangulation, tracking.

Pure functions over arrays and images: no files, ports or clocks.
"""
