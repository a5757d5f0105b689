"""The residual loop: find what a calibration lacks on measured data, add it, report it."""
