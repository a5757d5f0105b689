"""Virtual test rig: a soft resistive strain sensor on a tensile tester (strain % in, ohm out),
after the Electrolycra sensor of [Electrolycra]; its model and effects: docs/architecture.md."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt
from scipy.signal import lfilter

from strain_comp.base.conversion import divider_to_resistance, resistance_to_divider
from strain_comp.errors import ParameterError
from strain_comp.io.recording import Recording, write_recordings

L0_MM = 100.0  # specimen length [mm]: rates in mm/min convert to %/s via this
T_REF = 23.0  # reference temperature [deg C]
HYSTERESIS_TAUS = (1.0, 6.0)  # fast branch time constants [s]
UNLOADING_RATIO = 0.2  # viscous response on unloading relative to loading
TEMPERATURE_SINE = (3.0, 600.0)  # amplitude [K] and period [s] of the slow sinusoid
TEMPERATURE_STEP = (2.0, 150.0)  # size [K] of the temperature steps and time between them [s]
SPIKE_SIZE = 0.5  # height of a spike [ohm], with a random sign
DIVIDER = (10.5, 3.2)  # series resistor R1 [ohm] and supply Vin [V] of the voltage divider


def _effect(default: float, unit: str, doc: str) -> float:
    return field(default=default, metadata={"unit": unit, "doc": doc})


@dataclass(frozen=True)
class RigEffects:
    """Every physical effect of the rig: a named switch with its magnitude (0 = off)."""

    hysteresis: float = _effect(1.0, "1", "weight of the fast viscoelastic branches "
                                "(tau 1 s, 6 s); 1 puts the loading curve about 0.08 R0 above "
                                "the quasi-static one at 50 mm/min")
    relaxation: float = _effect(0.3, "1", "weight of the slow branch: overshoot after a "
                                "loading step = relaxation * R0 * du")
    relaxation_tau: float = _effect(20.0, "s", "time constant of the relaxation")
    drift: float = _effect(0.0, "1/h", "slow resistance drift, fraction of R per hour")
    temperature: float = _effect(0.0, "1/K", "temperature coefficient of resistance (TCR)")
    crosstalk: float = _effect(0.0, "1", "fraction of each array neighbour's strain-induced "
                               "resistance change that leaks in")
    mullins: float = _effect(0.0, "1 per 100 %", "sensitivity lost per 100 % of peak strain "
                             "reached (first-cycle softening, never recovers)")
    noise: float = _effect(0.01, "ohm", "standard deviation of Gaussian read-out noise")
    alternation: float = _effect(0.0, "ohm", "read-out alternating every sample: "
                                 "+-this added to R (an excitation reversing its polarity)")
    spikes: float = _effect(0.0, "1", "share of samples read as an isolated spike "
                            "(never two in a row)")
    baseline_step: float = _effect(0.0, "ohm", "series resistance added from "
                                   "baseline_step_at on (a connector re-seated)")
    baseline_step_at: float = _effect(60.0, "s", "time of the baseline step")
    adc_bits: float = _effect(12, "bit", "ADC resolution of the divider voltage (0 = ideal)")

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if not np.isfinite(value):
                raise ParameterError(f.name, f"must be finite, got {value}")
        nonneg = ("hysteresis", "relaxation", "noise", "adc_bits", "crosstalk", "mullins",
                  "baseline_step_at")
        if not 0.0 <= self.spikes <= 0.1:
            raise ParameterError("spikes", f"must lie in [0, 0.1], got {self.spikes}")
        for name in nonneg:
            if getattr(self, name) < 0:
                raise ParameterError(name, f"must be >= 0, got {getattr(self, name)}")
        if not self.relaxation_tau > 0:
            raise ParameterError("relaxation_tau", f"must be > 0, got {self.relaxation_tau}")
        if self.adc_bits != int(self.adc_bits) or self.adc_bits > 24:
            raise ParameterError("adc_bits", f"must be an integer 0..24, got {self.adc_bits}")

    @classmethod
    def parse(cls, items: Iterable[str]) -> RigEffects:
        """Effects from ``name=value`` strings, the others at their defaults."""
        changes: dict[str, float] = {}
        names = [f.name for f in dataclasses.fields(cls)]
        for item in items:
            name, sep, value = item.partition("=")
            name = name.strip()
            if not sep or name not in names:
                raise ParameterError(name or item, f"unknown effect (expected name=value, "
                                     f"name one of {', '.join(names)})")
            try:
                changes[name] = float(value)
            except ValueError:
                raise ParameterError(name, f"not a number: {value!r}") from None
        return cls(**changes)

    @classmethod
    def describe(cls) -> str:
        """One line per effect: name, default, unit, meaning."""
        return "\n".join(f"{f.name} = {f.default} [{f.metadata['unit']}]: {f.metadata['doc']}"
                         for f in dataclasses.fields(cls))


@dataclass(frozen=True)
class SensorSpec:
    """One simulated sensor: unstrained resistance r0 [ohm], gauge G [1/%], saturation [%]."""

    r0: float = 11.5
    gain: float = 0.03
    s_sat: float = 80.0


# --------------------------------------------------------------------------- profiles


class _Profile:
    """Piecewise-linear strain waypoints built from ramps (at mm/min rates) and holds."""

    def __init__(self, start: float = 0.0) -> None:
        self.t = [0.0]
        self.s = [start]

    def ramp(self, to: float, rate_mm_min: float) -> _Profile:
        rate = rate_mm_min / 60.0 / L0_MM * 100.0  # %/s
        self.t.append(self.t[-1] + abs(to - self.s[-1]) / rate)
        self.s.append(to)
        return self

    def hold(self, seconds: float) -> _Profile:
        if seconds > 0:
            self.t.append(self.t[-1] + seconds)
            self.s.append(self.s[-1])
        return self

    def triangles(self, lo: float, hi: float, rate: float, n: int) -> _Profile:
        self.ramp(lo, rate)
        for _ in range(n):
            self.ramp(hi, rate).ramp(lo, rate)
        return self

    def sample(self, fs: float, duration: float | None) -> tuple[np.ndarray, np.ndarray]:
        tp, sp = np.array(self.t), np.array(self.s)
        end = tp[-1] if duration is None else duration
        t = np.arange(int(np.floor(end * fs)) + 1) / fs
        return t, np.interp(t % tp[-1] if end > tp[-1] else t, tp, sp)


def _triangle(_: np.random.Generator) -> _Profile:
    return _Profile().hold(5).triangles(0, 30, 50, 4).hold(5)


def _rates(_: np.random.Generator) -> _Profile:
    p = _Profile().hold(5)
    for rate in (20, 40, 60, 80, 100):
        p.triangles(0, 20, rate, 2).hold(5)
    return p


def _patterns(_: np.random.Generator) -> _Profile:
    p = _Profile().hold(5)
    for offset, amplitude in ((10, 20), (20, 20), (20, 30), (30, 20), (10, 40)):
        p.triangles(offset, offset + amplitude, 50, 2)
    return p.ramp(0, 50).hold(5)


def _steps(_: np.random.Generator) -> _Profile:
    p = _Profile().hold(10)
    for level in (10, 20, 30, 40, 30, 20, 10, 0):
        p.ramp(level, 1000).hold(30)
    return p


def _random(rng: np.random.Generator) -> _Profile:
    p = _Profile().hold(5)
    while p.t[-1] < 300:
        p.ramp(float(rng.uniform(0, 40)), float(rng.uniform(20, 100)))
        p.hold(float(rng.uniform(0, 8)) * (rng.random() < 0.6))
    return p


def _cycles_and_holds(first: float, end: float, rate: float, hold: float) -> _Profile:
    """0-20 % cycles, holds at 10 % and at rest, repeated to ``end`` seconds."""
    p = _Profile().hold(first)
    while p.t[-1] < end:
        p.triangles(0, 20, rate, 2).hold(hold).ramp(10, rate).hold(hold).ramp(0, rate)
        p.hold(hold / 2)
    return p


@dataclass(frozen=True)
class _Scenario:
    doc: str
    profile: Callable[[np.random.Generator], _Profile]
    fs: float = 50.0
    effects: dict[str, float] = field(default_factory=dict)  # when effects=None
    temperature: bool = False


_SCENARIOS: dict[str, _Scenario] = {
    "triangle": _Scenario("0-30 % triangle waves at 50 mm/min, 4 cycles", _triangle),
    "rates": _Scenario("0-20 % triangles at 20, 40, 60, 80, 100 mm/min, 2 cycles each "
                       "(like SR1-SR9), 25 Hz", _rates, fs=25.0),
    "patterns": _Scenario("triangle pieces of different offsets and amplitudes at 50 mm/min "
                          "(like SP1, plus SP2's largest), 25 Hz", _patterns, fs=25.0),
    "steps": _Scenario("steps 0-40 % and back at 1000 mm/min with 30 s holds (like RB1)",
                       _steps),
    "random": _Scenario("random ramps (20-100 mm/min, 0-40 %) and holds, 300 s", _random),
    "array": _Scenario("6 sensors of different gains on one array topic /array/..., "
                       "neighbours strained differently", _triangle, fs=25.0),
    "long": _Scenario("1 h of cycles and holds at 5 Hz, with drift=0.05 per hour unless "
                      "effects are given", lambda _: _cycles_and_holds(60, 3600, 50, 120),
                      fs=5.0, effects={"drift": 0.05}),
    "temperature": _Scenario("20 min of cycles and holds at 10 Hz with a temperature "
                             "profile, TCR 0.004/K unless effects are given",
                             lambda _: _cycles_and_holds(30, 1200, 60, 40),
                             fs=10.0, effects={"temperature": 0.004}, temperature=True),
}
#: scenario name -> one-line description.
SCENARIOS: dict[str, str] = {name: sc.doc for name, sc in _SCENARIOS.items()}
ARRAY_NAME = "array"
ARRAY_SIZE = 6
#: Size limits of one simulation: samples x sensors, and the seed range (numpy's seeds).
MAX_SAMPLES = 2_000_000
SEED_MAX = 2**63 - 1


def check_size(scenario: str, *, seed: int = 0, duration: float | None = None) -> None:
    if scenario not in _SCENARIOS:
        raise ParameterError("scenario", f"unknown scenario {scenario!r}; one of "
                             f"{', '.join(SCENARIOS)}")
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= SEED_MAX:
        raise ParameterError("seed", f"must be an integer in [0, 2^63-1], got {seed!r}")
    if duration is None:
        return
    if not (np.isfinite(duration) and duration > 0):
        raise ParameterError("duration", f"must be > 0 s, got {duration}")
    sc = _SCENARIOS[scenario]
    n_sensors = ARRAY_SIZE if scenario == ARRAY_NAME else 1
    if duration * sc.fs * n_sensors > MAX_SAMPLES:
        longest = MAX_SAMPLES / (sc.fs * n_sensors)
        raise ParameterError("duration", f"at most {longest:g} s for scenario {scenario!r} "
                             f"({MAX_SAMPLES} samples x sensors at {sc.fs:g} Hz), got "
                             f"{duration:g}")


def _array_profiles(fs: float, duration: float | None) -> tuple[np.ndarray, np.ndarray]:
    """Per-sensor strain of the array: neighbours differ in amplitude, rate and phase."""
    columns = []
    for i in range(ARRAY_SIZE):
        hi = 12.0 + 4.0 * ((i * 3) % ARRAY_SIZE)
        rate = 30.0 + 14.0 * ((i * 5) % ARRAY_SIZE)
        p = _Profile().hold(2.0 + 3.0 * i)
        while p.t[-1] < 240:
            p.triangles(0, hi, rate, 1).hold(4.0 * (i % 3))
        t, si = p.sample(fs, 240.0 if duration is None else duration)
        columns.append(si)
    return t, np.column_stack(columns)


# --------------------------------------------------------------------------- physics


def _branch(u: npt.NDArray[np.float64], tau: float, fs: float) -> npt.NDArray[np.float64]:
    """x = u - q with dq/dt = (u - q)/tau, exact exponential update, q(0) = u(0)."""
    e = np.exp(-1.0 / (tau * fs))
    q: npt.NDArray[np.float64]  # scipy ships no types: lfilter of a float64 u is float64
    q, _ = lfilter([1.0 - e], [1.0, -e], u, zi=[e * u[0]])
    return u - q


def _mechanical(strain: np.ndarray, spec: SensorSpec, fx: RigEffects, fs: float) -> np.ndarray:
    """Noise-free R_mech [ohm] of one sensor (docs/architecture.md, items 1-2)."""
    g = spec.gain * spec.s_sat * np.tanh(strain / spec.s_sat)
    peak = np.maximum.accumulate(strain)
    u = np.maximum(0.1, 1.0 - fx.mullins * peak / 100.0) * g
    viscous = np.zeros_like(u)
    branches = [(tau, fx.hysteresis / 2.0) for tau in HYSTERESIS_TAUS]
    branches.append((fx.relaxation_tau, fx.relaxation))
    for tau, weight in branches:
        if weight > 0:
            x = _branch(u, tau, fs)
            viscous += weight * np.where(x >= 0, x, UNLOADING_RATIO * x)
    return spec.r0 * (1.0 + u + viscous)


def temperature_profile(t: np.ndarray) -> np.ndarray:
    """T(t): T_ref + slow sinusoid + a square wave of steps."""
    square = (np.floor(t / TEMPERATURE_STEP[1]) % 2) * TEMPERATURE_STEP[0]
    return T_REF + TEMPERATURE_SINE[0] * np.sin(2 * np.pi * t / TEMPERATURE_SINE[1]) + square


def _chain(t: np.ndarray, r: np.ndarray, fx: RigEffects, rng: np.random.Generator
           ) -> npt.NDArray[np.float64]:
    """The measurement chain (docs/architecture.md, item 4): alternation, spikes, baseline step."""
    out: npt.NDArray[np.float64] = r + fx.alternation * (-1.0) ** np.arange(r.size)
    out = out + fx.baseline_step * (t >= fx.baseline_step_at)
    if fx.spikes > 0:
        hit = rng.random(out.size) < fx.spikes
        hit[1:] &= ~hit[:-1]  # isolated: never two in a row
        out = out + hit * SPIKE_SIZE * rng.choice([-1.0, 1.0], out.size)
    return out


def _read_out(r: np.ndarray, fx: RigEffects, rng: np.random.Generator) -> np.ndarray:
    if fx.noise > 0:
        r = r + rng.normal(0.0, fx.noise, r.shape)
    if fx.adc_bits > 0:
        r1, vin = DIVIDER
        lsb = vin / 2.0 ** int(fx.adc_bits)
        v = np.round(resistance_to_divider(np.maximum(r, 0.0), r1, vin) / lsb) * lsb
        r = divider_to_resistance(v, r1, vin)
    return r


def simulate(scenario: str, *, seed: int = 0, effects: RigEffects | None = None,
             duration: float | None = None) -> dict[str, Recording]:
    """Run a scenario on the rig, a recording per sensor; deterministic for a seed."""
    check_size(scenario, seed=seed, duration=duration)
    sc = _SCENARIOS[scenario]
    fx = effects if effects is not None else dataclasses.replace(RigEffects(), **sc.effects)
    rng = np.random.default_rng([seed, 0])
    if scenario == "array":
        t, strain = _array_profiles(sc.fs, duration)
        names = [f"a{i + 1}" for i in range(ARRAY_SIZE)]
        specs = [SensorSpec(r0=10.0 + 0.8 * i, gain=0.024 + 0.003 * ((2 * i) % ARRAY_SIZE))
                 for i in range(ARRAY_SIZE)]
    else:
        t, s = sc.profile(rng).sample(sc.fs, duration)
        strain = s[:, None]
        names = ["s1"]
        specs = [SensorSpec()]
    with_temperature = sc.temperature or fx.temperature != 0
    temp = temperature_profile(t) if with_temperature else None
    mech = np.column_stack([_mechanical(strain[:, i], spec, fx, sc.fs)
                            for i, spec in enumerate(specs)])
    r = mech.copy()
    if fx.crosstalk > 0 and len(specs) > 1:
        delta = mech - np.array([spec.r0 for spec in specs])
        leak = np.zeros_like(delta)
        leak[:, 1:] += delta[:, :-1]
        leak[:, :-1] += delta[:, 1:]
        r += fx.crosstalk * leak
    if temp is not None:
        r *= (1.0 + fx.temperature * (temp - T_REF))[:, None]
    r *= (1.0 + fx.drift * t / 3600.0)[:, None]
    array = ARRAY_NAME if scenario == "array" else None
    sensors = {}
    for i, name in enumerate(names):
        noise_rng = np.random.default_rng([seed, 1 + i])
        chain = _chain(t, r[:, i], fx, np.random.default_rng([seed, 100 + i]))
        sensors[name] = Recording(name, t, _read_out(chain, fx, noise_rng), strain[:, i].copy(),
                                  temp, array, None if array is None else i)
    return sensors


def write_sim_bag(run: Mapping[str, Recording], path: str | Path, *,
                  temperature_rate: float = 2.0) -> None:
    """``simulate``'s recordings as an MCAP bag, the temperature read at ``temperature_rate`` Hz."""
    first = next(iter(run.values()))
    dt = first.t[1] - first.t[0] if first.t.size > 1 else 1.0
    write_recordings(run, path, temperature_every=max(1, round(1.0 / (temperature_rate * dt))))
