"""The residual loop names creep where a calibration lacks it, and adds nothing where
there is none (docs/results.md, "Residual loop").

A virtual-rig run (``rig.simulate``, viscous branches off) gets a known creep: one Prony
state added to its resistance, R' = R - w (R - z), z' = (R - z) / tau (after a change the
resistance has moved only 1 - w of the way, and creeps the rest with time constant tau).
The calibration is a cubic fitted on a clean run. ``diagnose`` works on one creeping run,
scores its terms on two others after their own session start, and the result is judged
on a fourth run it never saw, after that run's session start.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from strain_comp.core.calibration import Calibration
from strain_comp.diagnosis.loop import diagnose
from strain_comp.diagnosis.session import session_errors
from strain_comp.io.recording import Recording
from strain_comp.offline.fit import fit_sensor
from strain_comp.offline.rig import RigEffects, simulate

CLEAN = {"hysteresis": 0.0, "relaxation": 0.0}
MIN_DROP = 0.25
"""Least fall of a later run's error after its session start when creep is added."""


def prony_creep(t: np.ndarray, r: np.ndarray, tau: float, weight: float) -> np.ndarray:
    """R - weight (R - z), z the first-order low-pass of R with ``tau`` [s] (exact for a
    piecewise-constant R, z starting at R[0]): a slow loop, independent of the engine."""
    z = np.empty_like(r)
    z[0] = r[0]
    for k in range(1, r.size):
        z[k] = r[k - 1] + (z[k - 1] - r[k - 1]) * math.exp(-(t[k] - t[k - 1]) / tau)
    return r - weight * (r - z)


def run(scenario: str, seed: int, tau: float | None = None, weight: float = 0.0
        ) -> dict[str, Recording]:
    sim = simulate(scenario, seed=seed, effects=RigEffects(**CLEAN))["s1"]
    r = sim.r if tau is None else prony_creep(sim.t, sim.r, tau, weight)
    return {"s1": Recording("s1", sim.t, r, sim.s)}


def after_session_start(calibration: Calibration, recordings: dict[str, Recording]) -> float:
    """RMSE of s1 after the session-start recalibration after the run's warm-up stretch."""
    return float(np.sqrt(np.mean(session_errors(calibration, recordings, "s1") ** 2)))


@pytest.fixture(scope="module")
def calibration() -> Calibration:
    return Calibration({"s1": fit_sensor([run("patterns", 0)["s1"]], "cubic", name="s1")})


@pytest.mark.parametrize("tau", [5.0, 30.0])
def test_a_creep_the_calibration_lacks_is_named_and_carries(calibration: Calibration,
                                                            tau: float) -> None:
    weight = 0.2
    result = diagnose(run("random", 2, tau, weight), calibration,
                      validate_recordings=[run("steps", 3, tau, weight),
                                           run("patterns", 4, tau, weight)])
    first = result.added[0]
    assert first.to_json()["family"] == "creep", result.summary()
    read = float(first.params["tau"])
    assert tau / 2 <= read <= 2 * tau, result.summary()
    record = first.to_json()
    assert record["family"] == "creep" and record["time_constant"] == read
    reading = record["reading"]
    assert reading.startswith(f"creep (Prony series, tau = {read:g} s"), reading
    assert "lags the reference" in reading and "% of the span" in reading, reading
    assert f"creep, tau {read:g} s" in result.sensors["s1"].message
    later = run("steps", 5, tau, weight)
    before = after_session_start(calibration, later)
    after = after_session_start(result.calibration, later)
    print(f"creep tau {tau:g} s: read {read:g} s; later run after its session start "
          f"{before:.4f} -> {after:.4f} %")
    assert after <= (1 - MIN_DROP) * before


def test_no_creep_adds_nothing_and_says_why(calibration: Calibration) -> None:
    result = diagnose(run("random", 2), calibration,
                      validate_recordings=[run("steps", 3), run("patterns", 4)])
    assert not result.added, result.summary()
    message = result.sensors["s1"].message
    assert message.startswith("after the session start, what remains on the validation runs "
                              "is ") and message.endswith("nothing added"), message
    assert ";" not in message and len(message) < 250, message  # one line, one reason
    reading = result.sensors["s1"].session["reading"]
    assert "after the session start, what remains is" in reading, reading


def test_creep_readings_say_which_way_how_much_and_how_slow() -> None:
    from strain_comp.diagnosis.report import creep_tau, effect_reading

    assert effect_reading("relaxation", {"tau": 8.0, "branch": "both"}, -0.05, 1.0,
                          span=50.0) == (
        "creep (Prony series, tau = 8 s, a state of the estimate): the estimate lags the "
        "reference after each change by typically 2 % of the span (1 % strain), catching "
        "up with a time constant of 8 s")
    assert "overshoots the reference" in effect_reading(
        "resistance_memory", {"tau": 45.25, "form": "relaxation"}, 0.1, 2.0, unit="mm",
        span=70.0, lag=False)
    assert creep_tau("relaxation", {"tau": 4.0, "branch": "loading"}) is None
    assert creep_tau("resistance_memory", {"tau": 4.0, "form": "peak"}) is None


def test_a_term_that_raises_one_validation_run_beyond_the_margin_is_not_kept() -> None:
    """Two of three validation runs 10 % better, the third 10 % worse: the pooled and the
    median error fall, and still the term does not carry; 2 % worse is within the margin."""
    from strain_comp.diagnosis.selection import held_out_better

    runs = np.repeat([0, 1, 2], 100)
    old = np.ones(300)
    assert held_out_better(old * np.repeat([0.9, 0.9, 1.02], 100), old, 0.03, runs)
    worse = old * np.repeat([0.8, 0.8, 1.1], 100)
    assert held_out_better(worse, old, 0.03)  # pooled alone it would pass
    assert not held_out_better(worse, old, 0.03, runs)


def carried_case(shares: tuple[float, ...], seed: int = 0) -> tuple[Any, Any]:
    """A fit residual e = 2 g + noise over 10 folds, and validation runs in which the same
    regressor explains ``shares[k]`` of the term (run k's e = 2 shares[k] g + noise)."""
    from strain_comp.diagnosis.selection import Gram, linear_held_out

    rng = np.random.default_rng(seed)
    n = 2000
    g_fit = np.column_stack([np.ones(n), rng.standard_normal(n)])
    e_fit = 2.0 * g_fit[:, 1] + 0.3 * rng.standard_normal(n)
    gram = Gram(g_fit, e_fit, np.repeat(np.arange(10), n // 10), 10)
    g_val = np.column_stack([np.ones(n * len(shares)), rng.standard_normal(n * len(shares))])
    share = np.repeat(shares, n)
    e_val = 2.0 * share * g_val[:, 1] + 0.3 * rng.standard_normal(share.size)
    runs = np.repeat(np.arange(len(shares)), n)
    held_out = linear_held_out(e_val, g_val)
    return gram, lambda cols, coef: [held_out(cols, coef)[runs == k] for k in range(len(shares))]


def test_a_term_is_added_only_where_it_carries_beyond_the_spread_between_runs() -> None:
    """The term explains both validation runs: added, with its coefficient (2); it explains
    one run and harms the other: not added, and the refused candidate says what it did to
    each; with one validation run: not added (no spread to judge by)."""
    from strain_comp.diagnosis.selection import select_carried, upper_bound

    gram, held_out = carried_case((1.0, 0.9))
    found = select_carried(gram, 2, 0, held_out)
    assert found.selection.chosen == [1] and found.refused is None
    assert found.coef[1] == pytest.approx(2.0, rel=0.02)
    gram, held_out = carried_case((1.0, 0.0))
    found = select_carried(gram, 2, 0, held_out)
    assert found.selection.chosen == [] and found.refused is not None
    down, up = found.refused.log_ratios
    assert down < math.log(0.5) and up > math.log(2.0)
    # the prediction bound of one more run from two: Student's t with one degree of
    # freedom is Cauchy, t(0.95, 1) = tan(0.45 pi); sd sqrt(1 + 1/2)
    assert found.refused.bound == pytest.approx(np.mean([down, up]) + math.tan(0.45 * math.pi)
                                                * np.std([down, up], ddof=1) * math.sqrt(1.5))
    gram, held_out = carried_case((1.0,))
    found = select_carried(gram, 2, 0, held_out)
    assert found.selection.chosen == [] and found.refused is not None
    assert found.refused.log_ratios[0] < math.log(0.5)  # it helps, but one run shows no spread
    assert upper_bound([-0.1], 0.95) == math.inf
