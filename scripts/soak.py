#!/usr/bin/env python3
"""Soak test: every model over many samples, no NaN, no drift, no memory growth.

For each model (fitted once on a simulated rig run, as ``strain-comp fit`` does):

1. a *probe* (full-range sweeps 10 % beyond both ends of the valid range, which wipe out
   the rate-independent hysteresis memory, a 300 s hold (30 time constants for creep_pi's
   longest), which lets every fading memory (creep cells and states, sinh cells, spike
   decay, detector filter) settle, then two triangle
   cycles) on the fresh model;
2. ``--samples`` random-walk resistances inside the valid range, with jittered 100 Hz
   time stamps, through ``run`` in chunks of ``--chunk``, then ``--steps`` more through
   ``step``; every output must be finite;
3. the same probe again: over its two triangle cycles, its output must equal the fresh
   model's to 1e-9 of the strain span (any difference is state that drifted or was
   poisoned; during the sweeps and the hold the two runs legitimately differ by the
   memory of what came before, which fades);
4. ``--engine-samples`` through the ``Engine`` batch path with ~10 % bad samples (NaN,
   inf, <= 0, open, short, repeated and backward time stamps): no exception, every output
   finite once a sample was used.

Memory: VmRSS from /proc/self/status (no psutil) after the second and the last chunk of
each model, and at the start and end of the whole run.

    python scripts/soak.py --samples 10000000 [--models apl,pl] [--seed 0]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from strain_comp.base.samples import used_mask
from strain_comp.core.calibration import Calibration, SensorCalibration
from strain_comp.core.engine import Engine
from strain_comp.core.range_policy import OPEN_FACTOR, SHORT_FACTOR
from strain_comp.models import MODEL_NAMES
from strain_comp.offline.fit import fit_sensor
from strain_comp.offline.rig import simulate

DT = 0.01
"""Nominal sample period [s] of the soak stream."""


def rss_kib() -> int:
    """Resident set size of this process [KiB], from /proc/self/status (Linux)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise RuntimeError("no VmRSS in /proc/self/status")


@dataclass
class SoakResult:
    """What one model's soak found."""

    model: str
    samples: int
    seconds: float
    nan_count: int
    cycle_drift: float
    """max |probe output at the end - at the start| over its cycles [% strain]."""
    strain_span: float
    engine_bad: int
    engine_nonfinite: int
    rss_early_kib: int
    """VmRSS after the second chunk through ``run``: two chunks' arrays are alive at once
    from then on, and the allocator keeps their memory (steady state)."""
    rss_last_chunk_kib: int
    """VmRSS after the last chunk: equal to ``rss_early_kib`` if nothing grows."""


def fit_calibration(model: str) -> SensorCalibration:
    """``model`` fitted on 120 s of the rig's random ramps and holds (50 Hz)."""
    rec = simulate("random", seed=1, duration=120.0)["s1"]
    options: dict[str, object] = {"tau": 0.2}
    if model == "rational":
        options["mode"] = "split"
    elif model in ("apl", "pl"):  # one point of the sigma, p search is enough here
        options.update(sigma_grid=[0.03], p_grid=[1.0], refine=False)
    return fit_sensor([rec], model, name="s1", options=options)


PROBE_CYCLES = 1600
"""The probe's last samples, two triangle cycles: the drift comparison."""


HOLD = 300.0
"""The probe's hold [s]; at least ``HOLD_TAUS`` of a model's longest time constant."""
HOLD_TAUS = 30.0
"""exp(-30) ~ 1e-13: a first-order memory held this many time constants has faded."""


def probe(cal: SensorCalibration, t0: float) -> tuple[np.ndarray, np.ndarray]:
    """Sweeps to 10 % beyond both ends of the valid range, a hold (``HOLD``, longer for a
    model with longer time constants: creep_pi's ``taus``), two triangles."""
    lo, hi = cal.valid_range.r_lo, cal.valid_range.r_hi
    span = hi - lo
    hold = max(HOLD, HOLD_TAUS * max(cal.params.get("taus", [0.0])))
    legs = [np.linspace(lo - 0.1 * span, hi + 0.1 * span, 500),
            np.linspace(hi + 0.1 * span, lo - 0.1 * span, 500),
            np.full(round(hold / DT), lo - 0.1 * span)]
    tri = np.concatenate([np.linspace(lo, hi, PROBE_CYCLES // 4),
                          np.linspace(hi, lo, PROBE_CYCLES // 4)])
    r = np.concatenate([*legs, tri, tri])
    return t0 + DT * (1 + np.arange(r.size)), r


def random_walk(rng: np.random.Generator, u0: float, n: int) -> np.ndarray:
    """A reflected random walk in [0, 1] (crosses the range in ~1e5 samples)."""
    u = u0 + np.cumsum(rng.normal(0.0, 0.003, n))
    u = np.mod(u, 2.0)
    return np.where(u > 1.0, 2.0 - u, u)


def soak_model(cal: SensorCalibration, *, samples: int, chunk: int, steps: int,
               engine_samples: int, seed: int = 0) -> SoakResult:
    """Run the soak of the module docstring for one calibration."""
    rng = np.random.default_rng(seed)
    lo, hi = cal.valid_range.r_lo, cal.valid_range.r_hi
    model = cal.build_model()
    rss_early, n_chunks = 0, 0
    start = time.perf_counter()
    t_probe, r_probe = probe(cal, 0.0)
    first = model.run(t_probe, r_probe)
    t_last, u = float(t_probe[-1]), 0.0
    nan_count = int(np.count_nonzero(~np.isfinite(first)))
    done = 0
    while done < samples:
        n = min(chunk, samples - done)
        t = t_last + np.cumsum(rng.uniform(0.5 * DT, 1.5 * DT, n))
        u_walk = random_walk(rng, u, n)
        out = model.run(t, lo + u_walk * (hi - lo))
        nan_count += int(np.count_nonzero(~np.isfinite(out)))
        t_last, u, done = float(t[-1]), float(u_walk[-1]), done + n
        n_chunks += 1
        if n_chunks <= 2:
            rss_early = rss_kib()
    rss_last = rss_kib()
    u_walk = random_walk(rng, u, steps)
    for k in range(steps):
        t_last += DT
        nan_count += not math.isfinite(model.step(t_last, lo + u_walk[k] * (hi - lo)))
    t_probe2, r_probe2 = probe(cal, t_last)
    again = model.run(t_probe2, r_probe2)
    nan_count += int(np.count_nonzero(~np.isfinite(again)))
    engine_bad, engine_nonfinite = engine_soak(cal, rng, engine_samples, chunk)
    return SoakResult(
        model=cal.model, samples=samples + steps + 2 * t_probe.size,
        seconds=time.perf_counter() - start, nan_count=nan_count,
        cycle_drift=float(np.max(np.abs(again - first)[-PROBE_CYCLES:])),
        strain_span=cal.valid_range.s_hi - cal.valid_range.s_lo,
        engine_bad=engine_bad, engine_nonfinite=engine_nonfinite,
        rss_early_kib=rss_early, rss_last_chunk_kib=rss_last)


def engine_soak(cal: SensorCalibration, rng: np.random.Generator, samples: int,
                chunk: int) -> tuple[int, int]:
    """(bad samples counted, non-finite outputs after the first used sample)."""
    engine = Engine(Calibration({"s1": cal}))
    lo, hi = cal.valid_range.r_lo, cal.valid_range.r_hi
    bad_values = np.array([np.nan, np.inf, -np.inf, 0.0, -1.0, OPEN_FACTOR * hi * 10,
                           SHORT_FACTOR * lo / 10])
    t_last, u, done, nonfinite, seen_good = 0.0, 0.5, 0, 0, False
    while done < samples:
        n = min(chunk, samples - done)
        t = t_last + np.cumsum(rng.uniform(0.5 * DT, 1.5 * DT, n))
        u_walk = random_walk(rng, u, n)
        r = lo + u_walk * (hi - lo)
        bad = rng.random(n) < 0.1
        r[bad] = bad_values[rng.integers(0, bad_values.size, bad.sum())]
        back = np.flatnonzero(rng.random(n) < 0.002)
        t[back[back > 0]] = t[back[back > 0] - 1] - rng.uniform(0.0, 1.0)
        out = engine.run("s1", t, r)
        used = used_mask(out.status)
        first = 0 if seen_good else (int(np.argmax(used)) if used.any() else n)
        seen_good = seen_good or bool(used.any())
        nonfinite += int(np.count_nonzero(~np.isfinite(out.strain[first:])))
        t_last, u, done = float(t.max()), float(u_walk[-1]), done + n
    return engine.health()["s1"].n_bad, nonfinite


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=10_000_000,
                        help="random-walk samples per model through run (default 1e7)")
    parser.add_argument("--chunk", type=int, default=1_000_000)
    parser.add_argument("--steps", type=int, default=100_000,
                        help="further samples through step (one call each)")
    parser.add_argument("--engine-samples", type=int, default=1_000_000)
    parser.add_argument("--models", default=",".join(MODEL_NAMES))
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    models = [m.strip() for m in args.models.split(",") if m.strip()]
    print(f"RSS at start: {rss_kib()} KiB", flush=True)
    failures = 0
    for k, model in enumerate(models):
        cal = fit_calibration(model)
        warm = soak_model(cal, samples=1000, chunk=1000, steps=10, engine_samples=1000)
        del warm  # compiles every kernel before the measured run
        r = soak_model(cal, samples=args.samples, chunk=args.chunk, steps=args.steps,
                       engine_samples=args.engine_samples, seed=args.seed + k)
        ok = (r.nan_count == 0 and r.cycle_drift <= 1e-9 * r.strain_span
              and r.engine_nonfinite == 0)
        failures += not ok
        print(f"{model:12s} {r.samples:>10d} samples in {r.seconds:7.1f} s "
              f"({r.samples / r.seconds / 1e6:5.2f} M/s)  NaN {r.nan_count}  "
              f"probe drift {r.cycle_drift:.1e} %  engine bad {r.engine_bad} "
              f"non-finite {r.engine_nonfinite}  RSS chunk 2 / last "
              f"{r.rss_early_kib}/{r.rss_last_chunk_kib} KiB"
              f"  {'ok' if ok else 'FAIL'}", flush=True)
    print(f"RSS at end: {rss_kib()} KiB")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
