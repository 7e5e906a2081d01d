"""Readers and converters of raw datasets (KITTI raw, Waymo, VISTA) to XVIZ."""
