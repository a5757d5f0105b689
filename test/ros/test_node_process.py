"""The node as a robot runs it: colcon-built into a temporary workspace, its installed
``compensator`` executable started with a params file, a second process playing a bag
(``strain-comp play``), this process recording the outputs; start-up errors and signals.

Under sim time the bag is played with ``--clock --lockstep /s1/strain`` (a tick before each
input, the next input after the answer): every strain must equal ``strain-comp replay``'s
(1e-9). Without sim time the node stamps inputs with the wall clock, so the bag is played at
4x speed (100 messages/s) through a memoryless (cubic) calibration, whose strain does not
depend on the stamps: again every strain must equal replay's.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from ros_env import copy_package, ros_env, use_ros_env, wait_for

ROS_SLOT = 2
ENV = use_ros_env(ROS_SLOT)

import rclpy  # noqa: E402  (after the environment is set; never skipped)
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from std_msgs.msg import Float64  # noqa: E402

from strain_comp.cli import main as cli_main  # noqa: E402
from strain_comp.core.calibration import Calibration  # noqa: E402
from strain_comp.core.calibration_file import load_calibration, save_calibration  # noqa: E402
from strain_comp.io.bag import read_bag  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
N_MESSAGES = 1500
N_WALL = 300


@pytest.fixture(scope="module")
def workspace(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    """One colcon build of this package into a temporary workspace."""
    ws = tmp_path_factory.mktemp("ws")
    src = ws / "src" / "strain_comp"
    copy_package(src)
    colcon = Path(sys.executable).parent / "colcon"
    done = subprocess.run(
        [str(colcon), "build", "--packages-select", "strain_comp", "--base-paths", str(ws / "src"),
         "--build-base", str(ws / "build"), "--install-base", str(ws / "install")],
        cwd=ws, capture_output=True, text=True, timeout=300,
        env={**os.environ, "PATH": f"{colcon.parent}:{os.environ['PATH']}"})
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    prefix = ws / "install" / "strain_comp"
    site = next(prefix.glob("lib/python3*/site-packages"))
    env = {**os.environ, **ros_env(2), "PYTHONPATH": str(site),
           "AMENT_PREFIX_PATH": str(prefix), "PYTHONUNBUFFERED": "1"}
    yield {"ws": ws, "exe": prefix / "lib" / "strain_comp" / "compensator",
           "share": prefix / "share" / "strain_comp", "env": env}


@pytest.fixture(scope="module")
def recorder() -> Iterator[Any]:
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node("recorder", context=ctx)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    yield node, executor
    executor.shutdown(timeout_sec=1.0)
    node.destroy_node()
    rclpy.try_shutdown(context=ctx)


def short_bag(path: Path, n: int, topics: tuple[str, ...] = ("/s1/resistance",),
              rename: dict[str, str] | None = None) -> Path:
    """The first ``n`` messages on ``topics`` of bags/demo_rates.mcap, as recorded (a topic
    written under its name in ``rename``, where it has one)."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with open(ROOT / "bags/demo_rates.mcap", "rb") as src, open(path, "wb") as dst:
        writer = Writer(dst)
        writer.start("ros2", "strain_comp test")
        channels: dict[int, int] = {}
        for k, (schema, channel, message) in enumerate(
                make_reader(src).iter_messages(topics=list(topics), log_time_order=True)):
            if k == n:
                break
            if channel.id not in channels:
                sid = writer.register_schema(schema.name, schema.encoding, schema.data)
                channels[channel.id] = writer.register_channel(
                    (rename or {}).get(channel.topic, channel.topic), channel.message_encoding,
                    sid)
            writer.add_message(channels[channel.id], message.log_time, message.data,
                               message.publish_time)
        writer.finish()
    return path


def replay_strain(bag: Path, calibration: Path, out: Path) -> np.ndarray:
    assert cli_main(["replay", str(bag), "--calibration", str(calibration), "--out",
                     str(out)]) == 0
    return np.asarray(read_bag(out).series["/s1/strain"].values, dtype=float).reshape(-1)


def start(cmd: list[str], env: dict[str, str], log: Path, cwd: Path | None = None
          ) -> subprocess.Popen[str]:
    with open(log, "w") as stream:
        return subprocess.Popen(cmd, env=env, stdout=stream, stderr=subprocess.STDOUT,
                                text=True, cwd=cwd)


def stop(proc: subprocess.Popen[str], sig: int = signal.SIGINT) -> tuple[int, float]:
    """Send ``sig``; (exit code, seconds until the process ended)."""
    t0 = time.monotonic()
    proc.send_signal(sig)
    try:
        code = proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        code = proc.wait()
    return code, time.monotonic() - t0


def player(bag: Path, log: Path, *options: str) -> subprocess.Popen[str]:
    env = {**os.environ, **ENV, "PYTHONPATH": str(ROOT)}
    return start([sys.executable, "-m", "strain_comp.cli", "play", str(bag), *options], env, log)


def record(recorder: Any, play_args: tuple[Any, ...], timeout: float,
           diagnostics: list[Any] | None = None) -> list[float]:
    """Subscribe to /s1/strain (and /diagnostics into ``diagnostics``), start the player
    once matched, record until it ends."""
    from diagnostic_msgs.msg import DiagnosticArray

    node, executor = recorder
    got: list[float] = []
    sub = node.create_subscription(Float64, "/s1/strain", lambda m: got.append(m.data), 1000)
    diag = None if diagnostics is None else node.create_subscription(
        DiagnosticArray, "/diagnostics", diagnostics.append, 100)
    deadline = time.monotonic() + timeout
    try:
        while sub.get_publisher_count() == 0 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        play = player(*play_args)
        while play.poll() is None and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
        assert play.wait(timeout=10) == 0, play_args[1].read_text()
    finally:
        node.destroy_subscription(sub)
        if diag is not None:
            node.destroy_subscription(diag)
    return got


def aligned(got: list[float], truth: np.ndarray) -> int:
    """How many received values equal (1e-9) replay's value of their input, in order; an
    input without an answer is skipped."""
    j, n = 0, 0
    for value in got:
        while j < truth.size and abs(truth[j] - value) > 1e-9:
            j += 1
        if j < truth.size:
            n, j = n + 1, j + 1
    return n


def run_node(workspace: dict[str, Any], params: Path, log: Path, *extra: str
             ) -> subprocess.Popen[str]:
    proc = start([str(workspace["exe"]), "--ros-args", "--params-file", str(params), *extra],
                 workspace["env"], log)
    wait_for(log, "ready:", proc)
    return proc


def test_a_fresh_colcon_install_starts_without_compiling(workspace: dict[str, Any],
                                                        tmp_path: Path) -> None:
    """colcon's install compiles the kernels of the bundled params files into the installed
    package's numba cache (setup.py, ``prime_cache``): the first start of the install loads
    every kernel and compiles none (it compiled into an empty cache, 9 s idle, a minute on a
    loaded machine: docs/results.md). First in this module: no node started before."""
    site = Path(workspace["env"]["PYTHONPATH"])
    assert list(site.glob("strain_comp/models/__pycache__/apl_kernels.*.nbi"))
    log = tmp_path / "node.log"
    proc = start([str(workspace["exe"]), "--ros-args", "--params-file",
                  str(workspace["share"] / "config/compensator_params.yaml")],
                 {**workspace["env"], "NUMBA_DEBUG_CACHE": "1"}, log)
    wait_for(log, "ready:", proc)
    code, _ = stop(proc)
    text = log.read_text()
    assert code == 0 and "[cache] data loaded" in text and "[cache] data saved" not in text


def test_sim_time_play_equals_replay(workspace: dict[str, Any], recorder: Any,
                                     tmp_path: Path) -> None:
    bag = short_bag(tmp_path / "short.mcap", N_MESSAGES)
    truth = replay_strain(bag, ROOT / "config/demo_calibration.yaml", tmp_path / "replay.mcap")
    node = run_node(workspace, workspace["share"] / "config/compensator_params.yaml",
                    tmp_path / "node.log", "-p", "use_sim_time:=true")
    got = record(recorder, (bag, tmp_path / "play.log", "--clock", "--lockstep", "/s1/strain"),
                 120.0)
    code, seconds = stop(node)
    assert code == 0 and seconds < 2.0 and "Traceback" not in (tmp_path / "node.log").read_text()
    assert len(got) >= 0.99 * N_MESSAGES
    assert aligned(got, truth) == len(got)


def test_play_plays_the_topics_with_a_subscriber_and_names_the_others(
        workspace: dict[str, Any], recorder: Any, tmp_path: Path) -> None:
    """A bag with s1's resistance and a sensor s9 the default node does not know, played
    with --clock into the node under sim time: the resistance is played and answered,
    /diagnostics come under sim time, and one line names the topic without a subscriber and
    --topic (play waited for a subscriber on every topic and failed after 10 s: 0 strains)."""
    bag = short_bag(tmp_path / "both.mcap", 2 * N_WALL,
                    ("/s1/resistance", "/s1/strain_reference"),
                    {"/s1/strain_reference": "/s9/resistance"})
    node = run_node(workspace, workspace["share"] / "config/compensator_params.yaml",
                    tmp_path / "node.log", "-p", "use_sim_time:=true")
    diagnostics: list[Any] = []
    got = record(recorder, (bag, tmp_path / "play.log", "--clock", "--rate", "4"), 60.0,
                 diagnostics)
    code, _ = stop(node)
    assert code == 0
    assert len(got) >= 0.5 * N_WALL and diagnostics, (len(got), len(diagnostics))
    assert tmp_path.joinpath("play.log").read_text().splitlines() == [
        f"play: no subscriber on /s9/resistance: {N_WALL} messages not played "
        "(--topic TOPIC chooses the topics to play)", f"played {N_WALL} messages"]


def test_wall_clock_play_at_speed_equals_replay_for_a_memoryless_model(
        workspace: dict[str, Any], recorder: Any, tmp_path: Path) -> None:
    cal = load_calibration(ROOT / "config/demo_calibration.yaml").sensors["s1"]
    cubic = replace(cal, model="cubic", params={"c": [-40.0, 2.5, 0.0, 0.0]})
    save_calibration(Calibration({"s1": cubic}), tmp_path / "cubic.yaml")
    params = tmp_path / "params.yaml"
    params.write_text("/**/compensator:\n  ros__parameters:\n    sensors: [s1]\n"
                      "    s1: {calibration: cubic.yaml}\n    stale_after_s: 2\n")
    bag = short_bag(tmp_path / "short.mcap", N_WALL)
    truth = replay_strain(bag, tmp_path / "cubic.yaml", tmp_path / "replay.mcap")
    node = run_node(workspace, params, tmp_path / "node.log")
    got = record(recorder, (bag, tmp_path / "play.log", "--rate", "4"), 60.0)
    code, seconds = stop(node, signal.SIGTERM)
    assert code == 0 and seconds < 2.0
    # inputs are best effort (sensor-data QoS): a busy machine may drop some at speed; how
    # many get through is bench_node_throughput.py's figure, here every answer must be
    # replay's value for its input
    assert len(got) >= 0.5 * N_WALL, (len(got), aligned(got, truth))
    assert aligned(got, truth) == len(got)


def test_sigint_under_load_and_during_start_up(workspace: dict[str, Any],
                                               tmp_path: Path) -> None:
    node = run_node(workspace, workspace["share"] / "config/compensator_params.yaml",
                    tmp_path / "node.log")
    play = player(ROOT / "bags/demo_rates.mcap", tmp_path / "play.log", "--rate", "0",
                  "--topic", "/s1/resistance")
    time.sleep(3.0)  # the node busy with inputs as fast as they come
    code, seconds = stop(node)
    stop(play)
    assert code == 0 and seconds < 2.0
    assert "Traceback" not in (tmp_path / "node.log").read_text()
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2)]
    try:  # both cores kept busy: start-up stretched, every moment of it hit
        for delay in (0.0, 0.1, 0.2, 0.3, 0.5, 0.7, 1.0, 1.5):
            log = tmp_path / f"early{delay}.log"
            proc = start([str(workspace["exe"]), "--ros-args", "--params-file",
                          str(workspace["share"] / "config/compensator_params.yaml")],
                         workspace["env"], log)
            # once main has installed its handlers: exit 0, one line, no traceback (before
            # that, in the interpreter's start and the console-script wrapper, the signal is
            # Python's: docs/ros.md)
            wait_for_handlers(proc)
            time.sleep(delay)
            code, seconds = stop(proc)
            assert seconds < 2.0
            lines = log.read_text().splitlines()
            assert code == 0 and len(lines) in (1, 2), lines
            assert (lines[-1] == "compensator: SIGINT: stopped during start-up"
                    or lines[-1].endswith("[compensator]: SIGINT: stopped")), lines
            # the ready line comes after the running node's handlers: once it is logged, a
            # SIGINT gets the clean shutdown
            assert "ready:" not in lines[0] or lines[-1].endswith("SIGINT: stopped"), lines
    finally:
        for proc in busy:
            proc.kill()
            proc.wait()


def wait_for_handlers(proc: subprocess.Popen[str], timeout: float = 30.0) -> None:
    """Until ``proc`` catches SIGTERM (Linux's /proc/PID/status ``SigCgt``): the node's
    main installs its SIGINT and SIGTERM handlers first thing, and Python catches SIGTERM
    only when told to, so this is the moment main started, however loaded the machine."""
    deadline = time.monotonic() + timeout
    while True:
        status = Path(f"/proc/{proc.pid}/status").read_text()
        caught = int(next(line.split()[1] for line in status.splitlines()
                          if line.startswith("SigCgt:")), 16)
        if caught >> (signal.SIGTERM - 1) & 1:
            return
        assert proc.poll() is None and time.monotonic() < deadline
        time.sleep(0.01)


BASE = "/**/compensator:\n  ros__parameters:\n    sensors: [s1]\n"


@pytest.mark.parametrize(("body", "args", "expected"), [
    (None, [], "missing.yaml: cannot read params file"),
    ("/**/compensator: [\n", [], "not a YAML params file"),
    (BASE + "    s1: {calibration: nowhere.yaml}\n", [], "nowhere.yaml"),
    (BASE + "    s1: {calibration: demo_calibration.yaml}\n    deadzone_scale: -5.0\n", [],
     "deadzone_scale: must be in [0.01, 100.0], got -5.0"),
    (BASE + "    s1: {calibration: demo_calibration.yaml}\n    stale_afer_s: 1.0\n", [],
     "stale_afer_s: unknown parameter; did you mean 'stale_after_s'?"),
    (BASE + "    s1: {calibration: demo_calibration.yaml}\n", ["-r", "__node:=left_hand"],
     "no parameters for node '/left_hand' (the file holds: **/compensator)"),
])
def test_start_up_errors_are_one_line(workspace: dict[str, Any], tmp_path: Path,
                                      body: str | None, args: list[str], expected: str) -> None:
    params = tmp_path / ("missing.yaml" if body is None else "params.yaml")
    if body is not None:
        params.write_text(body)
    done = subprocess.run([str(workspace["exe"]), "--ros-args", "--params-file", str(params),
                           *args], env=workspace["env"], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 2
    lines = (done.stdout + done.stderr).strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("compensator: ") and expected in lines[0], lines


def test_cli_node_resolves_calibration_beside_its_params_file(tmp_path: Path) -> None:
    """The calibration beside the params file is found; its ready line states the error the
    calibration expects on a new session (``fit --model auto``'s ``expected_error``)."""
    import strain_comp as sc
    from strain_comp.core.calibration import expected_words

    folder = tmp_path / "robot"
    folder.mkdir()
    cal = sc.load_calibration(ROOT / "config/demo_calibration.yaml")
    cal.sensors["s1"].provenance["expected_error"] = {"median": 4.77, "worst": 6.77,
                                                      "runs": 7, "unit": "%", "model": "apl"}
    sc.save_calibration(cal, folder / "my_cal.yaml")
    (folder / "p.yaml").write_text(BASE + "    s1: {calibration: my_cal.yaml}\n")
    env = {**os.environ, **ENV, "PYTHONPATH": str(ROOT)}
    log = tmp_path / "node.log"
    proc = start([sys.executable, "-m", "strain_comp.cli", "node", "--params",
                  str(folder / "p.yaml")], env, log, cwd=tmp_path)
    wait_for(log, "ready:", proc)
    code, seconds = stop(proc)
    assert code == 0 and seconds < 2.0
    words = expected_words(sc.load_calibration(folder / "my_cal.yaml").sensors["s1"])
    assert words is not None and "RMSE 4.77 % strain (median)" in words
    assert f"s1 [s1] (apl, {words})" in log.read_text()


def test_a_bad_command_line_value_names_the_command_line(workspace: dict[str, Any],
                                                         tmp_path: Path) -> None:
    done = subprocess.run(
        [str(workspace["exe"]), "--ros-args", "--params-file",
         str(workspace["share"] / "config/compensator_params.yaml"), "-p",
         "deadzone_scale:=-5.0"], env=workspace["env"], capture_output=True, text=True,
        timeout=60)
    assert done.returncode == 2
    assert (done.stdout + done.stderr).strip() == (
        "compensator: command line (-p deadzone_scale:=-5.0): deadzone_scale: must be in "
        "[0.01, 100.0], got -5.0")
