"""Measurement-chain and tare hypotheses around the residual loop: each condition reruns the
whole loop (docs/design.md, "Conditions", says which is chosen)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from strain_comp.core.calibration import Calibration
from strain_comp.core.chain import (
    DESPIKE_K,
    STEP_K,
    STEP_SAMPLES,
    alternation,
    correct,
    quantisation,
)
from strain_comp.core.engine import Engine
from strain_comp.core.tare import tare_engine
from strain_comp.diagnosis.loop import diagnose
from strain_comp.diagnosis.report import DiagnoseResult
from strain_comp.diagnosis.residuals import as_bags
from strain_comp.diagnosis.selection import LOOP_POLICY, LoopPolicy, upper_bound
from strain_comp.io.recording import Recording

CHAIN_CONDITIONS = ("alternation", "despike", "baseline step")


def _with_input(calibration: Calibration, names: set[str], **settings: Any) -> Calibration:
    """``calibration`` with the ``InputSettings`` fields ``settings`` set for ``names``."""
    return Calibration({
        n: dataclasses.replace(c, input=dataclasses.replace(c.input, **settings))
        if n in names else c for n, c in calibration.sensors.items()})


@dataclasses.dataclass
class ChainFindings:
    """The sensors each chain condition would correct, and the reading lines by kind."""

    sensors: dict[str, set[str]] = dataclasses.field(
        default_factory=lambda: {kind: set() for kind in CHAIN_CONDITIONS})
    readings: list[tuple[str, str]] = dataclasses.field(default_factory=list)

    def lines(self, kind: str) -> list[str]:
        return [line for k, line in self.readings if k == kind]


def _reference_note(rec: Recording, t: float) -> str:
    """Whether the reference jumps too around a step at ``t`` (no jump: a baseline step)."""
    if rec.s is None or np.asarray(rec.t).size < 3:
        return ""
    times, strain = np.asarray(rec.t), np.asarray(rec.s, dtype=np.float64)
    dt = float(np.median(np.diff(times)))
    seen = (times >= t - (STEP_SAMPLES + 6) * dt) & (times <= t) & np.isfinite(strain)
    finite = strain[np.isfinite(strain)]
    span = float(np.ptp(finite)) if finite.size else 0.0
    if np.count_nonzero(seen) < 3 or not span > 0:
        return ""
    steps = np.diff(strain[seen])
    jump = float(np.max(np.abs(steps - np.median(steps)))) / span
    return (" (the reference shows no jump there)" if jump < 0.01
            else " (the reference jumps too: a strain change?)")


def chain_findings(recordings: Mapping[str, Recording], calibration: Calibration,
                   ) -> ChainFindings:
    """What the measurement chain shows in ``recordings`` that ``calibration`` does not correct."""
    found = ChainFindings()
    spikes: list[tuple[str, str]] = []
    steps: list[tuple[str, str]] = []
    for name, rec in recordings.items():
        if name not in calibration.sensors:
            continue
        settings = calibration.sensors[name].input
        raw = np.asarray(rec.r, dtype=np.float64)
        r = settings.to_ohm(raw)  # what the engine's input path reads (divider volts: ohm)
        wobble = alternation(r)
        if wobble.present:
            done = settings.alternation
            found.readings.append(("alternation", f"{name}: {wobble.reading()}"
                                   + (" (corrected by the calibration)" if done else "")))
            if not done:
                found.sensors["alternation"].add(name)
        # what the engine's corrector would see: the calibration's pair statistic if it
        # reads one, pair means if an alternation is found (the condition switches them on)
        _, _, corrector = correct(rec.t, r, step_k=STEP_K,
                                  alternating=settings.alternation or wobble.present,
                                  pair=settings.pair if settings.alternation else "mean")
        if corrector.n_spikes and settings.despike is None:
            found.sensors["despike"].add(name)
            plural = "s" if corrector.n_spikes > 1 else ""
            spikes.append(("despike", f"{name}: {corrector.n_spikes} isolated spike{plural} in "
                           f"{r.size} samples (held out online at {DESPIKE_K:g} robust sigmas)"))
        if corrector.steps and settings.baseline_step is None:
            found.sensors["baseline step"].add(name)
            steps += [("baseline step", f"{name}: {step.reading()}"
                       f"{_reference_note(rec, step.t)}") for step in corrector.steps]
        step = quantisation(raw)  # an ADC quantises what it reads: volts of a divider
        if step is not None:
            what = ("divider voltage", "V") if settings.kind == "divider" else ("resistance",
                                                                                "ohm")
            found.readings.append(("quantisation", f"{name}: {what[0]} quantised in steps of "
                                   f"{step:.3g} {what[1]}"))
    found.readings += spikes + steps
    return found


def _tare_outcome(calibration: Calibration, *runs: Mapping[str, Recording] | None) -> str:
    """What ``--tare auto`` did on each run, in words: the tare taken, or why not."""
    lines = []
    for k, run in enumerate(r for r in runs if r is not None):
        where = "training run" if k == 0 else "validation run"
        outcome = tare_engine(Engine(calibration), {n: (rec.t, rec.r) for n, rec in run.items()},
                              "auto")
        lines += [f"{where} {name}: {line.removeprefix('tare: ')}"
                  for name, line in outcome.items()]
    return "; ".join(lines) or "no sensor with a rest resistance to tare"


def _carries(result: DiagnoseResult, reference: DiagnoseResult, policy: LoopPolicy) -> bool:
    """Does ``result`` lower the validation runs' error beyond the spread between runs?"""
    ratios = [math.log(a / b) for name, d in result.sensors.items() if name in reference.sensors
              for a, b in zip(d.runs_after, reference.sensors[name].runs_after, strict=False)
              if a > 0 and b > 0]
    return len(ratios) < 2 or upper_bound(ratios, policy.level) < math.log(1.0 - policy.margin)


def _chosen(results: Sequence[DiagnoseResult], policy: LoopPolicy) -> int:
    """The index of the condition chosen (docs/design.md, "Conditions")."""
    best = 0
    for k, result in enumerate(results[1:], start=1):  # below the best is below the first
        if result.after["rmse"] < (1.0 - policy.margin) * results[best].after["rmse"] \
                and _carries(result, results[0], policy):
            best = k
    return best


def diagnose_conditions(recordings: Mapping[str, Recording], calibration: Calibration, *,
                        validate_recordings: Mapping[str, Recording]
                        | Sequence[Mapping[str, Recording]] | None = None,
                        tare: str = "calibration", policy: LoopPolicy = LOOP_POLICY,
                        progress: Callable[[int, int], None] | None = None,
                        **options: Any) -> DiagnoseResult:
    """``diagnose`` under each condition (docs/design.md, "Conditions"); the chosen result."""
    found = chain_findings(recordings, calibration)
    validate = [] if validate_recordings is None else as_bags(validate_recordings)
    for bag in validate:  # what the validation runs show is tested as well
        more = chain_findings(bag, calibration)
        for kind in CHAIN_CONDITIONS:
            found.sensors[kind].update(more.sensors[kind])
        found.readings += [(kind, f"{line} (validation run)") for kind, line in more.readings]
    runs: list[tuple[str, str, Calibration, str]] = [
        ("as calibrated", "the calibration's rest resistance and input", calibration,
         "calibration")]
    if tare == "auto":
        runs.append(("tare", _tare_outcome(calibration, recordings, *validate),
                     calibration, "auto"))
    base = calibration
    if found.sensors["alternation"]:
        base = _with_input(calibration, found.sensors["alternation"], alternation=True)
        text = "; ".join(found.lines("alternation"))
        runs.append(("alternation", f"pair means for {text}", base, "calibration"))
        if tare == "auto":
            runs.append(("alternation + tare", f"pair means and tare for {text}", base,
                         "auto"))
    then = " + tare" if tare == "auto" else ""
    for kind, what, setting in (("despike", "spikes held out online", {"despike": DESPIKE_K}),
                                ("baseline step", "jumps re-based online",
                                 {"baseline_step": STEP_K})):
        if found.sensors[kind]:
            runs.append((f"{kind}{then}", f"{what}: {'; '.join(found.lines(kind))}",
                         _with_input(base, found.sensors[kind], **setting), tare))
    total = len(runs) * len(calibration.sensors)
    done: list[str] = []

    def step(sensor: str) -> None:
        done.append(sensor)
        if progress is not None:
            progress(len(done), total)
    results = [diagnose(recordings, cal, validate_recordings=validate_recordings,
                        policy=policy, tare=mode, on_sensor=step, **options)
               for _, _, cal, mode in runs]
    best = _chosen(results, policy)
    conditions = [{"name": name, "reading": reading, "before": r.before["rmse"],
                   "after": r.after["rmse"], "chosen": k == best}
                  for k, ((name, reading, _, _), r) in enumerate(zip(runs, results,
                                                                     strict=True))]
    conditions += [{"name": "measurement chain", "reading": line, "before": float("nan"),
                    "after": float("nan"), "chosen": False}
                   for kind, line in found.readings if kind != "alternation"]
    conditions += [{k: d.session[k] for k in ("name", "reading", "before", "after", "chosen")}
                   for d in results[best].sensors.values() if d.session]
    return dataclasses.replace(results[best], conditions=conditions)
