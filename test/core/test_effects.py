"""Effect regressors: sample by sample == in batches (state carried), the equations against
slow pure-Python references, calibration-dict round trip and validation errors."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from strain_comp.core.calibration import MAX_SENSOR_EFFECTS
from strain_comp.core.calibration_file import (
    calibration_text,
    load_calibration,
    save_calibration,
)
from strain_comp.core.effects import (
    KINDS,
    Batch,
    EffectTerms,
    regressor_from_dict,
    validate_effect_dict,
)
from strain_comp.diagnosis.candidates import default_candidates
from strain_comp.errors import CalibrationError, ParameterError


def random_inputs(n: int = 400, seed: int = 0) -> Batch:
    """Irregular times, a wandering strain, a flickering direction, gappy side inputs."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.01, 0.5, n))
    s_hat = np.cumsum(rng.normal(0, 0.5, n))
    direction = np.sign(np.round(rng.normal(0, 1.0, n)))
    temperature = 25 + np.cumsum(rng.normal(0, 0.1, n))
    temperature[rng.random(n) < 0.2] = np.nan
    temperature[:5] = np.nan
    nb = s_hat * 0.3 + rng.normal(0, 0.1, n)
    nb[rng.random(n) < 0.1] = np.nan
    return Batch.of(t, 100 + s_hat, s_hat, direction, temperature, {"left": nb})


ALL = [*default_candidates(temperature_ref=24.0, neighbours=["left"], stretch_history=True),
       {"name": "x", "kind": "elapsed", "params": {}, "coef": 0.0}]


@pytest.mark.parametrize("effect", ALL, ids=[e["name"] for e in ALL])
def test_run_continues_state_sample_by_sample_and_across_batches(effect: dict) -> None:
    """Batches of one (as the engine runs online), two halves and the whole agree."""
    b = random_inputs()

    def part(k: slice) -> Batch:
        return Batch.of(b.t[k], b.r[k], b.s_hat[k], b.direction[k], b.temperature[k],
                        {"left": b.neighbours["left"][k]})

    g_step = regressor_from_dict(effect)
    stepped = np.concatenate([g_step.run(part(slice(k, k + 1))) for k in range(b.t.size)])
    g_run = regressor_from_dict(effect)
    half = b.t.size // 2
    ran = np.concatenate([g_run.run(part(slice(None, half))),
                          g_run.run(part(slice(half, None)))])
    assert np.all(np.isfinite(ran))
    np.testing.assert_allclose(ran, stepped, rtol=1e-12, atol=1e-12)
    g_run.reset()
    np.testing.assert_allclose(g_run.run(b), stepped, rtol=1e-12, atol=1e-12)


def test_relaxation_matches_first_order_filter() -> None:
    """h = S_hat - x with x' = (S_hat - x)/tau, exact for a piecewise-constant S_hat."""
    b = random_inputs(seed=3)
    tau = 4.0
    g = regressor_from_dict({"name": "r", "kind": "relaxation", "params": {"tau": tau},
                             "coef": 0.0}).run(b)
    x = b.s_hat[0]
    ref = [0.0]
    for k in range(1, b.t.size):
        # S_hat held at s[k-1] over (t[k-1], t[k]], then jumps to s[k]
        x = b.s_hat[k - 1] + (x - b.s_hat[k - 1]) * math.exp(-(b.t[k] - b.t[k - 1]) / tau)
        ref.append(b.s_hat[k] - x)
    np.testing.assert_allclose(g, ref, atol=1e-9)
    loading = regressor_from_dict({"name": "l", "kind": "relaxation",
                                   "params": {"tau": tau, "branch": "loading"}, "coef": 0})
    unloading = regressor_from_dict({"name": "u", "kind": "relaxation",
                                     "params": {"tau": tau, "branch": "unloading"}, "coef": 0})
    moving = b.direction != 0
    both = loading.run(b) + unloading.run(b)
    # with every increment made while moving, the two branches add up to the plain filter
    b2 = Batch.of(b.t, b.r, b.s_hat, np.where(moving, b.direction, 1.0))
    loading.reset()
    unloading.reset()
    np.testing.assert_allclose(loading.run(b2) + unloading.run(b2), g, atol=1e-9)
    assert not np.allclose(both, g)


def test_rate_tracks_a_ramp_and_mullins_counts_cycles() -> None:
    t = np.arange(0, 60, 0.1)
    s = 2.0 * t
    rate = regressor_from_dict({"name": "r", "kind": "rate", "params": {"tau": 1.0},
                                "coef": 0}).run(Batch.of(t, s, s, np.ones_like(t)))
    assert rate[-1] == pytest.approx(2.0, rel=1e-9)
    # three triangle cycles: +1 up, -1 down; a cycle completes at each down -> up turn
    d = np.tile(np.r_[np.ones(10), np.zeros(3), -np.ones(10)], 3)
    s = np.cumsum(d)
    tt = np.arange(d.size, dtype=float)
    g = regressor_from_dict({"name": "m", "kind": "mullins",
                             "params": {"form": "cycles_log"}, "coef": 0}).run(
        Batch.of(tt, s, s, d))
    cycles = np.r_[np.zeros(23), np.ones(23), 2 * np.ones(23)]
    np.testing.assert_allclose(g, s * np.log1p(cycles))
    gap = regressor_from_dict({"name": "m", "kind": "mullins", "params": {"form": "gap"},
                               "coef": 0}).run(Batch.of(tt, s, s, d))
    np.testing.assert_allclose(gap, np.maximum.accumulate(s) - s)


def test_effect_terms_correct() -> None:
    b = random_inputs(seed=5)
    effects = [{"name": "drift", "kind": "elapsed", "params": {"form": "sqrt", "scale": 50.0},
                "coef": 0.25},
               {"name": "ct", "kind": "crosstalk", "params": {"neighbour": "left"}, "coef": -0.1},
               {"name": "offset", "kind": "offset", "params": {}, "coef": 0.5}]
    terms = EffectTerms.from_dicts(effects)
    assert terms.neighbours == ["left"]
    out = terms.run(b.t, b.r, b.s_hat, b.direction, b.temperature, b.neighbours)
    nb = b.neighbours["left"]
    held = np.array([nb[: k + 1][np.isfinite(nb[: k + 1])][-1]
                     if np.isfinite(nb[: k + 1]).any() else 0.0 for k in range(nb.size)])
    expected = b.s_hat - 0.25 * np.sqrt((b.t - b.t[0]) / 50.0) + 0.1 * held - 0.5
    np.testing.assert_allclose(out, expected, atol=1e-12)


def test_every_kind_round_trips_through_a_calibration_file(tmp_path: Path) -> None:
    from conftest import make_calibration

    cal = make_calibration()
    first: dict[str, dict[str, Any]] = {}
    for e in ALL[:-1]:
        if e["kind"] != ALL[-1]["kind"]:
            first.setdefault(e["kind"], e)
    one_per_kind = [*first.values(), ALL[-1]]  # last: "elapsed", params left to the defaults
    assert len(one_per_kind) <= MAX_SENSOR_EFFECTS  # the per-sensor budget of a file
    effects = [dict(e, coef=0.125 * i) for i, e in enumerate(one_per_kind)]
    assert {e["kind"] for e in effects} == set(KINDS)
    cal.sensors["right"].effects = effects  # the cross-talk term reads "left"
    save_calibration(cal, tmp_path / "c.yaml")
    loaded = load_calibration(tmp_path / "c.yaml")
    assert loaded.sensors["right"].effects == effects
    again = [regressor_from_dict(e).params() for e in loaded.sensors["right"].effects]
    assert again[:-1] == [e["params"] for e in effects[:-1]]
    # params: {} takes every default, and params() writes them out
    assert again[-1] == {"form": "linear", "scale": 100.0}


@pytest.mark.parametrize(("effect", "field"), [
    ({"name": "a", "kind": "nope", "coef": 1.0}, "kind"),
    ({"name": "a", "kind": "relaxation", "params": {"tau": -1.0}, "coef": 1.0}, "params.tau"),
    ({"name": "a", "kind": "relaxation", "params": {"branch": "up"}, "coef": 1.0},
     "params.branch"),
    ({"name": "a", "kind": "relaxation", "params": {"taux": 1.0}, "coef": 1.0}, "params.taux"),
    ({"name": "a", "kind": "crosstalk", "params": {}, "coef": 1.0}, "params.neighbour"),
    ({"name": "a", "kind": "strain_level", "params": {"power": 4}, "coef": 1.0},
     "params.power"),
    ({"name": "a", "kind": "direction", "params": {"hold": "yes"}, "coef": 1.0}, "params.hold"),
    ({"name": "a", "kind": "temperature", "params": {"t_ref": "hot"}, "coef": 1.0},
     "params.t_ref"),
    ({"name": "a", "kind": "offset", "params": [], "coef": 1.0}, "params"),
    ({"name": "a", "kind": "offset"}, "coef"),
    ({"name": "a", "kind": "offset", "coef": float("nan")}, "coef"),
])
def test_bad_effect_entries_name_the_field(tmp_path: Path, effect: dict, field: str) -> None:
    with pytest.raises(ParameterError) as err:
        validate_effect_dict(effect)
    assert err.value.field == field
    from conftest import make_calibration

    cal = make_calibration()
    cal.sensors["right"].effects = [{"name": "ok", "kind": "offset", "params": {}, "coef": 1.0},
                                    effect]
    with pytest.raises(CalibrationError) as serr:  # the writer applies the reader's checks
        save_calibration(cal, tmp_path / "bad.yaml")
    assert serr.value.field == f"sensors.right.effects.1.{field}"
    assert not (tmp_path / "bad.yaml").exists()
    (tmp_path / "bad.yaml").write_text(calibration_text(cal))
    with pytest.raises(CalibrationError) as cerr:
        load_calibration(tmp_path / "bad.yaml")
    assert cerr.value.field == serr.value.field


def test_baseline_captures_the_start_of_each_run() -> None:
    """g = running mean of S_hat over the first ``window`` s, then held, minus ``rest``;
    captured again after ``reset`` (the engine resets it at a gap)."""
    b = random_inputs(seed=7)
    window, rest = 3.0, 0.5
    g = regressor_from_dict({"name": "b", "kind": "baseline",
                             "params": {"window": window, "rest": rest}, "coef": 1.0})
    out = g.run(b)
    inside = b.t - b.t[0] <= window
    ref = [np.mean(b.s_hat[: k + 1][inside[: k + 1]]) - rest for k in range(b.t.size)]
    np.testing.assert_allclose(out, ref, rtol=1e-12)
    assert np.all(out[~inside] == out[~inside][0])
    g.reset()
    later = Batch.of(b.t[100:], b.r[100:], b.s_hat[100:], b.direction[100:])
    again = g.run(later)
    assert again[0] == pytest.approx(b.s_hat[100] - rest)


def test_mullins_peak_strain_and_direction_of_the_previous_sample() -> None:
    b = random_inputs(seed=9)
    peak = regressor_from_dict({"name": "m", "kind": "mullins",
                                "params": {"form": "peak_strain"}, "coef": 0}).run(b)
    np.testing.assert_allclose(peak, b.s_hat * np.maximum.accumulate(b.s_hat))
    d = regressor_from_dict({"name": "d", "kind": "direction", "params": {}, "coef": 0}).run(b)
    np.testing.assert_array_equal(d, np.r_[0.0, b.direction[:-1]])
    held = regressor_from_dict({"name": "d", "kind": "direction", "params": {"hold": True},
                                "coef": 0}).run(b)
    last, ref = 0.0, []
    for x in b.direction:  # the last moving direction up to the previous sample
        ref.append(last)
        last = x if x != 0 else last
    np.testing.assert_array_equal(held, ref)


def _memory(form: str, tau: float, b: Batch, r: np.ndarray) -> np.ndarray:
    g = regressor_from_dict({"name": "m", "kind": "resistance_memory",
                             "params": {"tau": tau, "form": form}, "coef": 0.0})
    return g.run(Batch.of(b.t, r, b.s_hat, b.direction))


def test_resistance_memory_against_references() -> None:
    """relaxation = the S_hat relaxation filter applied to 100 ln R; peak against a slow
    loop; trough(R) = peak(1 / R); every form unchanged by a multiplicative tare."""
    b = random_inputs(seed=5)
    r = 1000.0 * np.exp(np.cumsum(np.random.default_rng(5).normal(0, 0.05, b.t.size)))
    y = 100.0 * np.log(r)
    tau = 6.0
    relaxation = regressor_from_dict({"name": "r", "kind": "relaxation",
                                      "params": {"tau": tau, "branch": "both"}, "coef": 0.0})
    np.testing.assert_allclose(_memory("relaxation", tau, b, r),
                               relaxation.run(Batch.of(b.t, r, y, b.direction)), atol=1e-9)
    p, ref = y[0], [0.0]
    for k in range(1, b.t.size):
        p = max(y[k], y[k - 1] + (p - y[k - 1]) * math.exp(-(b.t[k] - b.t[k - 1]) / tau))
        ref.append(p - y[k])
    peak = _memory("peak", tau, b, r)
    np.testing.assert_allclose(peak, ref, atol=1e-9)
    assert np.all(peak >= 0.0) and peak.max() > 1.0
    np.testing.assert_allclose(_memory("trough", tau, b, r), _memory("peak", tau, b, 1.0 / r),
                               atol=1e-9)
    for form in ("relaxation", "peak", "trough"):
        np.testing.assert_allclose(_memory(form, tau, b, 37.0 * r), _memory(form, tau, b, r),
                                   atol=1e-9)


def _stretch_reference(s: np.ndarray, form: str, scale: float, band: float) -> list[float]:
    """Slow reference: travel of S_hat through a play of +-band, then the form."""
    out, play, travel = [], float(s[0]), 0.0
    for v in s:
        moved = min(max(play, v - band), v + band)
        travel += abs(moved - play)
        play = moved
        h = (1 - math.exp(-travel / scale) if form in ("rest", "gain")
             else math.log(1 + travel / scale))
        out.append(h * v if form.startswith("gain") else h)
    return out


@pytest.mark.parametrize("form", ["rest", "rest_log", "gain", "gain_log"])
def test_stretch_history_against_a_slow_reference(form: str) -> None:
    """The stretch terms against a plain loop; a 0 -> 50 -> 0 % cycle adds 100 % of
    travel; noise inside the play band adds none."""
    b = random_inputs(seed=7)
    g = regressor_from_dict({"name": "x", "kind": "stretch", "coef": 0.0,
                             "params": {"form": form, "scale": 150.0, "band": 0.3}})
    np.testing.assert_allclose(g.run(b), _stretch_reference(b.s_hat, form, 150.0, 0.3),
                               rtol=1e-12, atol=1e-12)
    cycle = np.r_[np.linspace(0, 50, 51), np.linspace(49, 0, 50)]
    quiet = 0.5 + 0.2 * np.sin(np.arange(300))  # about where the play rests: no travel
    s = np.r_[cycle, quiet]
    t = np.arange(s.size, dtype=float)
    rest = regressor_from_dict({"name": "x", "kind": "stretch", "coef": 0.0,
                                "params": {"form": "rest_log", "scale": 100.0, "band": 0.5}})
    g_s = rest.run(Batch.of(t, 100 + s, s, np.zeros(s.size)))
    # up 0 -> 50 moves the play 0 -> 49.5, down to 0 moves it back to 0.5: 98.5 % of travel
    assert g_s[-1] == pytest.approx(math.log(1 + 98.5 / 100.0), rel=1e-9)
