"""The session start (``strain-comp start``, ``offline.session_start.start``) the CLI, the API,
the loop and the benchmark share, against known truth: a sensor whose first load and unload
reads another sensitivity than the rest of the run (the first stretch after a long rest), a
run with one stretch only, and the recordings a start must refuse in one line saying what
to record instead."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

import strain_comp as sc
from strain_comp.cli import main
from strain_comp.core.calibration import Calibration
from strain_comp.diagnosis.session import session_errors
from strain_comp.errors import InputError
from strain_comp.io.bag.writer import BagWriter
from strain_comp.io.recording import Recording
from strain_comp.offline.evaluate import evaluate_recordings
from strain_comp.offline.fit import fit_sensor
from strain_comp.offline.session_start import start, start_or_keep

R0 = 100.0
"""Rest resistance [ohm] of the synthetic sensor."""


def triangles(t: np.ndarray) -> np.ndarray:
    """Strain [%]: a 5 s rest, then 0 -> 30 -> 0 % over 10 s, every 20 s."""
    return np.interp(t % 20.0, [0.0, 5.0, 10.0, 15.0, 20.0], [0.0, 0.0, 30.0, 0.0, 0.0])


def linear_run(t: np.ndarray, s: np.ndarray, gain: np.ndarray | float) -> Recording:
    """A linear sensor, R = R0 (1 + gain s / 100), with the reference ``s``."""
    return Recording("s1", t, R0 * (1.0 + gain * s / 100.0), s)


def write_bag(path: Path, rec: Recording) -> None:
    """One sensor's run as a bag."""
    assert rec.s is not None
    with BagWriter(path) as writer:
        writer.write_float64("/s1/resistance", rec.t, rec.r)
        writer.write_float64("/s1/strain_reference", rec.t, rec.s)


@pytest.fixture(scope="module")
def calibration() -> Calibration:
    t = np.arange(0.0, 100.0, 0.05)
    return Calibration({"s1": fit_sensor([linear_run(t, triangles(t), 1.0)], "cubic",
                                         name="s1")})


def test_the_start_reads_the_run_after_its_warm_up(calibration: Calibration) -> None:
    """Sensitivity 1.5 on the first stretch, 1.2 after it: the start finds the second
    stretch itself and reads the rest of the run as it is (the first stretch's error only);
    read on the first stretch (``--window 0:END``), the later strains read 1.2 / 1.5 = 0.8
    of the truth, an RMS error of 0.2 x RMS(s)."""
    t = np.arange(0.0, 120.0, 0.05)
    s = triangles(t)
    rec = linear_run(t, s, np.where(t < 14.55, 1.5, 1.2))  # the first return: 14.55 s
    started = start(calibration, {"s1": rec})
    assert started.window == pytest.approx((14.55, 34.55), abs=0.06)
    assert started.steps == ["input", "output"]
    (record,) = started.records
    assert record.rmse < 0.05 and "input zero" in record.correction
    later = t >= 14.55
    errors = session_errors(calibration, {"s1": rec}, "s1")
    assert np.sqrt(np.mean(errors[later] ** 2)) < 0.05  # % strain, against 30 % of travel
    first = start(calibration, {"s1": rec}, window=(0.0, 14.55))
    ev = evaluate_recordings({"s1": rec}, first.calibration).sensors["s1"]
    first_errors = (ev.estimate - ev.reference)[ev.scored]
    assert np.sqrt(np.mean(first_errors[later] ** 2)) == pytest.approx(
        0.2 * np.sqrt(np.mean(s[later] ** 2)), rel=0.2)


def test_a_run_with_one_stretch_is_started_on_it(calibration: Calibration) -> None:
    """One load and unload, then rest: there is no second stretch to read, the first is."""
    t = np.arange(0.0, 40.0, 0.05)
    s = np.where(t < 20.0, triangles(t), 0.0)
    rec = linear_run(t, s, 1.2)
    started = start(calibration, {"s1": rec})
    assert started.window is not None and started.window[0] == 0.0
    assert started.steps == ["input", "output"]
    errors = session_errors(calibration, {"s1": rec}, "s1")
    assert np.sqrt(np.mean(errors ** 2)) < 0.05


@pytest.mark.parametrize("reference, words", [
    (lambda t: np.zeros_like(t), "makes no stretch and return"),
    (lambda t: np.minimum(t, 30.0), "shorter than the warm-up"),
    (lambda t: np.interp(t, [0.0, 5.0, 10.0, 15.0, 20.0, 40.0, 60.0],
                         [0.0, 0.0, 30.0, 0.0, 0.0, 45.0, 20.0]),
     "never came back to rest after its largest strain"),
])
def test_a_recording_a_start_cannot_read_is_refused(
        calibration: Calibration, reference: Callable[[np.ndarray], np.ndarray],
        words: str) -> None:
    """Flat, ending during the first stretch, or never back to rest after its largest
    strain: one line in the user's terms saying what to record, no internal field name;
    ``start_or_keep`` leaves the calibration as it is."""
    t = np.arange(0.0, 60.0, 0.05)
    s = reference(t)
    rec = linear_run(t, s, 1.2)
    with pytest.raises(InputError, match=words) as found:
        start(calibration, {"s1": rec}, source="start.mcap")
    text = str(found.value)
    assert "record one stretch and back" in text and "\n" not in text
    assert "sensors." not in text and "zero_span" not in text
    kept = start_or_keep(calibration, {"s1": rec})
    assert kept.window is None and kept.calibration is calibration


def test_the_command_and_the_api_start_alike(calibration: Calibration, tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    """``strain-comp start`` prints one line per sensor (the stretch, the correction, the
    RMSE on it) and writes what ``sc.session_start`` returns; a recording it refuses exits 2
    with one line and writes nothing."""
    t = np.arange(0.0, 80.0, 0.05)
    s = triangles(t)
    bag, cal = tmp_path / "start.mcap", tmp_path / "cal.yaml"
    write_bag(bag, linear_run(t, s, 1.3))
    sc.save_calibration(calibration, cal)
    out = tmp_path / "today.yaml"
    assert main(["start", str(cal), str(bag), "--out", str(out), "-q"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    api = sc.session_start(cal, str(bag))
    assert lines == api.readings and len(lines) == 1
    assert lines[0].startswith("s1: stretch 14.55-34.55 s, input zero") and "RMSE" in lines[0]
    assert sc.load_calibration(out).to_dict() == api.calibration.to_dict()
    flat = tmp_path / "flat.mcap"
    write_bag(flat, linear_run(t, np.zeros_like(t), 1.3))
    refused = tmp_path / "refused.yaml"
    assert main(["start", str(cal), str(flat), "--out", str(refused)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("strain-comp: error: ")
    assert "record one stretch and back" in err[0] and not refused.exists()
