#!/usr/bin/env python3
# Study: What does each tuned number of the engine's policies buy? (docs/results.md)
"""Policy ablation: what each tuned number of the engine's policies buys on the measured data.

    python studies/policy_ablation.py --out out/generalisation

For every number of the out-of-range rule, the tare, the fusion and the session start
(module constants of ``core/range_policy.py``, ``core/tare.py``, ``core/fusion.py``,
``offline/session_start.py``; docs/results.md), the benchmark's leave-one-run-out scheme
(``scripts/generalisation.py``: fits pooled over the other runs, then the session start and
the evaluation as a user makes them) is rerun with that field set to its neutral value (the
rule turned off, or a resolution made coarser), everything else at its default, and the
change of the benchmark's figures is printed as one Markdown table.

Subset (``--runs``, ``--models``): by default the first three runs of each sensor
(``generalisation.py --quick``: carbon black v16, v19, v10; fibre run1, run3, run4; thread
sin_20, sin_30, sin_40; the rig's triangle, rates and patterns) and three models,
``cubic`` (static: spanned through two points), ``mpi`` and ``creep_pi`` (memory: spanned
on their branches and through the run), so every sensor type and both span paths are in
every row (36 cases; 19 min here with ``--guards``, 2 cores shared). The fits are
made once with the default policies (cached in ``OUT/cache`` as the benchmark's are); an
ablation changes how a calibration is used, not how it was fitted.

Each row gives, per sensor, the change of the median RMSE (each sensor's unit: fibre mm,
else % strain) of the workflow the field acts in: ``warmup`` (the README's session start)
for the range and span policies, ``as_is`` (``evaluate --tare auto``) for the
tare, ``refs_60`` (a known strain every 60 s) for the fusion; and the largest relative
change of any case in any workflow. The benchmark is deterministic: a change is *beyond
noise* when a sensor's median moves by more than ``NOISE_MEDIAN`` of itself or a case by
more than ``NOISE_CASE`` (differences of the floating-point order, as from the summation
order of a refit, stay far below both).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import math
import os
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "scripts"))

import generalisation as gen  # noqa: E402  (the benchmark's machinery, one file beside)

POLICIES = {"range": ("strain_comp.core.range_policy", ""),
            "tare": ("strain_comp.core.tare", ""),
            "fusion": ("strain_comp.core.fusion", ""),
            "span": ("strain_comp.offline.session_start", "")}
"""Policy -> (module, name of its default instance; empty: each number is a constant of
the module, the field's name in capitals, ``REST_WINDOW`` for the tare's window)."""


def _holder(policy: str, field: str) -> tuple[Any, str]:
    """(the object holding the number, its attribute name): a module, or a policy instance."""
    module, name = POLICIES[policy]
    if name:
        return getattr(importlib.import_module(module), name), field
    return importlib.import_module(module), "REST_WINDOW" if field == "window" else field.upper()
WORKFLOW = {"range": "warmup", "tare": "as_is", "fusion": "refs_60",
            "span": "warmup", "mode": "warmup"}
"""The workflow whose median each policy's rows report."""
NOISE_MEDIAN = 0.01
"""A sensor's median RMSE moving by more than this share of itself is beyond noise."""
NOISE_CASE = 0.03
"""A case's RMSE moving by more than this share of itself is beyond noise."""
GUARD_TESTS = {"range": ("test_out_of_range.py", "test_reliability.py", "test_engine.py"),
               "tare": ("test_tare.py",),
               "fusion": ("test_fusion.py",),
               "span": ("test_recalibrate_checks.py", "test_recalibrate_memory.py",
                        "test_span_run.py", "test_pool_and_window.py", "test_tare.py")}
"""The tests of each policy's faults (``--guards``: rerun with the field neutral)."""
DEFAULT_MODELS = ("cubic", "mpi", "creep_pi")
INF = math.inf


@dataclass(frozen=True)
class Ablation:
    """One row: ``policy.field`` set to ``neutral`` (``mode``: an engine option instead)."""

    policy: str
    field: str
    neutral: Any
    what: str
    """What the neutral value means."""


ABLATIONS = (
    Ablation("mode", "out_of_range", "clamp", "no extension beyond the valid range"),
    Ablation("range", "open_factor", INF, "no open-circuit flag"),
    Ablation("range", "short_factor", 0.0, "no short-circuit flag"),
    Ablation("range", "margin", 0.0, "flag and clamp at the fitted range's edge"),
    Ablation("range", "extend_slope", (0.0, INF), "end slope unbounded"),
    Ablation("range", "extend_monotone", INF, "a branch that peaked is extended too"),
    Ablation("range", "extend_reach", INF, "extension without reach"),
    Ablation("range", "settle_steps", 50, "a 4x coarser, faster ramp"),
    Ablation("tare", "window", INF, "the whole leading rest"),
    Ablation("tare", "min_rest_samples", 1, "one sample is a rest"),
    Ablation("tare", "min_rest_seconds", 0.0, "no rest duration needed"),
    Ablation("tare", "max_rest_drift", INF, "a drifting start is tared"),
    Ablation("tare", "rest_band", 0.1, "a 5x wider rest band"),
    Ablation("fusion", "gain_sd", 0.0, "no prior gain uncertainty"),
    Ablation("fusion", "offset_share", 0.0, "no prior offset uncertainty"),
    Ablation("fusion", "gain_walk", 0.0, "the gain does not walk"),
    Ablation("fusion", "offset_walk_share", 0.0, "the offset does not walk"),
    Ablation("fusion", "noise_share", 0.001, "references trusted fully"),
    Ablation("fusion", "gate", INF, "no gate"),
    Ablation("span", "settle_samples", 50, "steady outputs after 5 s"),
    Ablation("span", "grid_points", 51, "a 4x coarser grid"),
    Ablation("span", "static_tolerance", INF, "every model spanned as a static one"),
    Ablation("span", "fit_evaluations", 0, "no search through the run"),
    Ablation("span", "fit_step", (0.1, 0.4), "2x larger first steps"),
    Ablation("span", "fit_tolerance", (1e-2, 1e-3), "10x looser stop"),
    Ablation("span", "from_cover", 0.0, "no coverage needed"),
    Ablation("span", "cycle_up", 0.3, "a cycle passes 30 % of the span"),
    Ablation("span", "cycle_back", 0.3, "a cycle returns within 30 %"),
    Ablation("span", "min_cycle_share", 0.0, "no window stretch needed"),
)


@contextlib.contextmanager
def installed(policy: str, field: str, value: Any) -> Iterator[None]:
    """``policy.field`` = ``value`` (a module constant, or a field of the default instance)
    in every module of the package that holds it (``from ... import MARGIN`` binds the name
    in the importer), the default restored after; ``mode``: the benchmark's engine option."""
    if policy == "mode":
        old_engine = dict(gen.ENGINE)
        gen.ENGINE.update({field: value})
        try:
            yield
        finally:
            gen.ENGINE.clear()
            gen.ENGINE.update(old_engine)
        return
    module, name = POLICIES[policy]
    if name:
        old = getattr(importlib.import_module(module), name)
        new = replace(old, **{field: value})
    else:  # a module constant: every module that imported it holds the name
        name = _holder(policy, field)[1]
        old = getattr(importlib.import_module(module), name)
        new = value
    holders = [m for key, m in list(sys.modules.items())
               if key.startswith("strain_comp") and getattr(m, name, None) is old]
    for m in holders:
        setattr(m, name, new)
    try:
        yield
    finally:
        for m in holders:
            setattr(m, name, old)


def default_value(ablation: Ablation) -> Any:
    if ablation.policy == "mode":
        return "extend" if ablation.field == "out_of_range" else "on"
    return getattr(*_holder(ablation.policy, ablation.field))


Cases = dict[tuple[str, str, str], dict[str, float]]
"""(sensor, model, test run) -> workflow -> RMSE."""


def run_cases(bench: gen.Bench, sensors: Sequence[gen.Sensor], models: Sequence[str],
              calibrations: dict[tuple[str, str, str], Any]) -> Cases:
    """Every leave-one-run-out case's workflows (``generalisation.workflows``)."""
    out: Cases = {}
    for sensor in sensors:
        for model in models:
            for test in sensor.runs:
                key = (sensor.name, model, test.label)
                if key not in calibrations:
                    others = [r for r in sensor.runs if r != test]
                    calibrations[key] = bench.fit(sensor, others, model, "spanned")
                rec = bench.recording(sensor, test)
                out[key] = gen.workflows(rec, calibrations[key], log=lambda line: None)
    return out


def medians(cases: Cases, workflow: str) -> dict[str, float]:
    """Per sensor, the median RMSE of ``workflow`` over its cases."""
    sensors = dict.fromkeys(k[0] for k in cases)
    return {s: float(np.median([v[workflow] for k, v in cases.items() if k[0] == s]))
            for s in sensors}


def largest_change(base: Cases, trial: Cases) -> tuple[float, str]:
    """The largest relative change of any case in any workflow, and where."""
    best, where = 0.0, "-"
    for key, values in base.items():
        for workflow, value in values.items():
            change = abs(trial[key][workflow] - value) / max(abs(value), 1e-12)
            if change > best:
                best, where = change, f"{key[0]} {key[1]} {key[2]} {workflow}"
    return best, where


def guard(index: int) -> str:
    """The first of the policy's ``GUARD_TESTS`` that fails with ablation ``index``'s field
    neutral (pytest in a child process, the default instance replaced before the tests
    import it), or ``-`` when all pass."""
    ablation = ABLATIONS[index]
    if ablation.policy == "mode":
        return "-"
    code = ("import sys, pytest, policy_ablation as p\n"
            f"with p.installed(*p.as_installed({index})):\n"
            "    sys.exit(pytest.main(sys.argv[1:]))\n")
    files = [str(path) for name in GUARD_TESTS[ablation.policy]
             for path in sorted((REPO / "test").rglob(name))]
    done = subprocess.run([sys.executable, "-c", code, "-x", "-q", "-p", "no:cacheprovider",
                           *files], cwd=REPO, capture_output=True, text=True, check=False,
                          env={**os.environ,
                               "PYTHONPATH": f"{REPO}:{REPO / 'scripts'}:{REPO / 'studies'}"})
    failed = [line.split(" ", 1)[1].split(" - ")[0] for line in done.stdout.splitlines()
              if line.startswith("FAILED ")]
    if done.returncode == 0:
        return "-"
    return failed[0].removeprefix("test/") if failed else "error"


def as_installed(index: int) -> tuple[str, str, Any]:
    """(policy, field, neutral) of ablation ``index`` (``installed``'s arguments)."""
    a = ABLATIONS[index]
    return a.policy, a.field, a.neutral


def text(value: Any) -> str:
    if isinstance(value, tuple):
        return "(" + ", ".join(text(v) for v in value) + ")"
    if isinstance(value, float):
        return "inf" if math.isinf(value) else f"{value:g}"
    return str(value)


def row(index: int, base: Cases, trial: Cases, sensors: Sequence[str], guards: bool) -> str:
    """The table row of ablation ``index``; with ``guards``, the first guard test that
    fails with it (``guard``) where the benchmark moves within noise."""
    ablation = ABLATIONS[index]
    workflow = WORKFLOW[ablation.policy]
    before, after = medians(base, workflow), medians(trial, workflow)
    cells = [f"{after[s] - before[s]:+.3f}" for s in sensors]
    moved = any(abs(after[s] - before[s]) > NOISE_MEDIAN * before[s] for s in sensors)
    case, where = largest_change(base, trial)
    verdict = "moves" if moved or case > NOISE_CASE else "within noise"
    test = guard(index) if guards and verdict == "within noise" else ""
    return (f"| {ablation.policy}.{ablation.field} | {text(default_value(ablation))} | "
            f"{text(ablation.neutral)} ({ablation.what}) | {workflow} | " + " | ".join(cells)
            + f" | {100 * case:.1f} % ({where}) | {verdict} | {test} |")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=gen.DEFAULT_DATA)
    parser.add_argument("--out", type=Path, default=REPO / "out" / "generalisation",
                        help="bags and fits, shared with scripts/generalisation.py")
    parser.add_argument("--models", nargs="+", default=list(DEFAULT_MODELS))
    parser.add_argument("--runs", type=int, default=3, help="test runs per sensor (first N)")
    parser.add_argument("--only", nargs="+", metavar="POLICY[.FIELD]",
                        help="only these rows (e.g. range tare.window)")
    parser.add_argument("--guards", action="store_true",
                        help="for a row within noise, the first test of the policy's faults "
                             "that fails with the field neutral (GUARD_TESTS)")
    args = parser.parse_args(argv)

    start = time.perf_counter()
    available = gen.sensors_of(args.data)
    sensors = [replace(s, runs=s.runs[:args.runs]) for s in available.values()]
    names = [s.name for s in sensors]
    bench = gen.Bench(args.data, args.out, log=lambda line: print(line, file=sys.stderr))
    calibrations: dict[tuple[str, str, str], Any] = {}
    base = run_cases(bench, sensors, args.models, calibrations)
    chosen = [i for i, a in enumerate(ABLATIONS) if not args.only
              or any(o in (a.policy, f"{a.policy}.{a.field}") for o in args.only)]
    print(f"Baseline ({', '.join(args.models)}; leave-one-run-out on the first {args.runs} "
          f"runs of {', '.join(names)}), median RMSE per sensor:\n")
    print("| workflow | " + " | ".join(names) + " |")
    print("|---|" + "---:|" * len(names))
    for workflow in gen.WORKFLOWS:
        per = medians(base, workflow)
        print(f"| {workflow} | " + " | ".join(f"{per[s]:.3f}" for s in names) + " |")
    print("\nChange of the median RMSE with one field neutral (each sensor's unit), the "
          "largest change of any case in any workflow, and the verdict:\n")
    print("| field | value | neutral | workflow | " + " | ".join(names)
          + " | largest case change | verdict | guard test |")
    print("|---|---|---|---|" + "---:|" * len(names) + "---|---|---|")
    for index in chosen:
        began = time.perf_counter()
        with installed(*as_installed(index)):
            trial = run_cases(bench, sensors, args.models, calibrations)
        print(row(index, base, trial, names, args.guards), flush=True)
        print(f"## {ABLATIONS[index].field}: {time.perf_counter() - began:.0f} s",
              file=sys.stderr)
    print(f"\n{len(chosen)} ablations of {len(base)} cases in "
          f"{time.perf_counter() - start:.0f} s (2 cores shared, timings vary by machine)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
