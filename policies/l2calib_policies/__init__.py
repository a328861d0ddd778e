"""Policies for l2calib (entry-point group ``l2calib.policies``)."""
