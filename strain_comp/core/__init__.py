"""The ROS-free core: calibration files, sample screening, the engine, direction, effects."""
