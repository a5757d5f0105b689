"""``fit --model auto`` (``offline.fit``) against known truth: runs of a sensor with
no memory and a sensitivity that differs from run to run, each candidate's error on every
run left out recomputed by hand (fit on the others, ``start``, ``evaluate``), the tie to
the simpler model, groups left out whole, one run, and every candidate failing."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import strain_comp as sc
from strain_comp.cli import main
from strain_comp.core.calibration import Calibration, expected_error
from strain_comp.errors import FitError
from strain_comp.io.bag.writer import BagWriter
from strain_comp.io.recording import Recording
from strain_comp.offline import fit
from strain_comp.offline.evaluate import evaluate_recordings
from strain_comp.offline.fit import fit_sensor
from strain_comp.offline.session_start import start

GAINS = (1.0, 1.1, 0.9, 1.05)
"""Sensitivity of each run (R = 100 (1 + g s / 100 + 0.002 s^2 / 100))."""


def run(gain: float) -> Recording:
    """A static, slightly curved sensor over triangles 0 -> 30 -> 0 % every 20 s."""
    t = np.arange(0.0, 80.0, 0.1)
    s = np.interp(t % 20.0, [0.0, 5.0, 10.0, 15.0, 20.0], [0.0, 0.0, 30.0, 0.0, 0.0])
    return Recording("s1", t, 100.0 * (1.0 + gain * s / 100.0 + 0.002 * s * s / 100.0), s)


RUNS = [run(g) for g in GAINS]


def left_out(model: str, held: list[int]) -> list[float]:
    """The candidate's RMSE on each held run, by hand: fitted on the others, started,
    evaluated."""
    rest = [r for i, r in enumerate(RUNS) if i not in held]
    cal = Calibration({"s1": fit_sensor(rest, model, name="s1")})
    out = []
    for i in held:
        started = start(cal, {"s1": RUNS[i]}).calibration
        out.append(evaluate_recordings({"s1": RUNS[i]}, started).sensors["s1"].stats.rmse)
    return out


def test_each_run_left_out_is_scored_after_start_and_the_lowest_median_wins() -> None:
    """Every candidate's errors are its RMSE on each run left out after ``start``; the
    chosen model has the lowest median, or is a simpler one within 2 % of it; the
    calibration carries the table and its median and worst as the error to expect."""
    cal = sc.fit(RUNS, "auto", candidates="cubic,creep_pi")
    prov = cal.sensors["s1"].provenance
    table = prov["model_choice"]["candidates"]
    for model in ("cubic", "creep_pi"):
        expected = [left_out(model, [i])[0] for i in range(len(RUNS))]
        assert table[model]["errors"] == pytest.approx(expected, rel=1e-5, abs=1e-6)
        assert table[model]["median"] == pytest.approx(np.median(expected), abs=1e-6)
        assert table[model]["worst"] == pytest.approx(max(expected), abs=1e-6)
    chosen = prov["model_choice"]["chosen"]
    best = min(c["median"] for c in table.values())
    assert table[chosen]["median"] <= (1.0 + fit.TIE) * best
    assert cal.sensors["s1"].model == chosen
    found = expected_error(cal.sensors["s1"])
    assert found is not None and found["median"] == table[chosen]["median"]
    assert found["worst"] == table[chosen]["worst"] and found["runs"] == len(RUNS)
    assert found["unit"] == "%"


def test_a_tie_goes_to_the_simpler_model(monkeypatch: pytest.MonkeyPatch) -> None:
    """Medians 1.00 (apl) and 1.015 (cubic): within 2 %, the cubic; 1.03: apl."""
    for cubic, chosen in ((1.015, "cubic"), (1.03, "apl")):
        def errors(recordings: object, name: str, fold: fit.Fold, options: object,
                   pool: str, cubic: float = cubic) -> fit.Scored:
            return fit.Scored([cubic if fold.model == "cubic" else 1.0]
                                       * len(fold.held), [Calibration({})] * len(fold.held))

        monkeypatch.setattr(fit, "fold_errors", errors)
        model, record, _ = fit.choose_model(RUNS, "s1", candidates=("apl", "cubic"))
        assert model == chosen, cubic
        assert "simpler" in record["why"] if chosen == "cubic" else "lowest" in record["why"]


def test_the_band_is_learned_from_the_choices_folds_not_fitted_again(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The uncertainty of ``--model auto`` is the one its folds give when the runs form one
    group (each run left out after the choice; weight for weight), yet the chosen model is
    fitted once per fold and once on every run (before: twice per fold; the input space's
    own cubic fits, ``pool="stretch"``, not counted)."""
    runs = [Recording("s1", rec.t, rec.r + np.random.default_rng(i).normal(0.0, 0.2,
                                                                          rec.t.size), rec.s)
            for i, rec in enumerate(RUNS)]
    fits: list[str] = []

    def counted(*args: object, **kwargs: object) -> object:
        if kwargs.get("pool", "spanned") == "spanned":
            fits.append(str(args[1]))
        return fit_sensor(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(fit, "fit_sensor", counted)
    cal = fit.fit_auto(runs, name="s1", candidates=("cubic",))
    assert fits.count("cubic") == len(runs) + 1
    again = fit.fit_auto(runs, name="s1", candidates=("cubic",),
                                  groups=["a"] * len(runs))
    assert cal.uncertainty is not None and again.uncertainty is not None
    assert cal.uncertainty == again.uncertainty
    assert cal.uncertainty.runs == len(runs)


def test_groups_are_left_out_whole() -> None:
    """Groups a, a, b, b: each run of group a is scored by the model fitted on b alone."""
    model, record, _ = fit.choose_model(RUNS, "s1", candidates=("cubic",),
                                                 groups=["a", "a", "b", "b"])
    assert model == "cubic" and record["groups"] == ["a", "a", "b", "b"]
    errors = record["candidates"]["cubic"]["errors"]
    assert errors == pytest.approx(left_out("cubic", [0, 1]) + left_out("cubic", [2, 3]),
                                   rel=1e-5, abs=1e-6)


def test_one_run_fits_the_benchmarks_model_and_says_why() -> None:
    """Nothing to leave out: the first of ``ONE_RUN_ORDER`` among the candidates, with the
    reason; no error to expect."""
    cal = sc.fit([RUNS[0]], "auto", candidates="cubic,creep_pi")
    assert cal.sensors["s1"].model == "creep_pi"
    assert "nothing to leave out" in cal.sensors["s1"].provenance["model_choice"]["why"]
    assert expected_error(cal.sensors["s1"]) is None


def test_every_candidate_failing_is_one_line_and_nothing_written(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    bags = []
    for i, rec in enumerate(RUNS[:3]):
        bags.append(str(tmp_path / f"run{i}.mcap"))
        assert rec.s is not None
        with BagWriter(bags[-1]) as writer:
            writer.write_float64("/s1/resistance", rec.t, rec.r)
            writer.write_float64("/s1/strain_reference", rec.t, rec.s)

    def fails(recordings: object, name: str, fold: fit.Fold, options: object,
              pool: str) -> str:
        return f"{fold.model} cannot be fitted"

    monkeypatch.setattr(fit, "fold_errors", fails)
    out = tmp_path / "cal.yaml"
    assert main(["fit", *bags, "--model", "auto", "--candidates", "cubic,mpi", "--sensor",
                 "s1", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no candidate could be fitted" in err[0] and not out.exists()
    with pytest.raises(FitError):
        fit.choose_model(RUNS, "s1", candidates=("cubic",))
