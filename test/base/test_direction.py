"""Dead-zone direction detector ([EGaIn] section V.E) against a slow reference."""

from __future__ import annotations

import math

import numpy as np
import pytest

from strain_comp.base.direction import (
    DirectionDetector,
    DirectionSettings,
    derivative_noise,
    estimate_deadzone,
)
from strain_comp.errors import InputError, ParameterError
from strain_comp.offline.options import check_fit_options


def detect_slow(t: list[float], r: list[float], deadzone: float, tau: float) -> list[int]:
    out = []
    filt = 0.0
    last = 0
    for n in range(len(t)):
        if n == 0:
            out.append(0)
            continue
        dt = t[n] - t[n - 1]
        d = (r[n] - r[n - 1]) / dt
        filt = filt + (1.0 - math.exp(-dt / tau)) * (d - filt) if tau > 0 else d
        last = 1 if filt > deadzone else (-1 if filt < -deadzone else 0)
        out.append(last)
    return out


@pytest.mark.parametrize("tau", [0.0, 0.05])
def test_kernel_matches_reference(tau: float) -> None:
    rng = np.random.default_rng(1)
    t = np.cumsum(rng.uniform(0.001, 0.02, 500))
    r = 100 + np.cumsum(rng.normal(0, 0.05, 500))
    settings = DirectionSettings(deadzone=1.0, tau=tau)
    batch = DirectionDetector(settings).run(t, r)
    assert batch.dtype == np.int8
    assert batch.tolist() == detect_slow(t.tolist(), r.tolist(), 1.0, tau)
    det = DirectionDetector(settings)
    assert [int(det.run([a], [b])[0]) for a, b in zip(t, r, strict=True)] == batch.tolist()
    det.reset()
    assert det.run(t, r).tolist() == batch.tolist()


def trapezoid(dt: float = 0.01) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """R ramps up 10 ohm in 2 s, holds 2 s, ramps down 2 s, holds 2 s; the true states."""
    t = np.arange(0.0, 8.0, dt)
    r = 100.0 + np.interp(t, [0, 2, 4, 6, 8], [0, 10, 10, 0, 0])
    truth = np.select([t < 2, t < 4, t < 6], [1, 0, -1], 0)
    return t, r, truth


def test_clean_trapezoid_with_noise() -> None:
    t, r, truth = trapezoid()
    r = r + np.random.default_rng(2).normal(0.0, 0.002, t.size)
    settings = DirectionSettings(deadzone=1.0, tau=0.02)
    states = DirectionDetector(settings).run(t, r)
    # away from the corners (filter lag) every state is right
    away = np.ones(t.size, bool)
    for corner in (0.0, 2.0, 4.0, 6.0):
        away &= np.abs(t - corner) > 0.15
    assert np.array_equal(states[away], truth[away])


def test_pure_noise_below_deadzone_never_flickers() -> None:
    rng = np.random.default_rng(3)
    t = np.arange(0, 60.0, 0.01)
    sigma_n = 0.01
    r = 50.0 + rng.uniform(-sigma_n, sigma_n, t.size)
    # |dR/dt| <= 2 * sigma_n / dt = 2 ohm/s for bounded noise
    states = DirectionDetector(DirectionSettings(deadzone=2.0)).run(t, r)
    assert not states.any()
    filtered = DirectionDetector(DirectionSettings(deadzone=2.0, tau=0.1)).run(t, r)
    assert not filtered.any()


@pytest.mark.parametrize("tau", [0.0, 0.1])
def test_k_sigma_estimate_matches_known_noise(tau: float) -> None:
    dt, sigma_n = 0.01, 0.02
    t = np.arange(0, 100.0, dt)
    r = 10.0 + 0.001 * t + np.random.default_rng(4).normal(0.0, sigma_n, t.size)
    a = 1.0 - math.exp(-dt / tau) if tau > 0 else 1.0
    # variance of exponentially smoothed first differences of white noise
    sigma_d = sigma_n / dt * a * math.sqrt(2.0 / (2.0 - a))
    settings = estimate_deadzone(t, r, k_sigma=4.0, tau=tau)
    print(f"tau={tau}: sigma estimate {settings.deadzone / 4:.4f} vs true {sigma_d:.4f} ohm/s")
    assert settings.deadzone == pytest.approx(4.0 * sigma_d, rel=0.1)
    assert settings.k_sigma == 4.0 and settings.tau == tau
    assert derivative_noise(t, r, tau) == pytest.approx(settings.deadzone / 4.0)


def test_bad_settings_name_the_field() -> None:
    with pytest.raises(ParameterError, match=r"direction\.tau"):
        DirectionDetector(DirectionSettings(deadzone=1.0, tau=-1.0))
    with pytest.raises(InputError, match="k_sigma"):  # a fit's k_sigma: with its options
        check_fit_options("apl", {"k_sigma": 0.0})
