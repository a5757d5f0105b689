"""``strain-comp play``: a bag's messages published over ROS 2 at their recorded times
(docs/ros.md)."""

from __future__ import annotations

import argparse

from strain_comp.cli.common import bag, note, require_ros

NAME = "play"
SUMMARY = "publish a bag's messages over ROS 2 (ros2 bag play where ROS is installed)"
DESCRIPTION = ("Publish a bag's messages at their recorded times, for machines without "
               "rosbag2 (needs the ros extra).")
EXAMPLE = "strain-comp play bags/demo_rates.mcap --clock --rate 2"


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The bag, the clock, the rate, the topics, the lockstep topic."""
    p.add_argument("bag", metavar="BAG.mcap", help="bag to play")
    p.add_argument("--clock", action="store_true",
                   help="publish /clock with each message's log time (for use_sim_time)")
    p.add_argument("--rate", type=float, default=1.0, metavar="X",
                   help="speed factor (default 1; 0: as fast as possible)")
    p.add_argument("--topic", action="append", metavar="TOPIC",
                   help="play only this topic (repeatable; default all)")
    p.add_argument("--lockstep", metavar="TOPIC",
                   help="after each message wait for one message on TOPIC (the node's answer)")


def run(args: argparse.Namespace) -> int:
    """The bag played; how many messages on stderr."""
    bag(args.bag)
    require_ros("strain-comp play")
    from strain_comp.ros.player import main as play_main

    n = play_main(args.bag, clock=args.clock, rate=args.rate, topics=args.topic,
                  lockstep=args.lockstep)
    note(args, f"played {n} messages")
    return 0
