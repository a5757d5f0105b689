#!/usr/bin/env python3
"""Generalisation benchmark: a calibration used, as a user uses it, on a run it was not
fitted on, judged by the error the user sees there.

    python scripts/generalisation.py --out out/generalisation --figures docs

For every sensor in ``../shared/data/measured`` (carbon black ``cb``, conductive fibre
``fiber``, silver nylon thread ``nylon``) and the virtual rig (``rig``: five scenarios of
``strain-comp simulate``, one sensor), every run B of that sensor is the *test run* of two
**schemes**:

* ``pair``: the model fitted on one other run A (every ordered pair A, B);
* ``loro`` (leave one run out): the model fitted on all other runs of the sensor at once
  (``strain-comp fit A C D ...``, runs pooled in one input space, ``fit --pool spanned``);
  ``loro_raw`` (with ``--pool-raw``): the same, pooled as recorded (``--pool raw``);
  ``loro_joint``, ``loro_stretch``: pooled in that input space (``--pool joint|stretch``),
  not the one ``spanned`` chooses.

Runs are imported with ``strain-comp import-csv`` and the sensor's preset (``simulate``'s
own bag writer for the rig); fits are ``fit_bags``, the code of ``strain-comp fit``, with
default options, cached in ``OUT/cache`` under a hash of the fitting code. The calibration
is then used on B in each **workflow** and scored on all of B (``evaluate_recordings``, the
numbers ``strain-comp evaluate`` prints):

* ``as_is``: ``evaluate --tare auto`` (the rest level read at the start of B);
* ``first``: the session start on B's first stretch and return: ``strain-comp start CAL B
  --window 0:S`` (the input zero and span, then the output gain and offset where the
  calibration takes one); S the end of the first stretch and return;
* ``warmup``: ``strain-comp start CAL B``, the stretch it finds itself: B's *second*
  stretch and return, the first being a warm-up whose reference is ignored; where B has
  no second, or it takes fewer steps than the first, the first (the README's procedure,
  ``strain_comp.offline.session_start``);
* ``refs_60``: ``warmup``, then ``evaluate --references-every 60``: B's own reference every
  60 s fused online into the output gain and offset (scored on all samples);
* ``loop`` (``pair`` only, with ``--loop``): ``warmup`` on the calibration ``strain-comp
  diagnose A --validate C...`` made (the first ``--loop-validate`` runs other than A, B).

A session start that ``start`` refuses leaves the calibration as it was, as for a user.

Reported per scheme, model and sensor: the median and the worst absolute RMSE over the test
runs (each sensor's unit: fibre mm, else % strain), and the **ratio** to the *best in-run
bound* of the run: the lowest RMSE any benchmarked model reaches when fitted on B itself
and scored on B (``evaluate --in-run-bound``). Overall ratios weigh every sensor equally.
Prints Markdown tables and the targets, writes ``OUT/generalisation.json`` (or ``--json``)
and, with ``--figures DIR``, one PNG of the medians.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import math
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
DEFAULT_DATA = REPO.parent / "shared" / "data" / "measured"
DEFAULT_MODELS = ("cubic", "mpi", "apl", "creep_pi")
SCHEMES = ("pair", "loro")
WORKFLOWS = ("as_is", "first", "warmup", "refs_60")
HEADLINE = "warmup"
"""The session start the README recommends (chosen on this benchmark: docs/results.md)."""
TARGETS = {("nylon", "loro", "warmup", "median"): 5.0, ("nylon", "loro", "warmup", "worst"): 7.5,
           ("nylon", "loro", "refs_60", "median"): 4.0, ("cb", "loro", "warmup", "median"): 7.0,
           ("nylon", "day2", "warmup", "ratio_median"): 1.2}
"""Targets: (sensor, scheme, workflow, statistic) -> at most (absolute RMSE [% strain], or
the ratio to the best in-run bound)."""
REFERENCE_SECONDS = 60.0
"""Spacing of the known strains of the ``refs_60`` workflow."""
ENGINE = {"out_of_range": "extend"}
"""Engine options of every evaluation (``--out-of-range``)."""
LOOP = {"stretch_history": False, "session_start": True, "validate": 3}
"""Options of the loop workflow's ``diagnose`` and how many other runs it validates on."""
NYLON_COLUMNS = "time=time_s,resistance=r_over_r0,strain=position"
BOUND_MODELS: list[str] = []
"""The models of the in-run bound (``--bound-models``; empty: the benchmarked ones but
``auto``, or cubic, mpi and apl with ``auto`` alone)."""
AUTO_JOBS = [1]
"""Worker processes of a ``fit --model auto`` (``--auto-jobs``)."""


@dataclass(frozen=True)
class Run:
    """One recording of a sensor: a CSV with its import arguments, or a rig scenario."""

    label: str
    source: str
    """CSV path relative to the data folder, or ``rig:SCENARIO``."""
    import_args: tuple[str, ...] = ()


@dataclass(frozen=True)
class Sensor:
    name: str
    runs: tuple[Run, ...]
    unit: str = "%"
    later: tuple[Run, ...] = ()
    """Runs of another session (scheme ``day2``: the test runs of a fit on ``runs``)."""


def sensors_of(data: Path) -> dict[str, Sensor]:
    """Every benchmarked sensor and its runs (the measured ones only when present)."""
    cb = "cb_pdms_7p5wt/2_7-5_"
    nylon = "nylon_silver/session1_100Hz/"
    fiber = "conductive_fiber/oldthread_sensorfiber_5x_"
    out = {
        "cb": Sensor("cb", tuple(Run(k, cb + f, ("--format", "cb_pdms")) for k, f in (
            ("v16", "E4pin_20mm_v16_0.3Strain.csv"), ("v19", "E4pin_20mm_v19_0.3Strain.csv"),
            ("v10", "E4pin_20mm_v10_0.3Strain.csv"), ("sawtooth", "4Epin_rand_sawtooth.csv"),
            ("v9", "E4pin_20mm_v9_0.2Strain_velocityprof.csv")))),
        "fiber": Sensor("fiber", tuple(Run(f"run{i}", f"{fiber}{i}_synced.csv",
                                           ("--format", "fiber")) for i in (1, 3, 4)),
                        unit="mm"),
        "nylon": Sensor("nylon", tuple(Run(k, f"{nylon}{k}.csv", (
            "--format", "generic", "--columns", NYLON_COLUMNS, "--scales", "strain=100"))
            for k in ("sin_20", "sin_30", "sin_40", "tri_50", "mixed_10_20", "mixed_15_25",
                      "mixed_20_30")), later=tuple(
            Run(f"day2_{k}", f"nylon_silver/session2_10Hz/{k}.csv", (
                "--format", "generic", "--columns", NYLON_COLUMNS, "--scales", "strain=100"))
            for k in ("sin_20", "sin_40", "tri_20", "tri_30", "mixed_20_30"))),
        "rig": Sensor("rig", tuple(Run(k, f"rig:{k}") for k in
                                   ("triangle", "rates", "patterns", "steps", "random"))),
    }
    out = {k: v for k, v in out.items()
           if k == "rig" or all((data / r.source).is_file() for r in v.runs)}
    return {k: v if all((data / r.source).is_file() for r in v.later) else
            replace(v, later=()) for k, v in out.items()}


def another_day(data: Path) -> Sensor:
    """The thread's session 2 (another day, 10 Hz): the test runs of ``--coverage``'s
    session 1 -> session 2 rows."""
    return Sensor("nylon_day2", tuple(Run(k, f"nylon_silver/session2_10Hz/{k}.csv", (
        "--format", "generic", "--columns", NYLON_COLUMNS, "--scales", "strain=100"))
        for k in ("sin_20", "sin_40", "tri_20", "tri_30", "mixed_20_30")))


def quick(sensor: Sensor) -> Sensor:
    """``--quick``: three runs per sensor."""
    return replace(sensor, runs=sensor.runs[:3])


# --------------------------------------------------------------------------- the pieces


def code_hash() -> str:
    """Hash of the package's code: a cached fit (or loop calibration) is reused only while
    none of it changed (a fit reads models, offline and core; the loop reads diagnosis)."""
    digest = hashlib.sha256()
    for path in sorted((REPO / "strain_comp").rglob("*.py")):
        digest.update(path.read_bytes())
    return digest.hexdigest()[:12]


class Bench:
    """Bags, cached fits and loaded recordings of one benchmark run."""

    def __init__(self, data: Path, out: Path, *, refit: bool = False,
                 log: Callable[[str], None] = print) -> None:
        self.data = data
        self.out = out
        self.refit = refit
        self.log = log
        self.key = code_hash()
        self.recordings: dict[tuple[str, str], Any] = {}
        self.fits: dict[Path, Any] = {}
        self.fit_seconds = 0.0

    def bag(self, sensor: Sensor, run: Run) -> Path:
        """The run's bag (made once: ``import-csv`` or the rig's bag writer)."""
        from strain_comp.cli import main as cli
        from strain_comp.offline import rig

        path = self.out / "bags" / sensor.name / f"{run.label}.mcap"
        if path.is_file():
            return path
        path.parent.mkdir(parents=True, exist_ok=True)
        if run.source.startswith("rig:"):
            scenario = run.source[4:]
            rig.write_sim_bag(rig.simulate(scenario, seed=1), path)
            return path
        argv = ["import-csv", str(self.data / run.source), "--out", str(path),
                "--sensor", sensor.name, *run.import_args]
        with contextlib.redirect_stdout(sys.stderr):
            if cli(argv) != 0:
                raise SystemExit(f"import of {run.source} failed")
        return path

    def recording(self, sensor: Sensor, run: Run) -> Any:
        from strain_comp.io.recording import load_recordings

        key = (sensor.name, run.label)
        if key not in self.recordings:
            recs = load_recordings(self.bag(sensor, run))[0]
            self.recordings[key] = recs[sensor.name if sensor.name != "rig" else "s1"]
        return self.recordings[key]

    def cache_path(self, sensor: Sensor, runs: Sequence[Run], model: str,
                   pool: str = "spanned", band: bool = False) -> Path:
        labels = "+".join(r.label for r in runs)
        tail = ("" if len(runs) == 1 or pool == "spanned" else f"_{pool}") + (
            "_band" if band else "")
        return self.out / "cache" / f"{sensor.name}_{labels}_{model}{tail}_{self.key}.yaml"

    def fit(self, sensor: Sensor, runs: Run | Sequence[Run], model: str,
            pool: str = "spanned", band: bool = False) -> Any:
        """``strain-comp fit RUN... --model MODEL --pool POOL`` (default options), cached;
        ``band``: ``--model auto --candidates MODEL``, which learns the uncertainty."""
        from strain_comp.core.calibration_file import load_calibration, save_calibration
        from strain_comp.offline.fit import auto_fitter, fit_bags

        runs = (runs,) if isinstance(runs, Run) else tuple(runs)
        path = self.cache_path(sensor, runs, model, pool, band)
        if path in self.fits:
            return self.fits[path]
        if path.is_file() and not self.refit:
            self.fits[path] = load_calibration(path)
            return self.fits[path]
        start = time.perf_counter()
        name = "s1" if sensor.name == "rig" else sensor.name
        cal = fit_bags([self.bag(sensor, r) for r in runs], model, [name],
                       {"progress": False} if model in ("apl", "pl", "mpi") else None,
                       pool=pool,
                       fitter=(auto_fitter(jobs=AUTO_JOBS[0]) if model == "auto" else
                               auto_fitter((model,), jobs=AUTO_JOBS[0]) if band else None))
        cal.sensors[name].strain_unit = sensor.unit
        self.fit_seconds += time.perf_counter() - start
        self.log(f"## fit {sensor.name}/{'+'.join(r.label for r in runs)} {model} {pool}: "
                 f"{time.perf_counter() - start:.1f} s")
        path.parent.mkdir(parents=True, exist_ok=True)
        save_calibration(cal, path)
        self.fits[path] = cal
        return cal


def rmse(rec: Any, cal: Any, *, tare: str = "calibration",
         references_every: float | None = None) -> float:
    """``strain-comp evaluate [--references-every SECONDS]`` RMSE of ``cal`` on ``rec``."""
    from strain_comp.offline.evaluate import evaluate_recordings

    result = evaluate_recordings({rec.name: rec}, cal, tare=tare,
                                 out_of_range=ENGINE["out_of_range"],
                                 references_every=references_every)
    return float(result.sensors[rec.name].stats.rmse)


def session_starts(rec: Any, cal: Any, log: Callable[[str], None] = print
                   ) -> tuple[Any, Any]:
    """``cal`` after ``strain-comp start CAL B --window 0:S`` on B's first stretch
    (``first``), and after ``strain-comp start CAL B`` (``warmup``: the stretch it finds):
    ``strain_comp.offline.session_start``, the code of the command; a start refused leaves
    the calibration as it is (``start_or_keep``), as for a user."""
    from strain_comp.errors import StrainCompError
    from strain_comp.offline.session_start import start_or_keep, stretch_of

    recs = {rec.name: rec}
    found = start_or_keep(cal, recs)
    for line in found.notes:
        log(f"## {rec.name}: {line}")
    vr = cal.sensors[rec.name].valid_range
    try:
        first = stretch_of(rec.t, rec.s, vr.s_hi - vr.s_lo, rec.name)[0]
    except StrainCompError:  # refused: as found (the calibration as it is)
        return found.calibration, found.calibration
    at_first = found if found.window == first else start_or_keep(cal, recs, window=first)
    return at_first.calibration, found.calibration


def workflows(rec: Any, cal: Any, loop_cal: Any | None = None, *,
              log: Callable[[str], None] = print) -> dict[str, float]:
    """RMSE on ``rec`` of every workflow (``WORKFLOWS``; ``loop`` when ``loop_cal``, with
    the same session start as ``warmup``)."""
    at_first, started = session_starts(rec, cal, log)
    out = {"as_is": rmse(rec, cal, tare="auto"), "first": rmse(rec, at_first)}
    out["warmup"] = out["first"] if started is at_first else rmse(rec, started)
    out["refs_60"] = rmse(rec, started, references_every=REFERENCE_SECONDS)
    if loop_cal is not None:
        out["loop"] = rmse(rec, session_starts(rec, loop_cal, log)[1])
    return out


def looped(bench: Bench, sensor: Sensor, train: Run, validate: Sequence[Run], model: str
           ) -> Any:
    """The calibration ``strain-comp diagnose TRAIN --validate VALIDATE...`` makes, cached."""
    from strain_comp.api import diagnose
    from strain_comp.core.calibration_file import load_calibration

    options = ("_stretch" if LOOP["stretch_history"] else "") + (
        "" if LOOP["session_start"] else "_nosession")
    path = bench.out / "cache" / (f"{sensor.name}_{train.label}_{model}_loop_"
                                  f"{'+'.join(r.label for r in validate)}{options}_"
                                  f"{bench.key}.yaml")
    if not path.is_file() or bench.refit:
        cal = bench.fit(sensor, train, model)
        src = bench.cache_path(sensor, (train,), model)
        with contextlib.redirect_stdout(sys.stderr):
            diagnose(cal, str(bench.bag(sensor, train)),
                     validate=[str(bench.bag(sensor, r)) for r in validate],
                     out=str(path), inputs=[str(src)], tare="auto",
                     stretch_history=LOOP["stretch_history"],
                     session_start=LOOP["session_start"])
    return load_calibration(path)


def band(rec: Any, cal: Any, log: Callable[[str], None] = print) -> tuple[float, float]:
    """(RMSE, share of the scored samples inside the 95 % band) of ``cal`` on ``rec`` after
    the headline session start (``warmup``): ``evaluate``'s ``coverage_95``."""
    from strain_comp.offline.evaluate import evaluate_recordings

    started = session_starts(rec, cal, log)[1]
    ev = evaluate_recordings({rec.name: rec}, started,
                             out_of_range=ENGINE["out_of_range"]).sensors[rec.name]
    return float(ev.stats.rmse), math.nan if ev.coverage_95 is None else ev.coverage_95


def coverage_table(bench: Bench, sensors: Sequence[Sensor], models: Sequence[str],
                   day2: Sensor | None) -> tuple[str, list[dict[str, Any]]]:
    """``--coverage``: every run of every sensor left out of the model fitted on the others
    (``fit --model auto --candidates MODEL``, which learns the band from its own runs left
    out), started on it (``warmup``)
    and scored; with ``day2``, the thread's session-2 runs on the fit of all of session 1.
    A Markdown table of the coverage per sensor and model, and the rows."""
    from strain_comp.core.calibration import Calibration

    rows: list[dict[str, Any]] = []
    for model in models:
        for sensor in sensors:
            tests = [(tuple(r for r in sensor.runs if r != test), sensor, test)
                     for test in sensor.runs]
            if day2 is not None and sensor.name == "nylon":
                tests += [(sensor.runs, day2, test) for test in day2.runs]
            for train, tested, test in tests:
                cal = bench.fit(sensor, train, model, band=True)
                rec = bench.recording(tested, test)
                rec = replace(rec, name=sensor.name)
                error, share = band(rec, Calibration({sensor.name: cal.sensors[sensor.name]}),
                                    bench.log)
                rows.append({"sensor": tested.name, "model": model, "test": test.label,
                             "rmse": error, "coverage_95": share,
                             "n": int(rec.t.size)})
                bench.log(f"## band {tested.name} {model} {test.label}: RMSE {error:.3f}, "
                          f"in 95% {100 * share:.1f}%")
    lines = ["| sensor | model | runs | coverage of the 95 % band: pooled (min-max over runs) "
             "| median RMSE |", "|---|---|---:|---|---:|"]
    keys = list(dict.fromkeys((r["sensor"], r["model"]) for r in rows))
    for name, model in keys:
        mine = [r for r in rows if (r["sensor"], r["model"]) == (name, model)]
        share = np.array([r["coverage_95"] for r in mine])
        n = np.array([r["n"] for r in mine], float)
        ok = np.isfinite(share)
        pooled = float(np.sum(share[ok] * n[ok]) / np.sum(n[ok])) if ok.any() else math.nan
        lines.append(f"| {name} | {model} | {len(mine)} | {100 * pooled:.1f} % "
                     f"({100 * np.nanmin(share):.1f}-{100 * np.nanmax(share):.1f}) | "
                     f"{np.median([r['rmse'] for r in mine]):.2f} |")
    return "\n".join(lines), rows


# --------------------------------------------------------------------------- the benchmark


@dataclass
class Case:
    """One test run B of one scheme and model: what it was trained on and its errors."""

    sensor: str
    model: str
    scheme: str
    train: str
    test: str
    in_run: float
    """The model's own in-run bound on B."""
    rmse: dict[str, float] = field(default_factory=dict)
    best_in_run: float = math.nan
    """The lowest in-run bound of any benchmarked model on B."""

    def ratio(self, workflow: str) -> float:
        value = self.rmse.get(workflow, math.nan)
        return value / self.best_in_run if self.best_in_run > 0 else math.nan


def bound_models(models: Sequence[str]) -> list[str]:
    """The models of the in-run bound (``BOUND_MODELS``)."""
    return BOUND_MODELS or [m for m in models if m != "auto"] or ["cubic", "mpi", "apl"]


def test_runs(sensor: Sensor, schemes: Sequence[str]) -> list[Run]:
    """The runs the schemes test on: the sensor's runs, and its ``later`` ones for
    ``day2``."""
    runs = [] if set(schemes) <= {"day2"} else list(sensor.runs)
    return runs + (list(sensor.later) if "day2" in schemes else [])


def in_run_bounds(bench: Bench, sensor: Sensor, models: Sequence[str],
                  step: Callable[[], None] = lambda: None, runs: Sequence[Run] | None = None,
                  ) -> dict[tuple[str, str], float]:
    """(model, run) -> the model's in-run bound on the run (fitted and scored on it), for
    ``runs`` (default the sensor's)."""
    from strain_comp.errors import StrainCompError

    bounds: dict[tuple[str, str], float] = {}
    for model in models:
        for run in sensor.runs if runs is None else runs:
            try:
                bounds[model, run.label] = rmse(bench.recording(sensor, run),
                                                bench.fit(sensor, run, model))
            except StrainCompError as err:
                bench.log(f"## {sensor.name}/{run.label} {model}: no in-run bound ({err})")
            step()
    return bounds


def test_cases(bench: Bench, sensor: Sensor, model: str, bounds: Mapping[tuple[str, str], float],
               schemes: Sequence[str], loop: bool, step: Callable[[], None] = lambda: None
               ) -> list[Case]:
    """Every test run of one sensor and model in every scheme (``best_in_run`` not set)."""
    from strain_comp.errors import StrainCompError

    cases: list[Case] = []
    for scheme in schemes:
        for test in sensor.later if scheme == "day2" else sensor.runs:
            step()
            others = [r for r in sensor.runs if r != test]
            trainings = [(r,) for r in others] if scheme == "pair" else [tuple(others)]
            pool = scheme.removeprefix("loro_") if scheme.startswith("loro_") else "spanned"
            for train in trainings:
                try:
                    cal = bench.fit(sensor, train, model, pool)
                except StrainCompError as err:
                    bench.log(f"## {sensor.name}/{train} {model}: {err}")
                    continue
                loop_cal = None
                if loop and scheme == "pair":
                    rest = [r for r in others if r != train[0]]
                    if rest:
                        loop_cal = looped(bench, sensor, train[0],
                                          rest[:int(LOOP["validate"])], model)
                rec = bench.recording(sensor, test)
                case = Case(sensor.name, model, scheme, "+".join(r.label for r in train),
                            test.label, bounds.get((model, test.label), math.nan),
                            workflows(rec, cal, loop_cal, log=bench.log))
                cases.append(case)
                bench.log(f"## {sensor.name} {model} {scheme} {case.train} -> {test.label}: "
                          + ", ".join(f"{k} {v:.2f}" for k, v in case.rmse.items()))
    return cases


def set_best_in_run(cases: Sequence[Case], bounds: Mapping[tuple[str, str, str], float]
                    ) -> None:
    """Each case's ``best_in_run``: the lowest bound of any model on its test run
    (``bounds``: (sensor, model, run) -> bound)."""
    for case in cases:
        found = [v for (name, _, label), v in bounds.items()
                 if name == case.sensor and label == case.test]
        case.best_in_run = min(found) if found else math.nan


def run_benchmark(bench: Bench, sensors: Sequence[Sensor], models: Sequence[str], *,
                  schemes: Sequence[str] = SCHEMES, loop: bool = False,
                  step: Callable[[], None] = lambda: None) -> list[Case]:
    """Every test run of every sensor, scheme and model; ``step()`` after each in-run fit
    and each test run of a scheme (a progress bar)."""
    cases: list[Case] = []
    bounds: dict[tuple[str, str, str], float] = {}
    for sensor in sensors:
        found = in_run_bounds(bench, sensor, bound_models(models), step,
                              test_runs(sensor, schemes))
        bounds.update({(sensor.name, *key): v for key, v in found.items()})
        for model in models:
            cases += test_cases(bench, sensor, model, found, schemes, loop, step)
    set_best_in_run(cases, bounds)
    return cases


@dataclass(frozen=True)
class Task:
    """One sensor and model of the benchmark, run in a worker process (``--jobs``)."""

    data: Path
    out: Path
    refit: bool
    sensor: Sensor
    model: str
    schemes: tuple[str, ...]
    loop: bool
    engine: dict[str, str]
    loop_options: dict[str, Any]
    models: tuple[str, ...] = ()
    """Every model of the benchmark (which give the in-run bound)."""
    bound: tuple[str, ...] = ()
    auto_jobs: int = 1


def run_task(task: Task) -> tuple[list[Case], dict[tuple[str, str], float], float, list[str]]:
    """A task's cases, in-run bounds, seconds of fitting and log lines."""
    ENGINE.update(task.engine)
    LOOP.update(task.loop_options)
    BOUND_MODELS[:] = task.bound
    AUTO_JOBS[0] = task.auto_jobs
    lines: list[str] = []
    bench = Bench(task.data, task.out, refit=task.refit, log=lines.append)
    bounds = in_run_bounds(bench, task.sensor, [m for m in [task.model]
                                                if m in bound_models(task.models)],
                           runs=test_runs(task.sensor, task.schemes))
    cases = test_cases(bench, task.sensor, task.model, bounds, task.schemes, task.loop)
    return cases, bounds, bench.fit_seconds, lines


def run_parallel(bench: Bench, sensors: Sequence[Sensor], models: Sequence[str], jobs: int,
                 *, schemes: Sequence[str] = SCHEMES, loop: bool = False,
                 step: Callable[[int], None] = lambda n: None) -> list[Case]:
    """``run_benchmark`` over ``jobs`` processes, one task per sensor and model (the
    largest first); the bags are made here first. ``step(n)`` after each task."""
    from concurrent.futures import ProcessPoolExecutor, as_completed
    from multiprocessing import get_context

    for sensor in sensors:
        for run in (*sensor.runs, *sensor.later):
            bench.bag(sensor, run)
    tasks = sorted((Task(bench.data, bench.out, bench.refit, sensor, model, tuple(schemes),
                         loop, dict(ENGINE), dict(LOOP), tuple(models), tuple(BOUND_MODELS),
                         AUTO_JOBS[0])
                    for sensor in sensors for model in models),
                   key=lambda t: -len(t.sensor.runs))
    cases: list[Case] = []
    bounds: dict[tuple[str, str, str], float] = {}
    with ProcessPoolExecutor(jobs, mp_context=get_context("spawn")) as pool:
        futures = {pool.submit(run_task, task): task for task in tasks}
        for future in as_completed(futures):
            task = futures[future]
            found_cases, found, seconds, lines = future.result()
            for line in lines:
                bench.log(line)
            cases += found_cases
            bounds.update({(task.sensor.name, *key): v for key, v in found.items()})
            bench.fit_seconds += seconds
            step(len(task.sensor.runs) * (1 + len(schemes)))
    order = {(s.name, m): i for i, (s, m) in enumerate((s, m) for s in sensors for m in models)}
    cases.sort(key=lambda c: order[c.sensor, c.model])
    set_best_in_run(cases, bounds)
    return cases


def weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    """The median of ``values`` where each counts ``weights`` times."""
    ok = np.isfinite(values)
    values, weights = values[ok], weights[ok]
    if values.size == 0:
        return math.nan
    order = np.argsort(values)
    cum = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cum, 0.5 * cum[-1])])


def summary(cases: Sequence[Case], scheme: str, workflow: str,
            ) -> dict[str, dict[str, dict[str, Any]]]:
    """{model: {sensor or "overall": {"median", "worst" (absolute RMSE; not overall),
    "ratio_median", "ratio_worst", "worst_case", "n"}}}."""
    out: dict[str, dict[str, dict[str, Any]]] = {}
    mine_all = [c for c in cases if c.scheme == scheme and workflow in c.rmse]
    for model in dict.fromkeys(c.model for c in mine_all):
        mine = [c for c in mine_all if c.model == model]
        counts: dict[str, int] = {}
        for c in mine:
            counts[c.sensor] = counts.get(c.sensor, 0) + 1
        groups = {s: [c for c in mine if c.sensor == s] for s in counts}
        groups["overall"] = mine
        out[model] = {}
        for key, group in groups.items():
            values = np.array([c.rmse[workflow] for c in group])
            ratios = np.array([c.ratio(workflow) for c in group])
            weights = np.array([1.0 / counts[c.sensor] for c in group])
            if not np.isfinite(ratios).any():
                continue
            worst = group[int(np.nanargmax(ratios))]
            cell = {"ratio_median": weighted_median(ratios, weights),
                    "ratio_worst": float(np.nanmax(ratios)), "n": len(group),
                    "worst_case": f"{worst.sensor} {worst.train} -> {worst.test}"}
            if key != "overall":  # absolute errors only within one sensor's unit
                cell.update(median=float(np.nanmedian(values)), worst=float(np.nanmax(values)))
            out[model][key] = cell
    return out


def markdown(cases: Sequence[Case], scheme: str, workflows_run: Sequence[str]) -> str:
    """One table per scheme: per model and sensor, for every workflow the median / worst
    RMSE and (in brackets) the median ratio to the best in-run bound."""
    tables = {w: summary(cases, scheme, w) for w in workflows_run}
    lines = [f"**{scheme}**", "",
             "| model | sensor | runs | best in-run | " + " | ".join(workflows_run) + " |",
             "|---|---|---:|---:|" + "---:|" * len(workflows_run)]
    for model, per_sensor in tables[workflows_run[0]].items():
        for key in per_sensor:
            cells = []
            for w in workflows_run:
                cell = tables[w].get(model, {}).get(key)
                if cell is None:
                    cells.append("-")
                elif key == "overall":
                    cells.append(f"({cell['ratio_median']:.2f})")
                else:
                    cells.append(f"{cell['median']:.2f} / {cell['worst']:.2f} "
                                 f"({cell['ratio_median']:.2f})")
            best = [c.best_in_run for c in cases if c.scheme == scheme and c.model == model
                    and (key == "overall" or c.sensor == key)]
            bound = "-" if key == "overall" else f"{np.nanmedian(best):.2f}"
            name = f"**{key}**" if key == "overall" else key
            lines.append(f"| {model} | {name} | {per_sensor[key]['n']} | {bound} | "
                         + " | ".join(cells) + " |")
    return "\n".join(lines)


def targets(cases: Sequence[Case]) -> list[str]:
    """The absolute targets (``TARGETS``), met or not, per model."""
    lines = []
    for (sensor, scheme, workflow, stat), limit in TARGETS.items():
        table = summary(cases, scheme, workflow)
        for model, per_sensor in table.items():
            cell = per_sensor.get(sensor)
            if cell is None:
                continue
            ok = cell[stat] <= limit
            lines.append(f"{model}: {sensor} {scheme} {workflow} {stat} {cell[stat]:.2f} "
                         f"(target <= {limit}): {'met' if ok else 'NOT met'}")
    return lines


def figures(cases: Sequence[Case], workflow: str, out: Path) -> list[Path]:
    """One bar chart: the median ratio to the best in-run bound per sensor and overall,
    a bar per model and scheme."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    schemes = list(dict.fromkeys(c.scheme for c in cases))
    tables = {s: summary(cases, s, workflow) for s in schemes}
    keys = list(dict.fromkeys(k for t in tables.values() for per in t.values() for k in per))
    keys = [k for k in keys if k != "overall"] + ["overall"]
    bars = [(s, m) for s in schemes for m in tables[s]]
    fig = Figure(figsize=(8.0, 3.8), layout="constrained")
    ax = fig.subplots()
    width = 0.8 / max(len(bars), 1)
    for i, (scheme, model) in enumerate(bars):
        x = np.arange(len(keys)) + (i - (len(bars) - 1) / 2) * width
        ax.bar(x, [tables[scheme][model].get(k, {}).get("ratio_median", np.nan) for k in keys],
               width, label=f"{model} {scheme}")
    ax.axhline(1.0, color="0.3", lw=0.8)
    ax.set_xticks(np.arange(len(keys)), keys)
    ax.set_ylabel("RMSE / best in-run bound")
    ax.set_title(f"median per sensor, session start '{workflow}'")
    ax.legend(fontsize=7, ncol=2)
    ax.grid(alpha=0.3, axis="y")
    path = out / ("generalisation_day2.png" if schemes == ["day2"] else
                  "generalisation_median.png")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    return [path]


def to_json(cases: Sequence[Case], schemes: Sequence[str], workflows_run: Sequence[str],
            meta: Mapping[str, Any]) -> dict[str, Any]:
    def finite(x: float) -> float | None:
        return x if math.isfinite(x) else None

    return {"meta": dict(meta), "headline": HEADLINE,
            "summary": {s: {w: summary(cases, s, w) for w in workflows_run} for s in schemes},
            "cases": [{"sensor": c.sensor, "model": c.model, "scheme": c.scheme,
                       "train": c.train, "test": c.test, "in_run_rmse": finite(c.in_run),
                       "best_in_run_rmse": finite(c.best_in_run),
                       "rmse": {k: finite(v) for k, v in c.rmse.items()},
                       "ratio": {k: finite(c.ratio(k)) for k in c.rmse}} for c in cases]}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--out", type=Path, default=REPO / "out" / "generalisation")
    parser.add_argument("--sensors", nargs="+", metavar="NAME",
                        help="cb, fiber, nylon, rig (default: all present)")
    parser.add_argument("--models", nargs="+", default=list(DEFAULT_MODELS))
    parser.add_argument("--schemes", nargs="+",
                        choices=("pair", "loro", "loro_raw", "loro_joint", "loro_stretch",
                                 "day2"),
                        default=list(SCHEMES))
    parser.add_argument("--bound-models", nargs="+", metavar="MODEL",
                        help="the models of the in-run bound (default: --models but auto; "
                             "cubic mpi apl for auto alone)")
    parser.add_argument("--auto-jobs", type=int, default=1, metavar="N",
                        help="worker processes of each fit --model auto (default 1)")
    parser.add_argument("--pool-raw", action="store_true",
                        help="also leave-one-run-out pooled as recorded (fit --pool raw)")
    parser.add_argument("--quick", action="store_true", help="three runs per sensor")
    parser.add_argument("--loop", action="store_true",
                        help="also the residual loop's calibration (pair scheme)")
    parser.add_argument("--loop-stretch-history", choices=("off", "on"), default="off",
                        help="the loop's diagnose --stretch-history")
    parser.add_argument("--loop-session-start", choices=("on", "off"), default="on",
                        help="the loop's diagnose --session-start")
    parser.add_argument("--loop-validate", type=int, default=3, metavar="N",
                        help="the loop validates on the first N runs other than A and B "
                             "(default 3)")
    parser.add_argument("--coverage", action="store_true",
                        help="only the uncertainty band: its coverage on every run left out "
                             "(leave one run out, warmup), and session 1 -> session 2 of "
                             "the thread")
    parser.add_argument("--refit", action="store_true", help="ignore cached fits")
    parser.add_argument("--jobs", type=int, default=1, metavar="N",
                        help="worker processes, one sensor and model each (default 1)")
    parser.add_argument("--out-of-range", choices=("clamp", "extrapolate", "extend"),
                        default="extend", help="evaluate's --out-of-range")
    parser.add_argument("--json", type=Path, help="write the results here "
                        "(default OUT/generalisation.json)")
    parser.add_argument("--figures", type=Path, metavar="DIR", help="write the PNG here")
    parser.add_argument("-q", "--quiet", action="store_true",
                        help="no progress bar and no per-case lines on stderr")
    args = parser.parse_args(argv)

    from strain_comp.progress import bar, wanted

    start = time.perf_counter()
    ENGINE.update(out_of_range=args.out_of_range)
    BOUND_MODELS[:] = args.bound_models or []
    AUTO_JOBS[0] = args.auto_jobs
    LOOP.update(stretch_history=args.loop_stretch_history == "on",
                session_start=args.loop_session_start == "on", validate=args.loop_validate)
    available = sensors_of(args.data)
    names = args.sensors or list(available)
    unknown = [n for n in names if n not in available]
    if unknown:
        parser.error(f"unknown or missing sensors {unknown}; present: {list(available)}")
    sensors = [quick(available[n]) if args.quick else available[n] for n in names]
    if args.coverage:
        day2 = another_day(args.data)
        bench = Bench(args.data, args.out, refit=args.refit,
                      log=(lambda line: None) if args.quiet else
                      lambda line: print(line, file=sys.stderr))
        table, rows = coverage_table(bench, sensors, args.models,
                                     day2 if (args.data / day2.runs[0].source).is_file()
                                     else None)
        print(table)
        path = args.json or args.out / "coverage.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps({"rows": rows, "seconds": time.perf_counter() - start},
                                   indent=1) + "\n", encoding="utf-8")
        print(f"wrote {path} ({time.perf_counter() - start:.0f} s)")
        return 0
    schemes = list(dict.fromkeys([*args.schemes, *(["loro_raw"] if args.pool_raw else [])]))
    steps = sum(len(s.runs) for s in sensors) * len(args.models) * (1 + len(schemes))
    with bar(steps, "benchmark", enabled=wanted(args.quiet)) as shown:
        bench = Bench(args.data, args.out, refit=args.refit,
                      log=(lambda line: None) if args.quiet else
                      lambda line: shown.write(line, file=sys.stderr))
        if args.jobs > 1:
            cases = run_parallel(bench, sensors, args.models, args.jobs, schemes=schemes,
                                 loop=args.loop, step=shown.update)
        else:
            cases = run_benchmark(bench, sensors, args.models, schemes=schemes,
                                  loop=args.loop, step=lambda: shown.update(1))
    run_workflows = [*WORKFLOWS, *(["loop"] if args.loop else [])]
    seconds = time.perf_counter() - start
    print("Median / worst RMSE over the test runs (each sensor's unit), in brackets the "
          "median ratio to the best in-run bound of any model\n")
    for scheme in schemes:
        print(markdown(cases, scheme, run_workflows))
        print()
    print("\n".join(targets(cases)))
    print(f"\n{len(cases)} cases in {seconds:.0f} s ({bench.fit_seconds:.0f} s of fitting; "
          "2 cores, timings vary by machine)")
    meta = {"out_of_range": args.out_of_range,
            "models": args.models, "sensors": names, "schemes": schemes,
            "quick": args.quick, "loop": args.loop, "loop_options": dict(LOOP),
            "jobs": args.jobs,
            "seconds": seconds, "fit_seconds": bench.fit_seconds}
    path = args.json or args.out / "generalisation.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(to_json(cases, schemes, run_workflows, meta), indent=1) + "\n",
                    encoding="utf-8")
    print(f"wrote {path}")
    if args.figures:
        for written in figures(cases, HEADLINE, args.figures):
            print(f"wrote {written}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
