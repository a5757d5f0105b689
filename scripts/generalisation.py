#!/usr/bin/env python3
"""Generalisation benchmark: a calibration fitted on one run, used on another run of the
same sensor, against what the model reaches on that run itself.

    python scripts/generalisation.py --out out/generalisation --figures docs

For every sensor in ``../shared/data/measured`` (carbon black ``cb``, conductive fibre
``fiber``, silver nylon thread ``nylon``) and the virtual rig (``rig``: five scenarios of
``strain-comp simulate``, one sensor), every ordered pair of runs (A, B) of that sensor:

1. A and B are imported into bags with ``strain-comp import-csv`` and the sensor's preset
   (``simulate``'s own bag writer for the rig);
2. the model is fitted on A alone (``fit_bags``, the code of ``strain-comp fit``, default
   options: a user's first try);
3. the calibration is used on B as a user would, in each *workflow*, and scored on all of
   B (``evaluate_recordings``, the numbers of ``strain-comp evaluate``):

   * ``plain``: ``evaluate`` as is (``--tare calibration``);
   * ``tare``: ``--tare auto``, the rest level read at the start of B;
   * ``recal``: ``--tare auto`` and the output gain and offset of ``recalibrate --from B
     --first SECONDS``, B's first cycle only (the reference strain of the first load and
     unload, what a user can measure at the start of a session; ``first_cycle``);
   * ``span``: ``recalibrate --input --from B --first SECONDS``: the input zero and span
     from the first rest and the largest strain of that cycle;
   * ``span_recal``: ``span``, then ``recal``'s output map on the same cycle;
   * ``loop`` (with ``--loop``): the headline workflow on the calibration the residual loop
     (``strain-comp diagnose A --validate C... --tare auto``) made from A, validated on up
     to three other runs C (the first runs other than A and B; ``--loop-validate N``); the
     loop scores its terms on each C after C's own session start and keeps those that lower
     the pooled and the median run's error (``--loop-session-start off``: as calibrated;
     ``--loop-stretch-history on``: with the ``stretch`` candidates).

The *in-run bound* of B is the same model fitted on B itself and scored on B (the
``evaluate --in-run-bound`` number). The **ratio** of a pair is the workflow's RMSE on B
divided by that bound: 1 means the calibration carried over as well as the model family
can fit B at all. Per sensor the table gives the median and the worst (largest) ratio over
its pairs; *overall* is the median with each sensor weighted equally (each pair weighs 1 /
its sensor's pair count), and the worst pair of all.

Fits are cached in ``OUT/cache`` under a key of the model, the run and a hash of the
fitting code (``strain_comp/models``, ``strain_comp/offline/fit.py``); ``--refit`` ignores
the cache. Prints a Markdown table, writes ``OUT/generalisation.json`` (or ``--json``) and,
with ``--figures DIR``, two PNGs (median and worst ratio per sensor and overall).
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
DEFAULT_MODELS = ("cubic", "mpi", "apl")
WORKFLOWS = ("plain", "tare", "recal", "span", "span_recal")
HEADLINE = "span_recal"
"""The workflow the targets are judged on: the session-start procedure docs/generalisation.md
recommends (chosen on this benchmark's overall medians)."""
HEADLINE_FORMS = {"recal": ("output",), "span": ("input",), "span_recal": ("input", "output")}
"""The recalibrations of each workflow (the loop's calibration gets the headline's)."""
TARGET_MEDIAN, TARGET_WORST = 1.3, 2.5
ENGINE = {"out_of_range": "extend", "tracking": "on"}
"""Engine options of every evaluation (``--out-of-range``)."""
LOOP = {"stretch_history": False, "session_start": True, "validate": 3}
"""Options of the loop workflow's ``diagnose`` (``--loop-stretch-history``,
``--loop-session-start``) and how many other runs it validates on (``--loop-validate``)."""
NYLON_COLUMNS = "time=time_s,resistance=r_over_r0,strain=position"


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
                      "mixed_20_30"))),
        "rig": Sensor("rig", tuple(Run(k, f"rig:{k}") for k in
                                   ("triangle", "rates", "patterns", "steps", "random"))),
    }
    return {k: v for k, v in out.items()
            if k == "rig" or all((data / r.source).is_file() for r in v.runs)}


def quick(sensor: Sensor) -> Sensor:
    """``--quick``: three runs per sensor (six ordered pairs)."""
    return replace(sensor, runs=sensor.runs[:3])


# --------------------------------------------------------------------------- the pieces


def first_cycle(t: np.ndarray, s: np.ndarray) -> float:
    """Seconds of a run's first load and unload (``strain_comp.diagnosis.session``, the
    cycle the loop's session start uses too; at most its ``FIRST_CYCLE_CAP`` of the run)."""
    from strain_comp.diagnosis.session import FIRST_CYCLE_CAP
    from strain_comp.diagnosis.session import first_cycle as cycle

    seconds = cycle(t, s)
    return FIRST_CYCLE_CAP * float(t[-1] - t[0]) if seconds is None else seconds


def code_hash() -> str:
    """Hash of the fitting code: a cached fit is reused only while it is unchanged."""
    digest = hashlib.sha256()
    files = sorted((REPO / "strain_comp" / "models").rglob("*.py"))
    for path in [*files, REPO / "strain_comp" / "offline" / "fit.py"]:
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

    def fit(self, sensor: Sensor, run: Run, model: str) -> Any:
        """``strain-comp fit RUN --model MODEL`` (default options), cached."""
        from strain_comp.core.calibration_file import load_calibration, save_calibration
        from strain_comp.offline.fit import fit_bags

        path = self.out / "cache" / f"{sensor.name}_{run.label}_{model}_{self.key}.yaml"
        if path in self.fits:
            return self.fits[path]
        if path.is_file() and not self.refit:
            self.fits[path] = load_calibration(path)
            return self.fits[path]
        start = time.perf_counter()
        name = "s1" if sensor.name == "rig" else sensor.name
        cal = fit_bags([self.bag(sensor, run)], model, [name])
        cal.sensors[name].strain_unit = sensor.unit
        self.fit_seconds += time.perf_counter() - start
        self.log(f"## fit {sensor.name}/{run.label} {model}: "
                 f"{time.perf_counter() - start:.1f} s")
        path.parent.mkdir(parents=True, exist_ok=True)
        save_calibration(cal, path)
        self.fits[path] = cal
        return cal


def rmse(rec: Any, cal: Any, *, tare: str = "calibration") -> float:
    """``strain-comp evaluate`` RMSE of ``cal`` on ``rec``."""
    from strain_comp.offline.evaluate import evaluate_recordings

    result = evaluate_recordings({rec.name: rec}, cal, tare=tare,
                                 out_of_range=ENGINE["out_of_range"],
                                 tracking=ENGINE["tracking"])
    return float(result.sensors[rec.name].stats.rmse)


def recalibrated(rec: Any, cal: Any, seconds: float, form: str = "output",
                 tare: str = "auto") -> Any:
    """``cal`` after ``recalibrate --from B --first SECONDS`` (``--input`` for the input
    form; the output form with ``--tare auto``)."""
    from strain_comp.offline.recalibrate import recalibrate_recordings

    return recalibrate_recordings(cal, {rec.name: rec}, form=form, first=seconds,
                                  tare=tare)[0]


def workflows(rec: Any, cal: Any, loop_cal: Any | None = None) -> dict[str, float]:
    """RMSE on ``rec`` of every workflow (``WORKFLOWS``; ``loop`` when ``loop_cal``).
    A recalibration that cannot be made (InputError: no rest in the first cycle, a strain
    the calibration never outputs) leaves the calibration as it was, as for a user."""
    seconds = first_cycle(rec.t, rec.s)
    out = {"plain": rmse(rec, cal), "tare": rmse(rec, cal, tare="auto")}
    out["recal"] = rmse(rec, chain(rec, cal, seconds, ("output",)), tare="auto")
    out["span"] = rmse(rec, chain(rec, cal, seconds, ("input",)))
    out["span_recal"] = rmse(rec, chain(rec, cal, seconds, ("input", "output")))
    if loop_cal is not None:
        forms = HEADLINE_FORMS[HEADLINE]
        out["loop"] = rmse(rec, chain(rec, loop_cal, seconds, forms),
                           tare="calibration" if "input" in forms else "auto")
    return out


def chain(rec: Any, cal: Any, seconds: float, forms: Sequence[str]) -> Any:
    """``cal`` after ``recalibrate --from B --first SECONDS`` in each form of ``forms``
    (``input``: ``--input``; ``output``: with ``--tare auto`` unless an input zero and
    span was made first); a step that cannot be made is skipped."""
    from strain_comp.errors import StrainCompError

    for form in forms:
        tare = "calibration" if form == "output" and "input" in forms else "auto"
        try:
            cal = recalibrated(rec, cal, seconds, form, tare=tare)
        except StrainCompError:
            continue
    return cal


def looped(bench: Bench, sensor: Sensor, train: Run, validate: Sequence[Run], model: str
           ) -> Any:
    """The calibration ``strain-comp diagnose TRAIN --validate VALIDATE...`` makes, cached."""
    from strain_comp.core.calibration_file import load_calibration
    from strain_comp.diagnosis.command import diagnose_bag

    options = ("_stretch" if LOOP["stretch_history"] else "") + (
        "" if LOOP["session_start"] else "_nosession")
    path = bench.out / "cache" / (f"{sensor.name}_{train.label}_{model}_loop_"
                                  f"{'+'.join(r.label for r in validate)}{options}_"
                                  f"{bench.key}.yaml")
    if not path.is_file() or bench.refit:
        cal = bench.fit(sensor, train, model)
        src = bench.out / "cache" / f"{sensor.name}_{train.label}_{model}_{bench.key}.yaml"
        with contextlib.redirect_stdout(sys.stderr):
            diagnose_bag(str(bench.bag(sensor, train)), cal,
                         validate=[str(bench.bag(sensor, r)) for r in validate],
                         out=str(path), plots=None, inputs=[str(src)], tare="auto",
                         stretch_history=LOOP["stretch_history"],
                         session_start=LOOP["session_start"])
    return load_calibration(path)


# --------------------------------------------------------------------------- the benchmark


@dataclass
class Pair:
    sensor: str
    model: str
    train: str
    test: str
    in_run: float
    rmse: dict[str, float] = field(default_factory=dict)

    def ratio(self, workflow: str) -> float:
        value = self.rmse.get(workflow, math.nan)
        return value / self.in_run if self.in_run > 0 else math.nan


def run_benchmark(bench: Bench, sensors: Sequence[Sensor], models: Sequence[str], *,
                  loop: bool = False, step: Callable[[], None] = lambda: None) -> list[Pair]:
    """Every ordered pair of runs of every sensor, for every model; ``step()`` after each
    in-run fit and each pair (a progress bar)."""
    from strain_comp.errors import StrainCompError

    pairs: list[Pair] = []
    for sensor in sensors:
        for model in models:
            in_run: dict[str, float] = {}
            for run in sensor.runs:
                try:
                    in_run[run.label] = rmse(bench.recording(sensor, run),
                                             bench.fit(sensor, run, model))
                except StrainCompError as err:
                    bench.log(f"## {sensor.name}/{run.label} {model}: no in-run bound ({err})")
                step()
            for train in sensor.runs:
                for test in sensor.runs:
                    if train == test:
                        continue
                    step()
                    if test.label not in in_run:
                        continue
                    try:
                        cal = bench.fit(sensor, train, model)
                    except StrainCompError as err:
                        bench.log(f"## {sensor.name}/{train.label} {model}: {err}")
                        break
                    loop_cal = None
                    if loop:
                        others = [r for r in sensor.runs if r not in (train, test)]
                        if others:
                            loop_cal = looped(bench, sensor, train,
                                              others[:int(LOOP["validate"])], model)
                    rec = bench.recording(sensor, test)
                    pair = Pair(sensor.name, model, train.label, test.label,
                                in_run[test.label], workflows(rec, cal, loop_cal))
                    pairs.append(pair)
                    bench.log(f"## {sensor.name} {model} {train.label} -> {test.label}: "
                              + ", ".join(f"{k} {pair.ratio(k):.2f}" for k in pair.rmse))
    return pairs


def weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    """The median of ``values`` where each counts ``weights`` times."""
    ok = np.isfinite(values)
    values, weights = values[ok], weights[ok]
    if values.size == 0:
        return math.nan
    order = np.argsort(values)
    cum = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cum, 0.5 * cum[-1])])


def summary(pairs: Sequence[Pair], workflow: str) -> dict[str, dict[str, dict[str, Any]]]:
    """{model: {sensor or "overall": {"median", "worst", "worst_pair", "n"}}}."""
    out: dict[str, dict[str, dict[str, Any]]] = {}
    for model in dict.fromkeys(p.model for p in pairs):
        mine = [p for p in pairs if p.model == model and workflow in p.rmse]
        counts: dict[str, int] = {}
        for p in mine:
            counts[p.sensor] = counts.get(p.sensor, 0) + 1
        groups = {s: [p for p in mine if p.sensor == s] for s in counts}
        groups["overall"] = mine
        out[model] = {}
        for key, group in groups.items():
            ratios = np.array([p.ratio(workflow) for p in group])
            weights = np.array([1.0 / counts[p.sensor] for p in group])
            if not np.isfinite(ratios).any():
                continue
            worst = group[int(np.nanargmax(ratios))]
            out[model][key] = {"median": weighted_median(ratios, weights),
                               "worst": float(np.nanmax(ratios)), "n": len(group),
                               "worst_pair": f"{worst.sensor} {worst.train} -> {worst.test}"}
    return out


def markdown(pairs: Sequence[Pair], workflows_run: Sequence[str]) -> str:
    """One table: per model and sensor, median / worst ratio of every workflow."""
    tables = {w: summary(pairs, w) for w in workflows_run}
    lines = ["| model | sensor | pairs | " + " | ".join(
        f"{w} median / worst" for w in workflows_run) + " | worst pair (" + HEADLINE + ") |",
             "|---|---|---:|" + "---:|" * len(workflows_run) + "---|"]
    for model, per_sensor in tables[workflows_run[0]].items():
        for key in per_sensor:
            cells = []
            for w in workflows_run:
                cell = tables[w].get(model, {}).get(key)
                cells.append("-" if cell is None else f"{cell['median']:.2f} / {cell['worst']:.2f}")
            head_cell = tables.get(HEADLINE, {}).get(model, {}).get(key, {})
            name = f"**{key}**" if key == "overall" else key
            lines.append(f"| {model} | {name} | {per_sensor[key]['n']} | " + " | ".join(cells)
                         + f" | {head_cell.get('worst_pair', '-')} |")
    return "\n".join(lines)


def targets(pairs: Sequence[Pair]) -> list[str]:
    """The targets, met or not, on the headline workflow."""
    lines = []
    for model, per_sensor in summary(pairs, HEADLINE).items():
        overall = per_sensor.get("overall")
        if overall is None:
            continue
        ok = overall["median"] <= TARGET_MEDIAN and overall["worst"] <= TARGET_WORST
        lines.append(f"{model} ({HEADLINE}): overall median {overall['median']:.2f} "
                     f"(target <= {TARGET_MEDIAN}), worst {overall['worst']:.2f} "
                     f"(target <= {TARGET_WORST}): {'met' if ok else 'NOT met'}")
        nylon = per_sensor.get("nylon")
        if nylon is not None:
            lines.append(f"{model} ({HEADLINE}): nylon median {nylon['median']:.2f} "
                         f"(target <= 1.5): {'met' if nylon['median'] <= 1.5 else 'NOT met'}")
    return lines


def figures(pairs: Sequence[Pair], workflow: str, out: Path) -> list[Path]:
    """Two bar charts: median and worst ratio per sensor and overall, a bar per model."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    table = summary(pairs, workflow)
    keys = list(dict.fromkeys(k for per in table.values() for k in per))
    keys = [k for k in keys if k != "overall"] + ["overall"]
    written = []
    for stat, target in (("median", TARGET_MEDIAN), ("worst", TARGET_WORST)):
        fig = Figure(figsize=(8.0, 3.8), layout="constrained")
        ax = fig.subplots()
        width = 0.8 / max(len(table), 1)
        for i, (model, per) in enumerate(table.items()):
            x = np.arange(len(keys)) + (i - (len(table) - 1) / 2) * width
            ax.bar(x, [per.get(k, {}).get(stat, np.nan) for k in keys], width, label=model)
        ax.axhline(1.0, color="0.3", lw=0.8)
        ax.axhline(target, color="tab:red", lw=0.8, ls="--", label=f"target {target}")
        ax.set_xticks(np.arange(len(keys)), keys)
        ax.set_ylabel("cross-run RMSE / in-run bound")
        ax.set_title(f"{stat} ratio per sensor, workflow '{workflow}' "
                     "(fit on one run, use on another)")
        ax.legend()
        ax.grid(alpha=0.3, axis="y")
        path = out / f"generalisation_{stat}.png"
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=100)
        written.append(path)
    return written


def to_json(pairs: Sequence[Pair], workflows_run: Sequence[str],
            meta: Mapping[str, Any]) -> dict[str, Any]:
    def finite(x: float) -> float | None:
        return x if math.isfinite(x) else None

    return {"meta": dict(meta), "headline": HEADLINE,
            "summary": {w: summary(pairs, w) for w in workflows_run},
            "pairs": [{"sensor": p.sensor, "model": p.model, "train": p.train, "test": p.test,
                       "in_run_rmse": finite(p.in_run),
                       "rmse": {k: finite(v) for k, v in p.rmse.items()},
                       "ratio": {k: finite(p.ratio(k)) for k in p.rmse}} for p in pairs]}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--out", type=Path, default=REPO / "out" / "generalisation")
    parser.add_argument("--sensors", nargs="+", metavar="NAME",
                        help="cb, fiber, nylon, rig (default: all present)")
    parser.add_argument("--models", nargs="+", default=list(DEFAULT_MODELS))
    parser.add_argument("--quick", action="store_true", help="three runs per sensor")
    parser.add_argument("--loop", action="store_true",
                        help="also the residual loop's calibration (diagnose on a third run)")
    parser.add_argument("--loop-stretch-history", choices=("off", "on"), default="off",
                        help="the loop's diagnose --stretch-history")
    parser.add_argument("--loop-session-start", choices=("on", "off"), default="on",
                        help="the loop's diagnose --session-start")
    parser.add_argument("--loop-validate", type=int, default=3, metavar="N",
                        help="the loop validates on the first N runs other than A and B "
                             "(default 3)")
    parser.add_argument("--refit", action="store_true", help="ignore cached fits")
    parser.add_argument("--out-of-range", choices=("clamp", "extrapolate", "extend"),
                        default="extend",
                        help="evaluate's --out-of-range")
    parser.add_argument("--baseline-tracking", choices=("off", "on"), default="on",
                        help="evaluate's --baseline-tracking")
    parser.add_argument("--json", type=Path, help="write the results here "
                        "(default OUT/generalisation.json)")
    parser.add_argument("--figures", type=Path, metavar="DIR", help="write the two PNGs here")
    parser.add_argument("-q", "--quiet", action="store_true",
                        help="no progress bar and no per-pair lines on stderr")
    args = parser.parse_args(argv)

    from strain_comp.progress import bar, wanted

    start = time.perf_counter()
    ENGINE.update(out_of_range=args.out_of_range, tracking=args.baseline_tracking)
    LOOP.update(stretch_history=args.loop_stretch_history == "on",
                session_start=args.loop_session_start == "on", validate=args.loop_validate)
    available = sensors_of(args.data)
    names = args.sensors or list(available)
    unknown = [n for n in names if n not in available]
    if unknown:
        parser.error(f"unknown or missing sensors {unknown}; present: {list(available)}")
    sensors = [quick(available[n]) if args.quick else available[n] for n in names]
    steps = sum(len(s.runs) ** 2 for s in sensors) * len(args.models)
    with bar(steps, "benchmark", enabled=wanted(args.quiet)) as shown:
        bench = Bench(args.data, args.out, refit=args.refit,
                      log=(lambda line: None) if args.quiet else
                      lambda line: shown.write(line, file=sys.stderr))
        pairs = run_benchmark(bench, sensors, args.models, loop=args.loop,
                              step=lambda: shown.update(1))
    run_workflows = [*WORKFLOWS, *(["loop"] if args.loop else [])]
    seconds = time.perf_counter() - start
    print(markdown(pairs, run_workflows))
    print()
    print("\n".join(targets(pairs)))
    print(f"\n{len(pairs)} pairs in {seconds:.0f} s ({bench.fit_seconds:.0f} s of fitting; "
          "2 cores, timings vary by machine)")
    meta = {"out_of_range": args.out_of_range, "baseline_tracking": args.baseline_tracking,
            "models": args.models, "sensors": names,
            "quick": args.quick, "loop": args.loop, "loop_options": dict(LOOP),
            "seconds": seconds,
            "fit_seconds": bench.fit_seconds}
    path = args.json or args.out / "generalisation.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(to_json(pairs, run_workflows, meta), indent=1) + "\n",
                    encoding="utf-8")
    print(f"wrote {path}")
    if args.figures:
        for written in figures(pairs, HEADLINE, args.figures):
            print(f"wrote {written}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
