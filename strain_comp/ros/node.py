"""The ``compensator`` executable: spins the rclpy node; start-up problems are one line and
exit 2, SIGINT/SIGTERM exit 0 at any moment (docs/ros.md). Only the standard library is
imported at module level, so the signal handlers are in place before anything slow."""

from __future__ import annotations

import os
import signal
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from types import FrameType
from typing import NoReturn

NODE_NAME = "compensator"
SHUTDOWN_S = 1.5
"""Longest clean shutdown after SIGINT/SIGTERM before the process exits regardless [s]."""
EXIT_BAD_INPUT = 2
_stopped_by: list[str] = []


def _exit_now(signum: int, frame: FrameType | None) -> None:
    os._exit(0)


def _stopped_in_start_up(signum: int, frame: FrameType | None = None) -> NoReturn:
    """SIGINT/SIGTERM before the node is up: one line, exit 0 (no traceback)."""
    os.write(2, f"{NODE_NAME}: {signal.Signals(signum).name}: stopped during start-up\n"
             .encode())
    os._exit(0)


def _request_stop(signum: int, frame: FrameType | None) -> None:
    _stopped_by.append(signal.Signals(signum).name)
    watchdog = threading.Timer(SHUTDOWN_S, os._exit, args=(0,))
    watchdog.daemon = True
    watchdog.start()


def _ros_flags(args: list[str], flags: tuple[str, ...]) -> Iterator[tuple[str, str]]:
    """(flag, its value) for each of ``flags`` in the ``--ros-args`` part of ``args``."""
    inside = False
    it = iter(args)
    for arg in it:
        if arg == "--ros-args":
            inside = True
        elif arg == "--":
            inside = False
        elif inside and arg in flags:
            yield arg, next(it, "")


def _unqualified(key: str) -> str:
    """A rule's key without its ``node:`` prefix (``name:key`` -> ``key``)."""
    return key.split(":", 1)[-1] if key.count(":") == 1 else key


def ros_arguments(args: list[str]) -> tuple[list[Path], str, str, dict[str, str]]:
    """The ``--ros-args`` part: params files, node name, namespace, ``-p`` rules by name."""
    files: list[Path] = []
    name, namespace = NODE_NAME, "/"
    rules: dict[str, str] = {}
    for flag, value in _ros_flags(args, ("--params-file", "-r", "--remap", "-p", "--param")):
        if flag == "--params-file":
            files.append(Path(value))
        elif flag in ("-p", "--param"):
            rules[_unqualified(value.partition(":=")[0])] = value
        elif ":=" in value:
            key, target = value.split(":=", 1)
            key = _unqualified(key)
            if key == "__node" or key == "__name":
                name = target
            elif key == "__ns":
                namespace = target
    return files, name, namespace, rules


def main(args: list[str] | None = None) -> int:
    """``compensator``: spin the node until SIGINT/SIGTERM or shutdown, then exit 0."""
    signal.signal(signal.SIGINT, _stopped_in_start_up)
    signal.signal(signal.SIGTERM, _stopped_in_start_up)
    argv = list(sys.argv if args is None else args)
    # rclpy's own argument and parameter-file errors (RCLError is a RuntimeError), and what
    # reading a params file can raise
    start_errors: tuple[type[Exception], ...] = (RuntimeError, ValueError, TypeError, OSError)
    try:
        from strain_comp.errors import StrainCompError
        from strain_comp.ros.params import read_params

        files, name, namespace, rules = ros_arguments(argv)
        base_dir = read_params(files, name, namespace)[1]
        import rclpy
        from rclpy.exceptions import ParameterException
        from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
        from rclpy.experimental.events_executor import EventsExecutor
        from rclpy.signals import SignalHandlerOptions
        from rclpy.utilities import ok, try_shutdown

        from strain_comp.ros.compensator import CompensatorNode
        from strain_comp.ros.rclpy_typed import destroy, logger

        start_errors = (*start_errors, ParameterException)

        rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
        node = CompensatorNode(name, base_dir=base_dir)
    except StrainCompError as err:
        given = rules.get(getattr(err, "field", ""))
        if given is not None:  # -p wins over the params files: the command line is at fault
            where = f"command line (-p {given}): "
        elif files and not str(err).startswith(str(files[-1])):
            where = f"{files[-1]}: "
        else:
            where = ""
        print(f"{NODE_NAME}: {where}" + " ".join(str(err).split()), file=sys.stderr)
        return EXIT_BAD_INPUT
    except start_errors as err:
        print(f"{NODE_NAME}: cannot start: " + " ".join(str(err).split()[:40]), file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:  # a library put Python's default SIGINT handler back
        _stopped_in_start_up(signal.SIGINT)
    signal.signal(signal.SIGINT, _request_stop)
    signal.signal(signal.SIGTERM, _request_stop)
    # only now: a SIGINT after the ready line gets the running node's clean shutdown
    logger(node).info(node.ready_line)
    # rclpy 7.1.6's EventsExecutor loses inputs under use_sim_time (docs/ros.md)
    sim_time = node.get_parameter("use_sim_time").value
    executor = (EventsExecutor() if node.live.params.executor == "events" and not sim_time
                else SingleThreadedExecutor())
    executor.add_node(node)
    try:
        while not _stopped_by and ok():
            executor.spin_once(timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if _stopped_by:
            logger(node).info(f"{_stopped_by[0]}: stopped")
        signal.signal(signal.SIGINT, _exit_now)
        signal.signal(signal.SIGTERM, _exit_now)
        executor.shutdown(timeout_sec=0.5)
        destroy(node)
        try_shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)  # the interpreter's own teardown of the DDS library can take over a second


def prime_cache(config: str) -> list[str]:
    """Compile the kernels of the params files in ``config`` into numba's cache (setup.py)."""
    from strain_comp.ros.live import LiveCompensator
    from strain_comp.ros.params import load_params

    primed = []
    for path in sorted(Path(config).glob("*_params.yaml")):
        LiveCompensator(load_params(path))
        primed.append(path.name)
    return primed


if __name__ == "__main__":
    sys.exit(main())
