"""What a calibration leaves behind: calibration.yaml, the report, the resolved recipe."""
