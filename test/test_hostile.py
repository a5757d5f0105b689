"""The command line and the files it writes under hostile use: exit codes 0/2/130 with one
error line, outputs that are inputs or not regular files refused, atomic outputs under
SIGKILL and concurrent writers, resource limits of simulate and of calibration files,
rosbag2 directories read defensively, and a bounded run of the command-line fuzzer.

Truth: the bytes of the inputs before the command (SHA-256), the bytes of the complete old
and new outputs written undisturbed, the mcap library's reader, and the engine's declared
strain range. Every random test is seeded and bounded.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import fitted, strain_bounds
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

import strain_comp as sc
from strain_comp.base.samples import DEFAULT_GAP_RESET
from strain_comp.cli import main
from strain_comp.core.calibration import (
    MAX_FILE_BYTES,
    PARAM_MAX,
    Calibration,
    SensorCalibration,
)
from strain_comp.core.calibration_file import load_calibration
from strain_comp.core.engine import Engine
from strain_comp.diagnosis.candidates import default_candidates
from strain_comp.errors import BagError, CalibrationError, InputError, OutputError
from strain_comp.io.bag import BagWriter, read_bag
from strain_comp.models import MODEL_NAMES
from strain_comp.offline.options import check_fit_options
from strain_comp.offline.rig import MAX_SAMPLES, check_size

ROOT = Path(__file__).resolve().parents[1]
ERROR = "strain-comp: error: "
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


def sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    """Exit code and stderr of ``strain-comp argv``; a failure is exactly one error line."""
    capsys.readouterr()
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert code in (0, 2, 130)
    assert "Traceback" not in err
    if code == 2:
        assert len(err.splitlines()) == 1 and err.startswith(ERROR), err
        assert "unexpected" not in err, err
    return code, err


class Blocked(BaseException):
    """A command ran past its time limit (not an Exception: the CLI must not absorb it)."""


@contextmanager
def time_limit(seconds: float) -> Iterator[None]:
    def alarm(signum: int, frame: object) -> None:
        raise Blocked(f"blocked for more than {seconds} s")

    previous = signal.signal(signal.SIGALRM, alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.signal(signal.SIGALRM, previous)


@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 20 s simulated bag, a cubic calibration of it and a CSV, once for the module."""
    work = tmp_path_factory.mktemp("hostile")
    assert main(["simulate", "--scenario", "triangle", "--out", str(work / "sim.mcap"),
                 "--seed", "1", "--duration", "20"]) == 0
    assert main(["fit", str(work / "sim.mcap"), "--model", "cubic", "--sensor", "all",
                 "--out", str(work / "cal.yaml")]) == 0
    (work / "in.csv").write_text("t,r,s\n" + "".join(
        f"{k * 0.1},{10 + (k % 50) * 0.1},{k % 50}\n" for k in range(300)))
    return work


# --------------------------------------------------------------------- exit codes

@pytest.mark.parametrize("argv", [
    [], ["bogus"], ["fit"], ["fit", "x.mcap", "--model"], ["simulate", "--seed", "abc"],
    ["simulate", "--duration", "x"], ["import-csv", "a.csv", "--format", "xls"],
    ["evaluate", "--nope"], ["replay", "a", "b", "--calibration", "c", "--out", "d"],
])
def test_usage_errors_are_one_line_and_exit_2(argv: list[str],
                                              capsys: pytest.CaptureFixture[str]) -> None:
    code, err = run(argv, capsys)
    assert code == 2 and "usage" not in err


@pytest.mark.parametrize(("model", "option", "words"), [
    ("apl", "N=abc", "N='abc': must be an integer"),
    ("apl", "N=2.5", "N=2.5: must be an integer"),
    ("cubic", "k_sigma=abc", "k_sigma='abc': must be a number"),
    ("cubic", "N=3", "model 'cubic' has no such option"),
    ("rational", "mode=fast", "must be one of combined, split"),
    ("sinh_pl", "n_cells=.inf", "n_cells=inf: must be an integer"),
])
def test_option_values_are_checked_per_model(work: Path, model: str, option: str, words: str,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    out = work / f"opt_{model}.yaml"
    code, err = run(["fit", work / "sim.mcap", "--model", model, "--sensor", "all",
                     "--out", out, "--option", option], capsys)
    assert code == 2 and words in err, err
    assert not out.exists()


OPTION_VALUES = st.sampled_from([
    "abc", 2.5, 3, 11, -1, 0, 1e400, [0.1, 0.3], [], True, None, "split", "free", {"a": 1},
    [1, [2]], 1, 0.5, 1e-3])
OPTION_KEYS = st.sampled_from(["N", "M", "mode", "k_sigma", "deadzone", "tau", "n_cells",
                               "max_nfev", "hold_rate", "min_hold", "sigma_grid", "refine",
                               "search_top", "cell_weights", "bogus"])


@settings(max_examples=40, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(model=st.sampled_from(["cubic", "rational", "sinh_pl", "spike_decay"]),
       key=OPTION_KEYS, value=OPTION_VALUES)
def test_accepted_fit_options_always_fit_and_refused_ones_name_the_option(
        model: str, key: str, value: object) -> None:
    from conftest import training_recording

    from strain_comp.errors import FitError
    from strain_comp.offline.fit import fit_sensor

    try:
        check_fit_options(model, {key: value})
    except InputError as err:
        assert str(err).startswith(f"--option {key}"), err
        return
    try:  # an accepted option must never crash the fit (a FitError is a clean refusal)
        fit_sensor([training_recording()], model, name="s1",
                   options={key: value, **({"tau": 0.2} if key not in ("deadzone", "tau")
                                           else {})})
    except FitError:
        pass


@pytest.mark.parametrize(("flags", "words"), [
    (["--duration", "1e7"], "at most 40000 s"), (["--duration", "1e12"], "at most"),
    (["--duration", "nan"], "must be > 0 s"), (["--seed", "-1"], "seed: must be"),
    (["--seed", str(2**63)], "seed: must be"),
])
def test_simulate_size_and_seed_limits(tmp_path: Path, flags: list[str], words: str,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "big.mcap"
    code, err = run(["simulate", "--scenario", "triangle", "--out", out, *flags], capsys)
    assert code == 2 and words in err, err
    assert not out.exists()
    # the limit itself: samples x sensors of the run, on both sides of it
    check_size("triangle", duration=MAX_SAMPLES / 50.0)
    check_size("array", duration=MAX_SAMPLES / 25.0 / 6 * 0.999)
    with pytest.raises(Exception, match="at most"):
        check_size("array", duration=MAX_SAMPLES / 25.0 / 6 * 1.001)


# --------------------------------------------------------------------- inputs never lost

def same_file_cases(work: Path) -> list[tuple[list[object], Path]]:
    bag, cal, csv = work / "sim.mcap", work / "cal.yaml", work / "in.csv"
    hard, link = work / "hard.mcap", work / "link.yaml"
    if not hard.exists():
        os.link(bag, hard)
        os.symlink(cal, link)
    fit = ["fit", bag, "--model", "cubic", "--sensor", "all", "--out"]
    return [
        ([*fit, bag], bag), ([*fit, hard], bag),
        (["diagnose", bag, "--calibration", cal, "--out", bag], bag),
        (["diagnose", bag, "--calibration", cal, "--out", link], cal),
        (["diagnose", bag, "--calibration", cal, "--out", work / "x.yaml", "--json", cal], cal),
        (["evaluate", bag, "--calibration", cal, "--json", bag], bag),
        (["evaluate", bag, "--calibration", cal, "--json", hard], bag),
        (["import-csv", csv, "--out", csv, "--sensor", "s1", "--format", "generic",
          "--columns", "time=0,resistance=1,strain=2"], csv),
        (["replay", bag, "--calibration", cal, "--out", cal], cal),
        (["replay", bag, "--calibration", cal, "--out", bag], bag),
        (["replay", hard, "--calibration", cal, "--out", bag], bag),
    ]


@pytest.mark.parametrize("case", range(11))
def test_an_output_that_is_an_input_is_refused_and_the_input_kept(
        work: Path, case: int, capsys: pytest.CaptureFixture[str]) -> None:
    argv, protected = same_file_cases(work)[case]
    before = sha(protected)
    code, err = run(argv, capsys)
    assert code == 2 and ("is the input" in err or "(a symbolic link)" in err), err
    assert sha(protected) == before


def test_the_api_refuses_an_output_that_is_an_input_as_the_command_does(work: Path) -> None:
    bag, cal = work / "sim.mcap", work / "cal.yaml"
    before = sha(cal)
    calls = [lambda: sc.replay(cal, bag, out=cal), lambda: sc.replay(str(cal), bag, out=bag),
             lambda: sc.evaluate(cal, bag, csv=cal),
             lambda: sc.diagnose(cal, bag, out=cal, session_start=False)]
    for call in calls:
        with pytest.raises(OutputError, match="is the input"):
            call()
    assert sha(cal) == before


@pytest.mark.parametrize("which", ["json", "report", "csv", "two"])
def test_outputs_that_collide_with_a_plot_or_each_other_are_refused_before_any_write(
        work: Path, tmp_path: Path, which: str, capsys: pytest.CaptureFixture[str]) -> None:
    plots = tmp_path / "plots"
    name = next(iter(load_calibration(work / "cal.yaml").sensors))
    target = plots / f"{name}_loop.png" if which != "two" else tmp_path / "same.json"
    argv: list[object] = ["evaluate", work / "sim.mcap", "--calibration", work / "cal.yaml",
                          "--plots", plots, f"--{which if which != 'two' else 'json'}", target]
    if which == "two":
        argv += ["--report", target]
    code, err = run(argv, capsys)
    assert code == 2 and "given for two outputs" in err, err
    assert not target.exists() and not plots.exists()
    diag = ["diagnose", work / "sim.mcap", "--calibration", work / "cal.yaml", "--plots",
            plots, "--out", tmp_path / "x.yaml", "--json", plots / f"diagnose_{name}.png"]
    code, err = run(diag, capsys)
    assert code == 2 and "given for two outputs" in err, err
    assert not (tmp_path / "x.yaml").exists()


@pytest.mark.parametrize("kind", ["symlink", "fifo", "directory", "device"])
def test_an_output_that_is_not_a_regular_file_is_refused(
        work: Path, tmp_path: Path, kind: str, capsys: pytest.CaptureFixture[str]) -> None:
    target = tmp_path / "out"
    other = tmp_path / "other.mcap"
    other.write_bytes(b"keep me")
    if kind == "symlink":
        os.symlink(other, target)
    elif kind == "fifo":
        os.mkfifo(target)
    elif kind == "directory":
        target.mkdir()
    else:
        target = Path("/dev/null")
    for argv in (["replay", work / "sim.mcap", "--calibration", work / "cal.yaml", "--out"],
                 ["fit", work / "sim.mcap", "--model", "cubic", "--sensor", "all", "--out"],
                 ["simulate", "--scenario", "triangle", "--duration", "5", "--out"]):
        with time_limit(20):
            code, err = run([*argv, target], capsys)
        assert code == 2 and "refusing to replace it" in err, err
    assert other.read_bytes() == b"keep me"
    assert kind != "symlink" or target.is_symlink()
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


@pytest.mark.parametrize("which", ["bag", "calibration", "csv", "validate", "params"])
def test_a_fifo_given_as_an_input_is_refused_without_blocking(
        work: Path, tmp_path: Path, which: str, capsys: pytest.CaptureFixture[str]) -> None:
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    bag, cal = work / "sim.mcap", work / "cal.yaml"
    argv = {
        "bag": ["replay", fifo, "--calibration", cal, "--out", tmp_path / "o.mcap"],
        "calibration": ["evaluate", bag, "--calibration", fifo],
        "csv": ["import-csv", fifo, "--out", tmp_path / "o.mcap", "--sensor", "s",
                "--format", "fiber"],
        "validate": ["diagnose", bag, "--calibration", cal, "--validate", fifo,
                     "--out", tmp_path / "o.yaml"],
        "params": ["node", "--params", fifo],
    }[which]
    with time_limit(20):
        code, err = run(argv, capsys)
    assert code == 2 and "not a regular file" in err, err
    with time_limit(20), pytest.raises(BagError, match="not a regular file"):
        read_bag(fifo)
    with time_limit(20), pytest.raises(CalibrationError, match="not a regular file"):
        load_calibration(fifo)


# --------------------------------------------------------------------- atomic outputs

BAG_WRITER = """
import sys
import numpy as np
from strain_comp.io.bag import BagWriter
target, first = sys.argv[1], int(sys.argv[2])
t = np.arange(50_000) * 0.01
k = first
while True:
    with BagWriter(target) as writer:
        writer.write_float64("/s1/resistance", t, 10.0 + k % 2 + np.sin(t))
    if k == first:
        print("ready", flush=True)  # compiled and written once: kills land in the loop
    k += 1
"""


def write_version(path: Path, k: int) -> bytes:
    t = np.arange(50_000) * 0.01
    with BagWriter(path) as writer:
        writer.write_float64("/s1/resistance", t, 10.0 + k % 2 + np.sin(t))
    return path.read_bytes()


def readable(path: Path) -> int:
    """Messages the mcap library reads from ``path`` (raises on a damaged file)."""
    with path.open("rb") as handle:
        return sum(1 for _ in make_reader(handle).iter_messages())


def test_a_killed_bag_writer_leaves_the_old_or_the_new_bag(tmp_path: Path) -> None:
    versions = {write_version(tmp_path / "a.mcap", 0), write_version(tmp_path / "b.mcap", 1)}
    target = tmp_path / "out" / "bag.mcap"
    target.parent.mkdir()
    write_version(target, 0)
    rng = np.random.default_rng(11)
    for _ in range(3):
        child = subprocess.Popen([sys.executable, "-c", BAG_WRITER, str(target),
                                  str(int(rng.integers(0, 2)))], stdout=subprocess.PIPE,
                                 text=True, env=ENV)
        try:
            assert child.stdout.readline().strip() == "ready"
            time.sleep(float(rng.uniform(0.0, 0.3)))  # one bag takes ~0.1 s
        finally:
            child.send_signal(signal.SIGKILL)
            child.wait(timeout=30)
            child.stdout.close()
        assert target.read_bytes() in versions  # never a partial bag
        assert readable(target) == 50_000
    leftovers = [p.name for p in target.parent.iterdir() if p != target]
    assert all(n.startswith(".bag.mcap.") and n.endswith(".tmp") for n in leftovers)


def test_a_killed_replay_leaves_the_old_or_the_complete_new_output(work: Path,
                                                                    tmp_path: Path) -> None:
    """``strain-comp replay`` killed at random moments over a previous complete output."""
    out = tmp_path / "replayed.mcap"
    assert main(["replay", str(work / "sim.mcap"), "--calibration", str(work / "cal.yaml"),
                 "--out", str(out)]) == 0
    new = out.read_bytes()
    old = b"previous complete output"
    rng = np.random.default_rng(3)
    for _ in range(2):
        out.write_bytes(old)
        child = subprocess.Popen([sys.executable, "-m", "strain_comp.cli", "replay",
                                  str(work / "sim.mcap"), "--calibration",
                                  str(work / "cal.yaml"), "--out", str(out)], env=ENV,
                                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(float(rng.uniform(0.5, 3.0)))  # a replay takes ~2 s, mostly start-up
        child.send_signal(signal.SIGKILL)
        child.wait(timeout=30)
        assert out.read_bytes() in (old, new)


CONCURRENT = """
import sys
import numpy as np
from strain_comp.io.bag import BagWriter
target, k = sys.argv[1], int(sys.argv[2])
t = np.arange(100_000) * 0.01
for _ in range(4):
    with BagWriter(target) as writer:
        writer.write_float64("/s1/resistance", t, 10.0 + k + np.sin(t))
"""


def test_concurrent_writers_end_with_one_complete_bag(tmp_path: Path) -> None:
    target = tmp_path / "bag.mcap"
    children = [subprocess.Popen([sys.executable, "-c", CONCURRENT, str(target), str(k)],
                                 env=ENV) for k in (0, 1)]
    assert [c.wait(timeout=120) for c in children] == [0, 0]
    versions = set()
    for k in (0, 1):
        t = np.arange(100_000) * 0.01
        with BagWriter(tmp_path / f"v{k}.mcap") as writer:
            writer.write_float64("/s1/resistance", t, 10.0 + k + np.sin(t))
        versions.add((tmp_path / f"v{k}.mcap").read_bytes())
    assert target.read_bytes() in versions
    assert readable(target) == 100_000
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


def test_a_failed_bag_write_leaves_the_old_file_and_no_temp(tmp_path: Path) -> None:
    target = tmp_path / "bag.mcap"
    old = write_version(target, 0)
    with pytest.raises(RuntimeError), BagWriter(target) as writer:
        writer.write_float64("/s1/resistance", [0.0, 1.0], [1.0, 2.0])
        raise RuntimeError("abort mid-write")
    assert target.read_bytes() == old
    assert [p.name for p in tmp_path.iterdir()] == ["bag.mcap"]


# --------------------------------------------------------------------- calibration limits

def cal_text(work: Path) -> str:
    return (work / "cal.yaml").read_text()


def hostile_calibrations(work: Path) -> dict[str, tuple[bytes, str]]:
    """name -> (file bytes, words the one-line error must hold)."""
    good = yaml.safe_load(cal_text(work))
    laughs = "a: &a [x,x,x,x,x,x,x,x,x,x]\n" + "".join(
        f"{c}: &{c} [{', '.join([f'*{p}'] * 10)}]\n"
        for p, c in zip("abcdefgh", "bcdefghi", strict=True))

    def edited(change: object) -> bytes:
        doc = yaml.safe_load(cal_text(work))
        change(doc["sensors"]["s1"])
        return yaml.safe_dump(doc).encode()

    def apl(doc: dict) -> None:
        model = SensorCalibration(**{**vars(fitted("apl")), "name": "s1"})
        doc.update(yaml.safe_load(yaml.safe_dump(
            Calibration({"s1": model}).to_dict()))["sensors"]["s1"])
        doc["model"]["params"]["w"] = [1e308] * len(doc["model"]["params"]["w"])

    return {
        "billion laughs": (laughs.encode(), "refused: more than"),
        "nesting": (b"[" * 1000 + b"]" * 1000, "nested more than 64 deep"),
        "bigint": (cal_text(work).replace("format:", "x: 1" + "0" * 400 + "\nformat:", 1)
                   .encode(), "beyond float range"),
        "huge digits": (("x: " + "9" * 6000 + "\n").encode(), "beyond float range"),
        "oversized": (b"#" * (MAX_FILE_BYTES + 1), "larger than"),
        "non-utf8": (b"format: \xff\xfe\n", "cannot read"),
        "recursive alias": (b"&a [*a]", "contains it"),
        "self cross-talk": (edited(lambda s: s.update(effects=[
            {"name": "ct", "kind": "crosstalk", "params": {"neighbour": "s1"},
             "coef": 0.1}])), "must read another sensor"),
        "effect coefficient": (edited(lambda s: s.update(effects=[
            {"name": "o", "kind": "offset", "params": {}, "coef": 1e307}])),
            "effects.0.coef: must be finite and at most"),
        "apl slopes": (edited(apl), "model.params.w.0: must be finite and at most"),
        "strain range": (edited(lambda s: s["valid_range"].update(strain=[0, 1e300])),
                         "valid_range.strain"),
        "text": (yaml.safe_dump(good).encode(), ""),  # the unedited file loads
    }


@pytest.mark.parametrize("name", ["billion laughs", "nesting", "bigint", "huge digits",
                                  "oversized", "non-utf8", "recursive alias",
                                  "self cross-talk", "effect coefficient", "apl slopes",
                                  "strain range", "text"])
def test_calibration_limits_refuse_with_one_line(work: Path, tmp_path: Path, name: str,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    data, words = hostile_calibrations(work)[name]
    path = tmp_path / "cal.yaml"
    path.write_bytes(data)
    with time_limit(30):
        if not words:
            load_calibration(path)
            return
        with pytest.raises(CalibrationError) as info:
            load_calibration(path)
        assert str(info.value).startswith(f"{path}: ") and words in str(info.value), info.value
        code, err = run(["evaluate", work / "sim.mcap", "--calibration", path], capsys)
    assert code == 2 and words in err


def perturb(value: object, rng: np.random.Generator) -> object:
    """Numbers of a parameter tree scaled by 10^U(-12, 12), sign-flipped or set to the
    largest magnitude allowed, at random; the tree's shape kept."""
    if isinstance(value, dict):
        return {k: perturb(v, rng) for k, v in value.items()}
    if isinstance(value, list):
        return [perturb(v, rng) for v in value]
    if isinstance(value, float) and rng.random() < 0.5:
        choice = rng.integers(0, 4)
        if choice == 0:
            return float(np.clip(value * 10.0 ** rng.uniform(-12, 12), -PARAM_MAX, PARAM_MAX))
        if choice == 1:
            return -value
        if choice == 2:
            return float(PARAM_MAX * rng.choice([-1.0, 1.0]))
        return float(rng.uniform(-10, 10))
    return value


@settings(max_examples=25, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(model=st.sampled_from(MODEL_NAMES), seed=st.integers(0, 2**32 - 1),
       n_effects=st.integers(0, 4), log_r=st.lists(st.floats(-300, 300), min_size=5,
                                                     max_size=60))
def test_a_calibration_that_loads_gives_finite_strain_in_its_range(
        tmp_path_factory: pytest.TempPathFactory, model: str, seed: int, n_effects: int,
        log_r: list[float]) -> None:
    rng = np.random.default_rng(seed)
    base = fitted(model)
    doc = Calibration({"s1": base, "s2": SensorCalibration(**{**vars(base), "name": "s2"})}
                      ).to_dict()
    sensor = doc["sensors"]["s1"]
    sensor["model"]["params"] = perturb(yaml.safe_load(yaml.safe_dump(
        sensor["model"]["params"])), rng)
    candidates = default_candidates(temperature_ref=24.0, neighbours=["s2"])
    picks = rng.choice(len(candidates), size=n_effects, replace=False)
    sensor["effects"] = [dict(candidates[int(i)], coef=float(
        rng.choice([-1.0, 1.0]) * 10.0 ** rng.uniform(-6, 12))) for i in picks]
    path = tmp_path_factory.mktemp("prop") / "cal.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    try:
        calibration = load_calibration(path)
    except CalibrationError:
        return  # refused with a reason: allowed
    cal = calibration.sensors["s1"]
    lo, hi = strain_bounds(cal)
    r = 10.0 ** np.asarray(log_r)
    t = np.cumsum(rng.uniform(1e-3, DEFAULT_GAP_RESET, r.size))
    engine = Engine(calibration, gap_reset=DEFAULT_GAP_RESET)
    out = engine.run_array(["s1", "s2"], t, np.column_stack([r, r]),
                           {"s1": np.full(t.size, 24.0 + 3.0 * np.sin(t))})["s1"]
    used = np.flatnonzero((out.status == 0) | (out.status >= 6))
    held = out.strain[used[0]:] if used.size else out.strain[:0]
    assert np.isfinite(held).all(), (model, sensor, r, held)
    assert ((held >= lo) & (held <= hi)).all()


# --------------------------------------------------------------------- rosbag2 directories

@pytest.mark.parametrize(("metadata", "words"), [
    (b"rosbag2_bagfile_information: {relative_file_paths: [\xff\xfe]}\n",
     "unreadable rosbag2 metadata"),
    (b"a: " + b"[" * 1000 + b"]" * 1000, "nested more than"),
    (b"rosbag2_bagfile_information: {relative_file_paths: 7}", "must be a list of strings"),
    (b"rosbag2_bagfile_information: {relative_file_paths: [7]}", "must be a list of strings"),
    (b"rosbag2_bagfile_information: [1, 2]", "must be a mapping"),
    (b"[1, 2]", "must be a mapping"),
    (b"rosbag2_bagfile_information: {relative_file_paths: [../outside.mcap]}",
     "leaves the bag directory"),
    (b"rosbag2_bagfile_information: {relative_file_paths: [/etc/passwd]}",
     "leaves the bag directory"),
    (b"rosbag2_bagfile_information: {relative_file_paths: [escape.mcap]}",
     "not a regular file inside the bag directory"),
])
def test_rosbag2_metadata_is_read_defensively(work: Path, tmp_path: Path, metadata: bytes,
                                              words: str,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    bag = tmp_path / "bag"
    bag.mkdir()
    (tmp_path / "outside.mcap").write_bytes((work / "sim.mcap").read_bytes())
    os.symlink(tmp_path / "outside.mcap", bag / "escape.mcap")
    (bag / "metadata.yaml").write_bytes(metadata)
    with pytest.raises(BagError) as info:
        read_bag(bag)
    assert words in str(info.value) and "\n" not in str(info.value)
    code, err = run(["replay", bag, "--calibration", work / "cal.yaml",
                     "--out", tmp_path / "o.mcap"], capsys)
    assert code == 2 and words in err


def test_rosbag2_directory_reads_only_files_inside_it(work: Path, tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    bag.mkdir()
    (tmp_path / "outside.mcap").write_bytes((work / "sim.mcap").read_bytes())
    os.symlink(tmp_path / "outside.mcap", bag / "escape.mcap")
    with pytest.raises(BagError, match=r"holds no \.mcap or \.db3 file"):
        read_bag(bag)  # the only .mcap is a link out of the directory
    (bag / "inside.mcap").write_bytes((work / "sim.mcap").read_bytes())
    assert read_bag(bag).problems == []
    assert read_bag(bag).series.keys() == read_bag(work / "sim.mcap").series.keys()


def float64_bag(path: Path, times: list[int], payloads: list[bytes]) -> None:
    from mcap.writer import Writer

    with path.open("wb") as handle:
        writer = Writer(handle)
        writer.start(profile="ros2", library="test")
        schema = writer.register_schema("std_msgs/msg/Float64", "ros2msg", b"float64 data")
        channel = writer.register_channel("/s1/resistance", "cdr", schema)
        for t, data in zip(times, payloads, strict=True):
            writer.add_message(channel, log_time=t, data=data, publish_time=t)
        writer.finish()


def test_extreme_log_time_and_all_malformed_payloads_replay_cleanly(
        work: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    good = [b"\0\1\0\0" + np.float64(v).tobytes() for v in (10.0, 10.5, 11.0)]
    float64_bag(tmp_path / "late.mcap", [10**9, 2 * 10**9, 2**63 - 1], good)
    float64_bag(tmp_path / "malformed.mcap", [10**9 * k for k in range(1, 20)],
                [b"\x01\x02"] * 19)
    for name, words in (("late", "1 messages with a log time beyond 2^31 s"),
                        ("malformed", "19 malformed std_msgs/msg/Float64 messages")):
        out = tmp_path / f"{name}_out.mcap"
        code, _ = run(["replay", tmp_path / f"{name}.mcap", "--calibration", work / "cal.yaml",
                       "--out", out], capsys)
        assert code == 0
        assert any(words in p for p in read_bag(tmp_path / f"{name}.mcap").problems)
        readable(out)
    late = read_bag(tmp_path / "late.mcap").series["/s1/resistance"]
    np.testing.assert_array_equal(late.t, [1.0, 2.0])


# --------------------------------------------------------------------- command-line fuzz

def test_fuzz_command_line(tmp_path: Path) -> None:
    spec = importlib.util.spec_from_file_location("strain_comp_fuzz", ROOT / "scripts" /
                                                  "fuzz.py")
    fuzz = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = fuzz  # dataclasses look their module up
    spec.loader.exec_module(fuzz)
    stats = fuzz.fuzz_cli({"cubic": fitted("cubic")}, np.random.default_rng(0), tmp_path,
                          iterations=150)
    assert stats.runs == 150
    assert not stats.crashes, stats.crashes[:3]
    assert not stats.unexpected, stats.unexpected[:3]
    assert stats.exits.get(0, 0) >= 5 and stats.exits.get(2, 0) >= 50  # both paths exercised
