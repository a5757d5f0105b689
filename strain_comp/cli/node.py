"""``strain-comp node``: the rclpy compensator node, as ``ros2 run`` starts it
(docs/ros.md)."""

from __future__ import annotations

import argparse

from strain_comp.cli.common import require_ros
from strain_comp.io.inputs import existing

NAME = "node"
SUMMARY = "run the rclpy compensator node (as `ros2 run` does)"
DESCRIPTION = ("The live node (needs the ros extra: pip install '.[ros]'): "
               "/NAME/resistance in, /NAME/strain, /NAME/direction and /diagnostics out "
               "(docs/ros.md).")
EXAMPLE = "strain-comp node --params config/compensator_params.yaml"


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The node's parameter file."""
    p.add_argument("--params", required=True, metavar="FILE",
                   help="node parameter YAML (sensors, calibrations, tunables)")


def run(args: argparse.Namespace) -> int:
    """The node run until it is stopped; its exit code (0, 2 or 130)."""
    existing(args.params, "parameter file")
    require_ros("strain-comp node")
    from strain_comp.ros.node import main as node_main

    code = node_main(["--ros-args", "--params-file", str(args.params)])
    return code if code in (0, 2, 130) else 2
