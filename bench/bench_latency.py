"""Per-message latency of the engine and the DDS round trip (median / p99).

    python bench/bench_latency.py [--messages N] [--no-dds]

1. ``Engine.step`` per message, cubic and APL (N = 11, M = 9) calibrations, kernels warm.
2. ``Engine.step_array`` per tick for a 256-sensor APL array (one kernel call per tick).
3. DDS round trip on loopback: this process publishes one ``rt/s1/resistance`` sample,
   the node (``python -m strain_comp.dds`` in a child process) computes, this process
   waits for the ``rt/s1/strain`` sample; one message in flight at a time.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from strain_comp.core.calibration import (
    Calibration,
    SensorCalibration,
    ValidRange,
    save_calibration,
)
from strain_comp.core.direction import DirectionSettings
from strain_comp.core.engine import Engine
from strain_comp.models import Normalisation, Segment, model_class

NORM = Normalisation.from_ranges(100.0, 200.0, 0.0, 50.0)
RANGE = ValidRange(100.0, 200.0, 0.0, 50.0)
DIRECTION = DirectionSettings(deadzone=20.0, tau=0.05)
CONFIG = """<CycloneDDS xmlns="https://cdds.io/config"><Domain id="any">
<General><Interfaces><NetworkInterface name="lo"/></Interfaces>
<AllowMulticast>false</AllowMulticast></General>
<Discovery><ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>30
</MaxAutoParticipantIndex><Peers><Peer address="127.0.0.1"/></Peers></Discovery>
</Domain></CycloneDDS>"""


def calibration(model: str, name: str = "s1") -> SensorCalibration:
    if model == "cubic":
        params = {"c": [-60.0, 0.4, 1e-3, -2e-6]}
    else:
        t = np.arange(2000) * 0.01
        r = 150.0 + 40.0 * np.sin(2 * np.pi * 0.3 * t)
        fitted = model_class("apl").fit([Segment(t, r, 0.5 * (r - 100.0))], NORM,
                                        direction=DIRECTION, N=11, M=9)
        params = fitted.to_params()
    return SensorCalibration(name=name, model=model, params=params, normalisation=NORM,
                             valid_range=RANGE, direction=DIRECTION)


def stats(seconds: list[float] | np.ndarray) -> str:
    us = np.asarray(seconds) * 1e6
    return f"median {np.median(us):8.2f} us   p99 {np.percentile(us, 99):8.2f} us"


def bench_step(cal: SensorCalibration, n: int) -> np.ndarray:
    engine = Engine(Calibration({"s1": cal}))
    engine.warm_up()
    r = 150.0 + 40.0 * np.sin(np.arange(n) * 0.01)
    out = np.empty(n)
    for i in range(n):
        t0 = time.perf_counter()
        engine.step("s1", i * 0.001, r[i])
        out[i] = time.perf_counter() - t0
    return out


def bench_array(cal: SensorCalibration, k: int, n: int) -> np.ndarray:
    names = [f"x{i}" for i in range(k)]
    engine = Engine(Calibration({nm: SensorCalibration(**{**cal.__dict__, "name": nm})
                                 for nm in names}), arrays={"arr": names})
    engine.warm_up()
    rng = np.random.default_rng(0)
    phase = rng.uniform(0, 6, k)
    out = np.empty(n)
    for i in range(n):
        r = 150.0 + 40.0 * np.sin(i * 0.002 + phase)
        t0 = time.perf_counter()
        engine.step_array("arr", i * 0.001, r)
        out[i] = time.perf_counter() - t0
    return out


def bench_dds(cal: SensorCalibration, n: int) -> np.ndarray:
    from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.pub import DataWriter
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic
    from cyclonedds.util import duration
    from strain_comp.dds import Float64_, qos, ros_topic

    tmp = Path(tempfile.mkdtemp(prefix="strain_comp_bench_"))
    save_calibration(Calibration({"s1": cal}), tmp / "cal.yaml")
    (tmp / "params.yaml").write_text("compensator:\n  ros__parameters:\n    sensors: [s1]\n"
                                     "    s1: {calibration: cal.yaml}\n")
    (tmp / "dds.xml").write_text(CONFIG)
    os.environ["CYCLONEDDS_URI"] = (tmp / "dds.xml").as_uri()
    domain = 150 + os.getpid() % 50
    node = subprocess.Popen([sys.executable, "-m", "strain_comp.dds", "--params",
                             str(tmp / "params.yaml"), "--domain", str(domain), "--reliable",
                             "--duration", "120"], stdout=subprocess.PIPE, text=True)
    try:
        assert node.stdout.readline().strip() == "ready"
        dp = DomainParticipant(domain)
        writer = DataWriter(dp, Topic(dp, ros_topic("/s1/resistance"), Float64_),
                            qos=qos(reliable=True))
        reader = DataReader(dp, Topic(dp, ros_topic("/s1/strain"), Float64_),
                            qos=qos(reliable=True))
        waitset = WaitSet(dp)
        waitset.attach(ReadCondition(reader, SampleState.Any | ViewState.Any | InstanceState.Any))
        deadline = time.monotonic() + 20
        while not (writer.get_matched_subscriptions() and reader.get_matched_publications()):
            if time.monotonic() > deadline:
                raise RuntimeError("DDS discovery did not complete")
            time.sleep(0.02)
        out = np.empty(n)
        for i in range(n):
            t0 = time.perf_counter()
            writer.write(Float64_(150.0 + 40.0 * np.sin(i * 0.01)), timestamp=(i + 1) * 10**6)
            got: list = []
            while not got:
                waitset.wait(duration(seconds=5))
                got = reader.take(N=10)
                if not got and time.perf_counter() - t0 > 5:
                    raise RuntimeError("no strain came back within 5 s")
            out[i] = time.perf_counter() - t0
        return out
    finally:
        node.kill()
        node.wait()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--messages", type=int, default=20000)
    parser.add_argument("--no-dds", action="store_true")
    args = parser.parse_args()
    cals = {"cubic": calibration("cubic"), "apl": calibration("apl")}
    for model, cal in cals.items():
        print(f"Engine.step, {model:5s}:            {stats(bench_step(cal, args.messages))}")
    ticks = bench_array(cals["apl"], 256, max(args.messages // 10, 500))
    print(f"Engine.step_array, 256 x apl:   {stats(ticks)}   "
          f"(median {np.median(ticks) / 1e-3:.1%} of a 1 ms tick)")
    if not args.no_dds:
        rtt = bench_dds(cals["cubic"], min(args.messages, 2000))
        print(f"DDS round trip (cubic), lo:     {stats(rtt)}")


if __name__ == "__main__":
    main()
