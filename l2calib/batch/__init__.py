"""Many calibrations in one batch (``l2calib batch MANIFEST.yaml``), locally or on Ray."""
