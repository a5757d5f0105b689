"""strain_comp: calibrated strain from the resistance of soft strain sensors.

The core (models, fitting, direction detection, bag I/O, evaluation, diagnosis) imports no
ROS module; ``strain_comp.ros.node`` is a thin rclpy layer over ``strain_comp.core.engine``.
Contracts (layout, topics, units, files, command line): docs/design.md; the papers the
docstrings cite by key and equation number: docs/references.md.
"""

__version__ = "0.1.0"
