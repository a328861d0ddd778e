"""Reference trajectories for calibration: LiDAR-only odometry runners and loaders."""
