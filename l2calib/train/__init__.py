"""PPO training of the calibration policy (TorchRL)."""
