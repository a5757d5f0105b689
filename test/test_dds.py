"""DDS transport end to end across processes, on loopback only.

Process 1 plays a bag's resistance topics over DDS (``python -m strain_comp.dds --play``),
process 2 is the compensator (``python -m strain_comp.dds --params``), and this test
process listens to ``rt/.../strain`` and ``rt/.../direction``. What it receives must equal
``replay`` on the same bag. Cyclone DDS is confined to ``lo`` without multicast (unicast
discovery to localhost) on a domain id of its own; every child is killed in ``finally``.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from test_engine import cubic_cal

from strain_comp.bag import BagWriter, read_bag
from strain_comp.calibration import Calibration, save_calibration
from strain_comp.replay import replay_bag

cyclonedds = pytest.importorskip("cyclonedds")

CONFIG = """<?xml version="1.0" encoding="UTF-8"?>
<CycloneDDS xmlns="https://cdds.io/config">
  <Domain id="any">
    <General>
      <Interfaces><NetworkInterface name="lo"/></Interfaces>
      <AllowMulticast>false</AllowMulticast>
    </General>
    <Discovery>
      <ParticipantIndex>auto</ParticipantIndex>
      <MaxAutoParticipantIndex>30</MaxAutoParticipantIndex>
      <Peers><Peer address="127.0.0.1"/></Peers>
    </Discovery>
  </Domain>
</CycloneDDS>
"""
PARAMS = """compensator:
  ros__parameters:
    sensors: [s1]
    s1: {topic: /s1/resistance, calibration: cal.yaml}
    arrays: [arr]
    arr: {topic: /arr/resistance, sensors: [a, b], calibration: cal.yaml}
"""
TIMEOUT = 15.0


def dds_setup(tmp_path: Path) -> tuple[dict[str, str], int]:
    config = tmp_path / "cyclonedds.xml"
    config.write_text(CONFIG)
    domain = 100 + os.getpid() % 100  # a domain of our own
    env = dict(os.environ, CYCLONEDDS_URI=config.as_uri())
    return env, domain


def write_inputs(tmp_path: Path) -> Path:
    save_calibration(Calibration({n: cubic_cal(n) for n in ("s1", "a", "b")}),
                     tmp_path / "cal.yaml")
    (tmp_path / "params.yaml").write_text(PARAMS)
    t = 1.0 + np.arange(200) * 0.01
    r = 150.0 + 40.0 * np.sin(3.0 * t)
    r[[20, 21, 90]] = [np.nan, -1.0, 1e7]
    arr = np.stack([r[::2], 300.0 - r[::2]], axis=1)
    with BagWriter(tmp_path / "in.mcap") as w:
        w.write_float64("/s1/resistance", t, r)
        w.write_float64_array("/arr/resistance", t[::2], arr, ["a", "b"])
    return tmp_path / "in.mcap"


def test_dds_node_matches_replay(tmp_path: Path) -> None:
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    from strain_comp.dds import Float64_, Float64MultiArray_, Int8_, qos, ros_topic

    bag = write_inputs(tmp_path)
    env, domain = dds_setup(tmp_path)
    os.environ["CYCLONEDDS_URI"] = env["CYCLONEDDS_URI"]  # this process listens too
    participant = DomainParticipant(domain)
    readers = {name: DataReader(participant, Topic(participant, ros_topic(name), kind),
                                qos=qos(reliable=True))
               for name, kind in (("/s1/strain", Float64_), ("/s1/direction", Int8_),
                                  ("/arr/strain", Float64MultiArray_))}
    children = []
    try:
        node = subprocess.Popen([sys.executable, "-m", "strain_comp.dds", "--params",
                                 str(tmp_path / "params.yaml"), "--domain", str(domain),
                                 "--reliable", "--duration", str(TIMEOUT)],
                                env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True)
        children.append(node)
        assert node.stdout.readline().strip() == "ready", node.stderr.read()
        deadline = time.monotonic() + TIMEOUT
        while any(not r.get_matched_publications() for r in readers.values()):
            assert time.monotonic() < deadline, "the node's writers were never discovered"
            time.sleep(0.02)
        player = subprocess.Popen([sys.executable, "-m", "strain_comp.dds", "--play", str(bag),
                                   "--domain", str(domain)], env=env, stdout=subprocess.PIPE,
                                  stderr=subprocess.PIPE, text=True)
        children.append(player)
        got: dict[str, list] = {name: [] for name in readers}
        want = {"/s1/strain": 200, "/s1/direction": 200, "/arr/strain": 100}
        while any(len(got[n]) < want[n] for n in want) and time.monotonic() < deadline:
            for name, reader in readers.items():
                for sample in reader.take(N=1000):
                    got[name].append((sample.sample_info.source_timestamp,
                                      list(sample.data) if name == "/arr/strain"
                                      else sample.data))
            time.sleep(0.01)
        assert player.wait(timeout=TIMEOUT) == 0, player.stderr.read()
        assert {n: len(v) for n, v in got.items()} == want
    finally:
        for child in children:
            if child.poll() is None:
                child.kill()
            child.wait(timeout=5)
    replay_bag(bag, Calibration({n: cubic_cal(n) for n in ("s1", "a", "b")}),
               tmp_path / "out.mcap")
    ref = read_bag(tmp_path / "out.mcap")
    for name in want:
        got[name].sort(key=lambda x: x[0])
        stamps = np.array([s for s, _ in got[name]]) * 1e-9
        np.testing.assert_allclose(stamps, ref.series[name].t, rtol=0, atol=1e-9)
        np.testing.assert_allclose(np.array([v for _, v in got[name]], dtype=float),
                                   ref.series[name].values, rtol=1e-9, atol=1e-9)
