"""The ROS 2 layer: node parameters, the per-message live logic and the rclpy node; the
only subpackage that imports rclpy (lazily, in ``node``)."""
