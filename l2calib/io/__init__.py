"""Readers and writers: trajectory files (TUM, KITTI, CSV) and, later, bags."""
