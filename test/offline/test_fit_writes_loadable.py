"""Whatever ``fit``, ``recalibrate`` and ``diagnose`` write, every reader loads: the writer
applies the loader's checks (``core.calibration_file.check_calibration``) and a fit that would
not load is repaired or refused with one line, never written."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from strain_comp.cli import main
from strain_comp.core.calibration import Calibration
from strain_comp.core.calibration_file import (
    calibration_text,
    check_calibration,
    load_calibration,
    save_calibration,
)
from strain_comp.errors import CalibrationError
from strain_comp.io.recording import Recording, write_recordings
from strain_comp.models.sinh_pl import _cell_step

ERROR = "strain-comp: error: "


def triangles(seed: int, *, amplitude: float, rest: float, gain: float, curve: float,
              lag: float, noise: float, rate: float) -> Recording:
    """Triangles 0 -> amplitude % at ``rate`` Hz for 60 s: R = rest (1 + gain x + curve
    x^2) with x the strain lagging the reference by ``lag`` s (a loop), plus noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 60.0, 1.0 / rate)
    s = amplitude * (1.0 - np.abs((t / 10.0) % 2.0 - 1.0))
    x = np.interp(t - lag, t, s) / 100.0
    r = rest * (1.0 + gain * x + curve * x * x) * (1.0 + noise * rng.standard_normal(t.size))
    return Recording("s1", t, r, s)


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 1000), model=st.sampled_from(["cubic", "sinh_pl", "rational", "mpi"]),
       amplitude=st.floats(2.0, 80.0), rest=st.floats(0.5, 2e6), gain=st.floats(-0.8, 3.0),
       curve=st.floats(-1.0, 2.0), lag=st.floats(0.0, 2.0), noise=st.floats(0.0, 0.01),
       rate=st.sampled_from([1.0, 10.0, 50.0]))
def test_whatever_fit_writes_evaluate_loads(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                            seed: int, model: str, amplitude: float,
                                            rest: float, gain: float, curve: float, lag: float,
                                            noise: float, rate: float) -> None:
    if abs(gain) < 0.05:
        gain = 0.05  # a sensor whose resistance does not follow strain has nothing to fit
    rec = triangles(seed, amplitude=amplitude, rest=rest, gain=gain, curve=curve, lag=lag,
                    noise=noise, rate=rate)
    bag, cal = tmp_path / f"r{seed}.mcap", tmp_path / f"c{seed}_{model}.yaml"
    cal.unlink(missing_ok=True)
    write_recordings({rec.name: rec}, bag)
    capsys.readouterr()
    code = main(["fit", str(bag), "--model", model, "--sensor", "s1", "--out", str(cal), "-q"])
    err = capsys.readouterr().err
    if code != 0:  # refused: one line, nothing written
        assert code == 2 and err.startswith(ERROR) and len(err.strip().splitlines()) == 1
        assert not cal.exists()
        return
    load_calibration(cal)
    assert main(["evaluate", str(bag), "--calibration", str(cal), "-q"]) == 0


def test_sinh_pl_on_the_fibre_runs_writes_what_evaluate_loads(
        measured_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Fibre runs 1 and 3: the sinh_pl fit's steep cells (I_S 2e4, V_T 0.006) used to give
    inf / inf in the cell step at a resistance outside the data, and every reader refused
    the file it wrote. The training RMSE fit prints is the RMSE evaluate gives."""
    for run in (1, 3):
        csv = measured_data / "conductive_fiber" / f"oldthread_sensorfiber_5x_{run}_synced.csv"
        bag, cal = tmp_path / f"f{run}.mcap", tmp_path / f"f{run}.yaml"
        assert main(["import-csv", str(csv), "--out", str(bag), "--sensor", "s1",
                     "--format", "fiber", "-q"]) == 0
        capsys.readouterr()
        assert main(["fit", str(bag), "--model", "sinh_pl", "--sensor", "s1", "--out", str(cal),
                     "--strain-unit", "mm", "-q"]) == 0
        fit_rmse = load_calibration(cal).sensors["s1"].provenance["fit_rmse"]
        capsys.readouterr()
        assert main(["evaluate", str(bag), "--calibration", str(cal), "-q"]) == 0
        row = capsys.readouterr().out.splitlines()[2].split()
        assert row[0] == "s1" and float(row[3]) == pytest.approx(fit_rmse, abs=6e-5)


def test_steep_sinh_cell_step_is_finite_and_tends_to_its_limit() -> None:
    """u' = I_S (e^x - e^-x), one linearly implicit step: du = dt g / (1 + dt g'). For large
    |x| both overflow; the step tends to V_T tanh(x) (g / g'), which it must give, and for
    moderate x it equals the formula evaluated directly."""
    for x in (0.3, -2.0, 40.0, -150.0):
        i_s, v_t, dt = 0.7, 0.05, 0.1
        g = i_s * (math.exp(x) - math.exp(-x))
        gp = i_s / v_t * (math.exp(x) + math.exp(-x))
        u_new, _ = _cell_step(0.0, x * v_t, dt, i_s, v_t)
        assert u_new == pytest.approx(dt * g / (1.0 + dt * gp), rel=1e-12)
    for x in (700.0, 5000.0, -5000.0):
        i_s, v_t = 22022.3, 0.00597
        u_new, slope = _cell_step(0.0, x * v_t, 1.0, i_s, v_t)
        assert math.isfinite(u_new) and math.isfinite(slope)
        assert u_new == pytest.approx(math.copysign(v_t, x), rel=1e-9)


def test_refused_writes_name_the_problem_in_the_users_terms(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A microstrain reference beyond what a calibration holds, and a
    recalibration through a strain of 1e300: one line, exit 2, nothing written."""
    rec = triangles(1, amplitude=10.0, rest=1000.0, gain=2.0, curve=0.0, lag=0.5, noise=0.0,
                    rate=10.0)
    micro = Recording("s1", rec.t, rec.r, rec.s * 1e6)  # 0 to 1e7: beyond +/- 1e6
    write_recordings({micro.name: micro}, tmp_path / "ue.mcap")
    write_recordings({rec.name: rec}, tmp_path / "pct.mcap")
    cases = [
        (["fit", str(tmp_path / "ue.mcap"), "--model", "cubic", "--sensor", "s1",
          "--strain-unit", "ue", "--out", str(tmp_path / "ue.yaml")], "ue.yaml",
         "import-csv --scales strain=1e-4"),
    ]
    assert main(["fit", str(tmp_path / "pct.mcap"), "--model", "cubic", "--sensor", "s1",
                 "--out", str(tmp_path / "pct.yaml"), "-q"]) == 0
    lo, hi = load_calibration(tmp_path / "pct.yaml").sensors["s1"].valid_range.r_lo, \
        load_calibration(tmp_path / "pct.yaml").sensors["s1"].valid_range.r_hi
    cases.append((["recalibrate", str(tmp_path / "pct.yaml"), "--point", f"{lo * 1.01}:0",
                   "--point", f"{hi * 0.99}:1e300", "--out", str(tmp_path / "re.yaml")],
                  "re.yaml", "must be within"))
    cases.append((["recalibrate", str(tmp_path / "pct.yaml"), "--point", f"{lo * 1.01}:0",
                   "--point", f"{lo * 1.0101}:900000", "--out", str(tmp_path / "re2.yaml")],
                  "re2.yaml", None))
    for argv, out, words in cases:
        capsys.readouterr()
        code = main(argv)
        err = capsys.readouterr().err
        if words is None:  # a steep but storable map: written, and it loads
            assert code == 0 and load_calibration(tmp_path / out)
            continue
        assert code == 2 and err.startswith(ERROR) and len(err.strip().splitlines()) == 1
        assert words in err and not (tmp_path / out).exists()


def test_save_calibration_refuses_what_load_would_refuse(tmp_path: Path) -> None:
    """One validation for writer and reader: the field the loader names, the writer names,
    before anything is written; check=False writes it (for tests of the loader)."""
    from dataclasses import replace

    from conftest import make_calibration

    good = make_calibration()
    check_calibration(good)
    bad = Calibration({n: replace(c, effects=[{"name": "o", "kind": "offset", "params": {},
                                               "coef": 1e300}])
                       for n, c in good.sensors.items()})
    with pytest.raises(CalibrationError) as written:
        save_calibration(bad, tmp_path / "bad.yaml")
    assert not (tmp_path / "bad.yaml").exists() and "not written" in str(written.value)
    (tmp_path / "bad.yaml").write_text(calibration_text(bad))
    with pytest.raises(CalibrationError) as loaded:
        load_calibration(tmp_path / "bad.yaml")
    assert loaded.value.field == written.value.field == "sensors.left.effects.0.coef"
