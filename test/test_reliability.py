"""Reliability: killed calibration writers, replay of bad and truncated bags, a
random stream of good and bad array messages, stale inputs, and a short soak.

The calibrations are the per-model fits of ``conftest.fitted`` (fitted once per
pytest run). Truth: the bytes ``save_calibration`` writes for the old and the new calibration;
the input bag's message times; the engine's documented rules (a bad sample holds the last
estimate, a used one is finite and inside the widened strain range).
"""

from __future__ import annotations

import importlib.util
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import calibration_of, fitted, strain_bounds

from strain_comp.base.samples import Status
from strain_comp.core.calibration import Calibration, SensorCalibration
from strain_comp.core.calibration_file import load_calibration
from strain_comp.core.calibration_file import save_calibration as save
from strain_comp.core.engine import Engine
from strain_comp.core.range_policy import OPEN_FACTOR, SHORT_FACTOR
from strain_comp.errors import InputError
from strain_comp.io.bag import BagWriter, read_bag
from strain_comp.models import MODEL_NAMES
from strain_comp.offline.replay import replay_bag

ROOT = Path(__file__).resolve().parents[1]


# --------------------------------------------------------------------- killed writer

def big_calibration(version: int, n_copies: int = 10) -> Calibration:
    """Every model, ``n_copies`` times (70 sensors, ~110 kB of YAML, 50 times a usual file);
    the two versions differ in every sensor's provenance."""
    sensors = {}
    for k in range(n_copies):
        for model in MODEL_NAMES:
            name = f"{model}_{k}"
            cal = fitted(model)
            sensors[name] = SensorCalibration(**{
                **vars(cal), "name": name,
                "provenance": {**cal.provenance, "version": version,
                               "bags": [f"bag_{version}_{i}.mcap" for i in range(20)]}})
    return Calibration(sensors)


WRITER = """
import os, sys, time
import yaml
from strain_comp.core.calibration import (Calibration, InputSettings, SensorCalibration,
                                     ValidRange)
from strain_comp.core.calibration_file import save_calibration
from strain_comp.base.direction import DirectionSettings
from strain_comp.models import Normalisation

def read(path):  # load_calibration without building the models (quicker start)
    sensors = {}
    loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
    for name, d in yaml.load(open(path), Loader=loader)["sensors"].items():
        sensors[name] = SensorCalibration(
            name, d["model"]["name"], d["model"]["params"],
            Normalisation(**d["normalisation"]),
            ValidRange(*d["valid_range"]["resistance"], *d["valid_range"]["strain"]),
            DirectionSettings(**d["direction"]), InputSettings(**d["input"]),
            d["effects"], d["provenance"], d.get("rest_resistance"))
    return Calibration(sensors)

mode, target, a, b = sys.argv[1:5]
versions = [read(a), read(b)]
real_fsync, real_fdopen = os.fsync, os.fdopen

def announce(what):
    sys.stdout.write(what + "\\n")
    sys.stdout.flush()

if mode == "after_fsync":  # the temp file is complete, the rename has not happened
    def fsync(fd):
        real_fsync(fd)
        announce("synced")
        time.sleep(60)
    os.fsync = fsync
elif mode == "mid_write":  # half of the text is on disk
    class Half:
        def __init__(self, handle):
            self.handle = handle
        def __enter__(self):
            return self
        def __exit__(self, *exc):
            return self.handle.__exit__(*exc)
        def write(self, text):
            self.handle.write(text[: len(text) // 2])
            self.handle.flush()
            announce("half")
            time.sleep(60)
        def __getattr__(self, name):
            return getattr(self.handle, name)
    os.fdopen = lambda *args, **kw: Half(real_fdopen(*args, **kw))
announce("ready")
k = 1
while True:
    save_calibration(versions[k % 2], target)
    k += 1
"""


def test_killed_writer_leaves_the_old_or_the_new_file(tmp_path: Path) -> None:
    old, new = tmp_path / "old.yaml", tmp_path / "new.yaml"
    save(big_calibration(0), old)
    save(big_calibration(1), new)
    contents = {old.read_bytes(), new.read_bytes()}
    assert len(new.read_bytes()) > 100_000
    target_dir = tmp_path / "target"
    target = target_dir / "cal.yaml"
    save(load_calibration(old), target)
    rng = np.random.default_rng(4)
    plan = ["after_fsync", "mid_write"] + ["random"] * 3
    for mode in plan:
        child = subprocess.Popen([sys.executable, "-c", WRITER, mode, str(target), str(old),
                                  str(new)], stdout=subprocess.PIPE, text=True)
        try:
            assert child.stdout.readline().strip() == "ready"
            if mode == "random":
                time.sleep(float(rng.uniform(0.0, 0.8)))  # a save takes ~0.1 s
            else:
                assert child.stdout.readline().strip() in ("synced", "half")
        finally:
            child.send_signal(signal.SIGKILL)
            child.wait(timeout=30)
            child.stdout.close()
        assert child.returncode == -signal.SIGKILL
        assert target.read_bytes() in contents  # never a partial target
        load_calibration(target)
    # a crash leaves only hidden temp files beside the target, never a partial target
    leftovers = sorted(p.name for p in target_dir.iterdir() if p != target)
    assert all(n.startswith(".cal.yaml.") and n.endswith(".tmp") for n in leftovers)
    assert len(leftovers) >= 2  # the two announced kills landed inside a write
    save(big_calibration(1), target)
    assert target.read_bytes() == new.read_bytes()


# --------------------------------------------------------------------- replay of bad bags

def test_replay_keeps_every_message_time_and_marks_bad_samples(tmp_path: Path) -> None:
    cal = calibration_of("apl")
    vr = cal.sensors["s1"].valid_range
    n = 400
    t = 100.0 + np.arange(n) * 0.02
    r = vr.r_lo + (vr.r_hi - vr.r_lo) * (0.5 + 0.4 * np.sin(t))
    expected = np.zeros(n, dtype=np.int8)
    faults = {20: (math.nan, Status.NOT_FINITE), 21: (math.inf, Status.NOT_FINITE),
              40: (-3.0, Status.NON_POSITIVE), 41: (0.0, Status.NON_POSITIVE),
              60: (vr.r_hi * OPEN_FACTOR * 5, Status.OPEN_CIRCUIT),
              61: (vr.r_lo * SHORT_FACTOR / 5, Status.SHORT_CIRCUIT)}
    for i, (value, status) in faults.items():
        r[i], expected[i] = value, status
    t[[80, 81, 82]] = t[79]  # repeated stamps: rejected, the first one was used
    expected[[80, 81, 82]] = Status.TIME_NOT_INCREASING
    order = np.arange(n)
    order[200:220] = order[200:220][::-1]  # written out of time order (clock went back)
    bag_in, bag_out = tmp_path / "bad.mcap", tmp_path / "out.mcap"
    with BagWriter(bag_in) as w:
        w.write_float64("/s1/resistance", t[order], r[order])
    summary = replay_bag(bag_in, cal, bag_out)
    out = read_bag(bag_out)
    for what in ("strain", "direction", "status"):
        np.testing.assert_allclose(out.series[f"/s1/{what}"].t, t, rtol=0, atol=1e-9)
    status = out.series["/s1/status"].values
    np.testing.assert_array_equal(status, expected)
    strain = out.series["/s1/strain"].values
    bad = expected != 0
    assert np.isfinite(strain).all()
    held = np.maximum.accumulate(np.where(bad, 0, np.arange(n)))
    np.testing.assert_array_equal(strain, strain[held])  # bad samples hold the estimate
    health = summary.sensors["s1"]
    assert (health.n_nan, health.n_non_positive, health.n_open, health.n_short,
            health.n_time_backwards) == (2, 2, 1, 1, 3)
    assert health.n_good + health.n_bad == n


def test_truncated_bag_replays_what_is_readable_and_reports_it(tmp_path: Path) -> None:
    cal = calibration_of("sinh_pl")
    vr = cal.sensors["s1"].valid_range
    t = 1.0 + np.arange(6000) * 0.01
    r = vr.r_lo + (vr.r_hi - vr.r_lo) * (0.5 + 0.4 * np.sin(t))
    whole, cut, bag_out = tmp_path / "whole.mcap", tmp_path / "cut.mcap", tmp_path / "out.mcap"
    with BagWriter(whole, chunk_size=8000) as w:
        w.write_float64("/s1/resistance", t, r)
        w.write_float64("/s1/strain_reference", t, np.zeros_like(t))
    data = whole.read_bytes()
    cut.write_bytes(data[:int(len(data) * 0.6)])  # mid-chunk, no summary, no footer
    summary = replay_bag(cut, cal, bag_out)
    assert any("truncated" in p for p in summary.problems), summary.problems
    kept = read_bag(bag_out).series["/s1/strain"]
    n = kept.t.size
    assert 0.2 * t.size < n < t.size
    np.testing.assert_allclose(kept.t, t[:n], atol=1e-9)  # every message before the damage
    reference = Engine(cal).run("s1", t[:n], r[:n]).strain
    np.testing.assert_allclose(kept.values, reference, rtol=1e-12)


# --------------------------------------------------------------------- random array stream

N_TICKS = 5000
"""Ticks of the random stream (about 1 s for an array of one sensor per model)."""


def _array_engine(models: list[str]) -> tuple[Engine, list[str]]:
    names = [f"{m}_{i}" for i, m in enumerate(models)]
    cals = {n: SensorCalibration(**{**vars(fitted(m)), "name": n})
            for n, m in zip(names, models, strict=True)}
    return Engine(Calibration(cals), arrays={"arr": names}, gap_reset=2.0,
                  stale_after=0.5), names


@pytest.mark.parametrize("models", [["apl", "pl", "mpi", "apl"], list(MODEL_NAMES)],
                         ids=["apl_kernel", "every_model"])
def test_array_engine_survives_a_random_stream_of_good_and_bad_messages(models: list) -> None:
    engine, names = _array_engine(models)
    k = len(names)
    vrs = [fitted(m).valid_range for m in models]
    r_lo, r_hi = np.array([v.r_lo for v in vrs]), np.array([v.r_hi for v in vrs])
    bounds = np.array([strain_bounds(fitted(m)) for m in models])
    rng = np.random.default_rng(11)
    u = np.full(k, 0.5)
    t = 50.0
    previous = np.full(k, np.nan)
    ever_used = np.zeros(k, dtype=bool)
    ticks = rejected = 0
    while ticks < N_TICKS:
        jump = rng.random()
        if jump < 0.02:
            t -= rng.uniform(0.0, 10.0)  # bag loop or sim-time reset
        elif jump < 0.04:
            t += rng.uniform(2.0, 20.0)  # long gap
        elif jump > 0.05:
            t += rng.uniform(1e-4, 0.05)  # else: a repeated stamp
        u = np.clip(u + rng.normal(0.0, 0.02, k), -0.3, 1.3)
        r = r_lo + u * (r_hi - r_lo)
        faults = rng.random(k) < 0.15
        choices = np.array([np.nan, np.inf, -np.inf, 0.0, -1.0, 1e300, 1e-300,
                            1e3 * OPEN_FACTOR, 1e-3 * SHORT_FACTOR])
        r[faults] = choices[rng.integers(0, choices.size, faults.sum())]
        if rng.random() < 0.02:  # wrong vector length: rejected whole, state untouched
            before = engine.health()
            with pytest.raises(InputError, match="expected"):
                engine.step_array("arr", t, r[:int(rng.integers(0, k))])
            assert engine.health() == before
            rejected += 1
            continue
        out = engine.step_array("arr", t, r)
        ticks += 1
        used = (out.status == Status.GOOD) | (out.status >= Status.GAP_RESET)
        ever_used |= used
        assert np.isfinite(out.strain[ever_used]).all()
        assert np.isnan(out.strain[~ever_used]).all()
        inside = (out.strain >= bounds[:, 0]) & (out.strain <= bounds[:, 1])
        assert inside[ever_used].all()
        np.testing.assert_array_equal(out.strain[~used], previous[~used])  # held
        assert set(np.unique(out.direction)) <= {-1, 0, 1}
        previous = out.strain
    assert rejected > 0
    health = engine.health()
    for name in names:
        h = health[name]
        assert h.n_good + h.n_bad == ticks
        assert h.n_nan and h.n_non_positive and h.n_open and h.n_short
        assert h.n_time_backwards and h.n_gaps


def test_stale_input_is_reported_until_good_samples_return() -> None:
    engine, names = _array_engine(["apl", "pl", "mpi"])
    vr = fitted("apl").valid_range
    mid = 0.5 * (vr.r_lo + vr.r_hi)
    t = np.arange(0.0, 3.0, 0.01)
    for ti in t:
        r = np.full(3, mid + 0.1 * math.sin(ti))
        if 1.0 <= ti < 2.0:
            r[1] = math.nan  # one wire broken for a second
        engine.step_array("arr", ti, r)
        if abs(ti - 1.9) < 1e-9:
            health = engine.health(now=ti)
            assert [health[n].stale for n in names] == [False, True, False]
            level, message, values = health[names[1]].to_diagnostic()
            assert level == 3 and "stale" in message and values["n_nan"] == "91"
    health = engine.health(now=t[-1])
    assert not any(h.stale for h in health.values())
    assert all(h.stale for h in engine.health(now=t[-1] + 0.6).values())  # input stopped
    assert all(h.to_diagnostic()[0] == 3 for h in engine.health(now=t[-1] + 0.6).values())


# --------------------------------------------------------------------- short soak

def test_short_soak_every_model() -> None:
    spec = importlib.util.spec_from_file_location("soak", ROOT / "scripts" / "soak.py")
    soak = importlib.util.module_from_spec(spec)
    sys.modules["soak"] = soak  # dataclasses look their module up there
    spec.loader.exec_module(soak)
    for model in MODEL_NAMES:
        result = soak.soak_model(fitted(model), samples=100_000, chunk=20_000, steps=2_000,
                                 engine_samples=20_000, seed=3)
        assert result.nan_count == 0, (model, result)
        assert result.cycle_drift <= 1e-9 * result.strain_span, (model, result)
        assert result.engine_bad > 0 and result.engine_nonfinite == 0, (model, result)
    assert os.path.exists("/proc/self/status") and soak.rss_kib() > 0


def test_replay_reports_a_calibrated_sensor_without_its_topic_as_stale(tmp_path: Path) -> None:
    both = Calibration({n: SensorCalibration(**{**vars(fitted("cubic")), "name": n})
                        for n in ("s1", "s2")})
    vr = fitted("cubic").valid_range
    t = 1.0 + np.arange(300) * 0.01
    bag_in, bag_out = tmp_path / "in.mcap", tmp_path / "out.mcap"
    with BagWriter(bag_in) as w:
        w.write_float64("/s1/resistance", t, np.full(t.size, 0.5 * (vr.r_lo + vr.r_hi)))
    summary = replay_bag(bag_in, both, bag_out)
    assert summary.sensors["s2"].n_good == 0
    assert [p for p in summary.problems if "'s2'" in p] == [
        f"{bag_in}: calibrated sensor 's2' has no input topic in the bag: not replayed "
        "(STALE in /diagnostics)"]
    out = read_bag(bag_out)
    assert "/s2/strain" not in out.series
    last = {name: (level, message) for name, level, message, _ in out.diagnostics[-1][1]}
    assert last["strain_comp: s1"][0] == 0
    assert last["strain_comp: s2"][0] == 3 and "stale" in last["strain_comp: s2"][1]
