"""The package as an operator meets it: ``colcon build``, then the real ``ros2`` command line.

The ``ros2`` command comes from a ROS 2 Jazzy installation (``ros2`` on PATH) or from the kit
``../shared/ros2cli`` built into ``.venv-ros2`` by ``scripts/ros2_venv.sh`` (Python 3.12,
Jazzy's; CI builds it). One ``colcon build`` per session (with that environment's setuptools,
>= 76 in the kit), one more with Ubuntu 24.04's setuptools 68 for ``ros2 run`` (the numba
cache the first primed copied into it, not compiled again). Then:
``ros2 run`` (both builds, and the ``strain-comp`` tools), ``ros2 param get|set|describe|dump``
(every refusal printed as docs/ros.md quotes it; a dumped file restarts the node),
``ros2 topic pub|echo|hz`` (the strain equals the engine's for the published resistance; the
stamped twin carries the node clock's time), ``ros2 service call`` (``~/tare``,
``~/reload_calibration``), ``ros2 launch`` with every launch argument, and Ctrl-C (SIGINT: one
log line, exit 0, no traceback). Discovery stays on this machine, a domain id per test.
Without ROS and without the kit these tests skip with one reason; under CI=true they fail.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import signal
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import pytest
import yaml
from ros_env import copy_package, ros_env, wait_for

from strain_comp.core.calibration import Calibration
from strain_comp.core.calibration_file import load_calibration, save_calibration
from strain_comp.core.engine import Engine

ROOT = Path(__file__).resolve().parents[2]
VENV = Path(os.environ.get("STRAIN_COMP_ROS2_VENV", ROOT / ".venv-ros2"))
DOCS = ROOT / "docs" / "ros.md"
CUBIC = [-40.0, 2.5, 0.0, 0.0]
"""A memoryless calibration: the strain of a resistance depends on nothing else."""


def _sourced(script: str, env: dict[str, str]) -> dict[str, str]:
    """The environment after ``source script`` (bash), as a dict."""
    done = subprocess.run(["bash", "-c", f'set +u; source "{script}" >/dev/null && env -0'],
                          env=env, capture_output=True, timeout=120, check=True)
    return dict(line.split("=", 1) for line in done.stdout.decode().split("\0") if "=" in line)


def ros2_environment() -> dict[str, str] | None:
    """An environment with ``ros2`` and colcon: the kit venv, else a sourced ROS, else None."""
    env = dict(os.environ)
    if (VENV / "bin" / "ros2").exists():
        env.update(VIRTUAL_ENV=str(VENV), PATH=f"{VENV / 'bin'}:{env['PATH']}")
        env.pop("PYTHONHOME", None)
        return _sourced(str(VENV / "setup.bash"), env)
    if shutil.which("ros2") and shutil.which("colcon"):
        return env
    return None


@dataclass
class Workspace:
    """A colcon workspace holding the built package, and how to run commands in it."""

    root: Path
    env: dict[str, str]

    @property
    def share(self) -> Path:
        return self.root / "install" / "strain_comp" / "share" / "strain_comp"

    def run(self, *cmd: str, slot: int, timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
        return subprocess.run(cmd, env={**self.env, **ros_env(slot)}, capture_output=True,
                              text=True, timeout=timeout, cwd=self.root)

    def start(self, *cmd: str, slot: int, log: Path) -> subprocess.Popen[str]:
        """A process in a session (process group) of its own, killed after the test."""
        with open(log, "w") as stream:
            proc = subprocess.Popen(cmd, env={**self.env, **ros_env(slot)}, stdout=stream,
                                    stderr=subprocess.STDOUT, text=True, cwd=self.root,
                                    start_new_session=True)
        STARTED.append(proc)
        return proc


STARTED: list[subprocess.Popen[str]] = []


@pytest.fixture(autouse=True)
def no_leftovers() -> Iterator[None]:
    """A test that fails half-way leaves no node or tool running: every process group it
    started is killed, also when its leader has ended (``ros2 launch`` gone, its node
    still running)."""
    yield
    while STARTED:
        proc = STARTED.pop()
        with contextlib.suppress(ProcessLookupError):  # the whole group ended meanwhile
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def build(root: Path, env: dict[str, str]) -> Workspace:
    """``colcon build`` of this package in ``root``; the workspace with its setup sourced."""
    src = root / "src" / "strain_comp"
    copy_package(src)
    done = subprocess.run(["colcon", "build", "--packages-select", "strain_comp"], cwd=root,
                          env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return Workspace(root, {**_sourced(str(root / "install" / "setup.bash"), env),
                            "PYTHONUNBUFFERED": "1"})


def copy_kernel_cache(source: Workspace, target: Workspace) -> None:
    """The numba cache that setup.py primed in ``source``'s install, into ``target``'s (the
    same sources and Python, built with ``STRAIN_COMP_NO_PRIME=1``): its node loads the
    kernels instead of compiling them a second time."""
    src, dst = (next(w.root.glob("install/strain_comp/lib/python3*/*-packages"))
                for w in (source, target))
    for path in src.rglob("__pycache__/*.nb[ci]"):
        (dst / path.relative_to(src)).parent.mkdir(exist_ok=True)
        shutil.copy2(path, dst / path.relative_to(src))


def setuptools_version(env: dict[str, str]) -> tuple[int, ...]:
    done = subprocess.run(["python3", "-c", "import setuptools; print(setuptools.__version__)"],
                          env=env, capture_output=True, text=True, timeout=60, check=True)
    return tuple(int(v) for v in done.stdout.strip().split(".")[:2])


ENV = ros2_environment()
if ENV is None and os.environ.get("CI") != "true":
    pytest.skip("no ROS 2 and no ros2cli kit: run scripts/ros2_venv.sh (needs "
                "../shared/ros2cli) or source a ROS 2 Jazzy installation",
                allow_module_level=True)


@pytest.fixture(scope="session")
def ros2_env() -> dict[str, str]:
    if ENV is None:  # under CI=true: the kit must be there
        pytest.fail("CI=true and no ros2 command: scripts/ros2_venv.sh did not build "
                    ".venv-ros2 (is ../shared/ros2cli beside the checkout?)")
    return ENV


@pytest.fixture(scope="session")
def ws(ros2_env: dict[str, str], tmp_path_factory: pytest.TempPathFactory) -> Iterator[Workspace]:
    """The one colcon build of the session; ros2 daemons started on its domains are stopped."""
    workspace = build(tmp_path_factory.mktemp("ros2ws"), ros2_env)
    yield workspace
    stopping = [subprocess.Popen(["ros2", "daemon", "stop"], env={**workspace.env, **ros_env(slot)},
                                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                for slot in SLOTS]
    for proc in stopping:
        proc.wait(timeout=30)


SLOTS = range(40, 46)
"""Test slots (ros_env domain ids) of this module."""


def ctrl_c(proc: subprocess.Popen[str], log: Path) -> list[str]:
    """SIGINT to the process group, as Ctrl-C in a terminal sends it; the lines printed
    after it. Exit 0 and no traceback."""
    before = len(log.read_text().splitlines())
    assert proc.poll() is None, f"ended by itself ({proc.returncode}): {log.read_text()}"
    os.killpg(proc.pid, signal.SIGINT)
    try:
        code = proc.wait(timeout=20)
    except subprocess.TimeoutExpired:
        proc.kill()
        raise
    text = log.read_text()
    assert code == 0 and "Traceback" not in text, text
    return text.splitlines()[before:]


def ros2(ws: Workspace, slot: int, *args: str) -> str:
    """A ``ros2`` command's output; asked again while discovery has not yet found the node
    ("Node not found": a freshly spawned ros2 daemon may not know it yet)."""
    deadline = time.monotonic() + 30.0
    while True:
        done = ws.run("ros2", *args, slot=slot)
        printed = (done.stdout + done.stderr).strip()
        if "Node not found" not in printed or time.monotonic() > deadline:
            return printed
        time.sleep(0.5)


def stop_tool(proc: subprocess.Popen[str]) -> None:
    """Ctrl-C to a ros2 tool (``ros2 topic hz`` exits 2 then: its own choice)."""
    os.killpg(proc.pid, signal.SIGINT)
    proc.wait(timeout=20)


def node_params(folder: Path, rest: float | None = None) -> Path:
    """A params file for sensor s1 on a cubic calibration (``rest``: its rest resistance)."""
    cal = load_calibration(ROOT / "config" / "demo_calibration.yaml").sensors["s1"]
    save_calibration(Calibration({"s1": replace(cal, model="cubic", params={"c": CUBIC},
                                                rest_resistance=rest)}),
                     folder / "cubic.yaml")
    (folder / "params.yaml").write_text(
        "/**/compensator:\n  ros__parameters:\n    sensors: [s1]\n"
        "    s1: {calibration: cubic.yaml}\n")
    return folder / "params.yaml"


def documented(line: str) -> None:
    """A message the ros2 command printed is quoted, verbatim, in docs/ros.md."""
    assert line in DOCS.read_text(), f"docs/ros.md does not quote: {line}"


@pytest.mark.parametrize("setuptools", ["environment", "68"])
def test_ros2_run_after_colcon_build(ws: Workspace, ros2_env: dict[str, str], setuptools: str,
                                     tmp_path: Path) -> None:
    """``ros2 run strain_comp compensator`` starts from a build with the environment's
    setuptools (>= 76 in the kit, whose ``scripts=`` shebang broke ros2 run) and with 68."""
    if setuptools == "environment":
        workspace = ws
        assert setuptools_version(ws.env) >= ((76, 0) if (VENV / "bin" / "ros2").exists()
                                              else (0, 0))
        done = ws.run("ros2", "run", "strain_comp", "strain-comp", "--help", slot=40)
        assert done.returncode == 0 and "replay" in done.stdout, done.stderr
    else:
        old = VENV / "setuptools68"
        if not old.is_dir():
            pytest.skip("no setuptools 68 beside the kit venv (scripts/ros2_venv.sh puts it)")
        env = {**ros2_env, "PYTHONPATH": f"{old}:{ros2_env.get('PYTHONPATH', '')}"}
        assert setuptools_version(env) == (68, 1)
        workspace = build(tmp_path / "ws68", {**env, "STRAIN_COMP_NO_PRIME": "1"})
        copy_kernel_cache(ws, workspace)
    log = tmp_path / "run.log"
    proc = workspace.start("ros2", "run", "strain_comp", "compensator", "--ros-args",
                           "--params-file", str(workspace.share / "config/compensator_params.yaml"),
                           slot=40, log=log)
    wait_for(log, "ready: 1 inputs: s1 [s1] (apl) /s1/resistance -> /s1/strain", proc)
    after = ctrl_c(proc, log)
    assert len(after) == 1 and after[0].endswith("[compensator]: SIGINT: stopped"), after


def test_ros2_param_get_set_describe_dump_and_restart(ws: Workspace, tmp_path: Path) -> None:
    params = node_params(tmp_path)
    log = tmp_path / "node.log"
    proc = ws.start("ros2", "run", "strain_comp", "compensator", "--ros-args", "--params-file",
                    str(params), slot=41, log=log)
    wait_for(log, "ready:", proc)

    def param(*args: str) -> str:
        return ros2(ws, 41, "param", *args)

    described = param("describe", "/compensator", "deadzone_scale")
    assert "Type: double" in described and "Min value: 0.01" in described
    assert param("set", "/compensator", "deadzone_scale", "2") == "Set parameter successful"
    refusals = {("deadzone_scale", "abc"): "Setting parameter failed: Wrong parameter type, "
                                           "expected 'Type.DOUBLE' got 'Type.STRING'",
                ("deadzone_scale", "500.0"): "Setting parameter failed: Parameter "
                                             "deadzone_scale out of range Min: 0.01, Max: "
                                             "100.0, value: 500.0",
                ("diagnostics_period_s", "2.0"): "Setting parameter failed: Trying to set a "
                                                 "read-only parameter: diagnostics_period_s.",
                ("use_sim_time", "true"): "Setting parameter failed: use_sim_time is fixed at "
                                          "start (params file or -p use_sim_time:=...); "
                                          "restart the node to change it"}
    for args, expected in refusals.items():
        printed = param("set", "/compensator", *args)
        assert printed == expected
        documented(printed)
    # still a double of the value set: no refusal changed its type or value
    assert param("get", "/compensator", "deadzone_scale") == "Double value is: 2.0"
    dump = tmp_path / "dumped.yaml"
    dump.write_text(param("dump", "/compensator"))
    assert yaml.safe_load(dump.read_text())["/compensator"]["ros__parameters"]["arrays"] == []
    ctrl_c(proc, log)

    log = tmp_path / "again.log"
    proc = ws.start("ros2", "run", "strain_comp", "compensator", "--ros-args", "--params-file",
                    str(dump), slot=41, log=log)
    wait_for(log, "ready:", proc)
    assert param("get", "/compensator", "deadzone_scale") == "Double value is: 2.0"
    ctrl_c(proc, log)


def echo_once(ws: Workspace, topic: str, kind: str, slot: int, log: Path
              ) -> subprocess.Popen[str]:
    return ws.start("ros2", "topic", "echo", "--once", topic, kind, slot=slot, log=log)


def test_ros2_topic_pub_echo_hz_and_service_call(ws: Workspace, tmp_path: Path) -> None:
    rest = 20.0
    params = node_params(tmp_path, rest=rest)
    log = tmp_path / "node.log"
    node = ws.start("ros2", "run", "strain_comp", "compensator", "--ros-args", "--params-file",
                    str(params), slot=42, log=log)
    wait_for(log, "ready:", node)
    refused = ws.run("ros2", "service", "call", "/compensator/tare", "std_srvs/srv/Trigger",
                     slot=42).stdout
    assert "success=False" in refused and "no good sample in the last 0.5 s" in refused

    echoes = {topic: (echo_once(ws, topic, kind, 42, tmp_path / f"{topic[4:]}.log"),
                      tmp_path / f"{topic[4:]}.log")
              for topic, kind in (("/s1/strain", "std_msgs/msg/Float64"),
                                  ("/s1/strain_stamped", "sensor_msgs/msg/JointState"))}
    hz_log = tmp_path / "hz.log"
    hz = ws.start("ros2", "topic", "hz", "/s1/strain", slot=42, log=hz_log)
    t0 = time.time()
    pub = ws.start("ros2", "topic", "pub", "-r", "20", "/s1/resistance", "std_msgs/msg/Float64",
                   "{data: 20.0}", slot=42, log=tmp_path / "pub.log")
    for proc, echo_log in echoes.values():
        assert proc.wait(timeout=60) == 0, echo_log.read_text()
    t1 = time.time()
    wait_for(hz_log, "average rate", hz)
    time.sleep(3.0)  # a few windows of the hz verb
    stop_tool(hz)
    rates = [float(v) for v in re.findall(r"average rate: ([0-9.]+)", hz_log.read_text())]

    truth = Engine(load_calibration(tmp_path / "cubic.yaml")).step("s1", 1.0, 20.0).strain
    strain = yaml.safe_load(echoes["/s1/strain"][1].read_text().split("---")[0])
    stamped = yaml.safe_load(echoes["/s1/strain_stamped"][1].read_text().split("---")[0])
    assert strain["data"] == pytest.approx(truth, abs=1e-9)
    assert stamped["name"] == ["s1"] and stamped["position"] == [strain["data"]]
    assert stamped["velocity"] == [] and stamped["effort"] == []
    assert stamped["header"]["frame_id"] == ""
    stamp = stamped["header"]["stamp"]["sec"] + stamped["header"]["stamp"]["nanosec"] * 1e-9
    assert t0 - 1.0 <= stamp <= t1  # the node clock (wall time) when the input arrived
    assert rates and rates[-1] == pytest.approx(20.0, rel=0.25)  # every input answered

    tared = ws.run("ros2", "service", "call", "/compensator/tare", "std_srvs/srv/Trigger",
                   slot=42).stdout
    assert "success=True" in tared and "tared s1 (rest 20 ohm, gain 1)" in tared
    reloaded = ws.run("ros2", "service", "call", "/compensator/reload_calibration",
                      "std_srvs/srv/Trigger", slot=42).stdout
    assert "success=True" in reloaded and "loading " in reloaded
    wait_for(log, "reloaded ", node, timeout=30.0)  # the load's result goes to the log
    stop_tool(pub)
    assert "Traceback" not in log.read_text()
    ctrl_c(node, log)


def test_ros2_launch_with_every_argument(ws: Workspace, tmp_path: Path) -> None:
    shown = ws.run("ros2", "launch", "strain_comp", "compensator.launch.py", "--show-args",
                   slot=43).stdout
    declared = set(re.findall(r"^\s+'(\w+)':", shown, flags=re.M))
    arguments = {"params_file": str(ws.share / "config/array_params.yaml"),
                 "use_sim_time": "true", "namespace": "robot1"}
    assert declared == set(arguments), shown
    log = tmp_path / "launch.log"
    proc = ws.start("ros2", "launch", "strain_comp", "compensator.launch.py",
                    *(f"{k}:={v}" for k, v in arguments.items()), slot=43, log=log)
    wait_for(log, "ready: 1 inputs: array [6 sensors: a1 .. a6]", proc)
    assert "/robot1/array/resistance -> /robot1/array/strain" in log.read_text()
    got = ros2(ws, 43, "param", "get", "/robot1/compensator", "use_sim_time")
    assert got == "Boolean value is: True"
    listed = "/robot1/array/strain_stamped [sensor_msgs/msg/JointState]"
    deadline = time.monotonic() + 30.0
    while listed not in (topics := ws.run("ros2", "topic", "list", "-t", slot=43).stdout):
        assert time.monotonic() < deadline, topics  # discovery may take a moment
    after = ctrl_c(proc, log)
    assert any("[robot1.compensator]: SIGINT: stopped" in line for line in after), after


def test_ros2_launch_under_sim_time_answers_every_lockstep_message(ws: Workspace,
                                                                   tmp_path: Path) -> None:
    """``ros2 launch ... use_sim_time:=true`` and ``strain-comp play BAG --clock --lockstep
    /s1/strain``: the node uses every message (``n_good`` on /diagnostics reaches the
    bag's count) and publishes /diagnostics under sim time (the bag spans 8 s of it). The
    calibration is named relative to its params file, which ``ros2 launch`` follows with
    a file of its own for ``use_sim_time``: the path still resolves beside the first."""
    import numpy as np

    from strain_comp.io.bag import BagWriter

    n = 600
    bag = tmp_path / "run.mcap"
    t = np.append(1.0 + np.arange(n) * 0.01, 9.0)  # the last: a tick after the others
    with BagWriter(bag) as writer:
        writer.write_float64("/s1/resistance", t, 15.0 + 4.0 * np.sin(t))
    log = tmp_path / "launch.log"
    proc = ws.start("ros2", "launch", "strain_comp", "compensator.launch.py",
                    f"params_file:={node_params(tmp_path)}", "use_sim_time:=true", slot=44,
                    log=log)
    wait_for(log, "ready: 1 inputs: s1 [s1]", proc)
    echo_log = tmp_path / "diagnostics.log"
    echo = ws.start("ros2", "topic", "echo", "/diagnostics",
                    "diagnostic_msgs/msg/DiagnosticArray", slot=44, log=echo_log)
    time.sleep(3.0)  # the echo subscribes before the first tick
    played = ws.run("ros2", "run", "strain_comp", "strain-comp", "play", str(bag), "--clock",
                    "--lockstep", "/s1/strain", slot=44, timeout=300)
    assert played.returncode == 0, played.stdout + played.stderr
    time.sleep(2.0)
    stop_tool(echo)
    text = echo_log.read_text()
    counts = [int(v) for v in re.findall(r"key: n_good\s+value: '(\d+)'", text)]
    assert counts, f"no /diagnostics under sim time: {text[-2000:]}"
    assert max(counts) >= n, (max(counts), log.read_text()[-2000:])  # every one before it
    ctrl_c(proc, log)
