"""Measurement-chain and tare hypotheses around the residual loop.

Some causes of a residual act on the resistance before any model sees it: the rest level of
this run (a tare), an alternation of the excitation every other sample (pair means, see
``strain_comp.core.chain``). They are not effect regressors on the output; each is a
*condition* under which the whole loop (``strain_comp.diagnosis.loop.diagnose``) runs:

1. ``as calibrated``: the calibration as given (always run; the reference).
2. ``tare`` (with ``tare="auto"``): every run tared at its start (``strain_comp.core.tare``).
3. ``alternation`` (when ``strain_comp.core.chain.alternation`` finds one in the
   diagnosed or the validation runs and the calibration does not correct it yet): the
   engine feeds the models pair means. Combined with 2 when both apply.

The condition whose held-out RMSE after the loop is lowest is chosen, but a condition other
than the reference only if it beats it by more than ``margin`` (relative): a tare or a
filter that worsens held-out error is not chosen. Every condition is reported with its
reading (e.g. ``alternation +-340 ohm every other sample``) and its before/after RMSE.
Spikes and quantisation found in the data are reported as readings only: the engine's
screen already bounds spikes, and quantisation is a noise floor no term can remove.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import numpy as np

from strain_comp.core.calibration import Calibration, InputSettings
from strain_comp.core.chain import alternation, quantisation, spikes
from strain_comp.diagnosis.loop import diagnose
from strain_comp.diagnosis.report import DiagnoseResult
from strain_comp.io.recording import Recording


def _with_alternation(calibration: Calibration, names: set[str]) -> Calibration:
    return Calibration({
        n: dataclasses.replace(c, input=InputSettings(c.input.kind, c.input.r1, c.input.vin,
                                                      alternation=True))
        if n in names else c for n, c in calibration.sensors.items()})


def chain_readings(recordings: Mapping[str, Recording], calibration: Calibration,
                   ) -> tuple[set[str], list[str]]:
    """(sensors with an uncorrected alternation, one reading line per finding)."""
    alternating: set[str] = set()
    lines = []
    for name, rec in recordings.items():
        if name not in calibration.sensors:
            continue
        found = alternation(rec.r)
        if found.present:
            done = calibration.sensors[name].input.alternation
            lines.append(f"{name}: {found.reading()}"
                         + (" (corrected by the calibration)" if done else ""))
            if not done:
                alternating.add(name)
        n_spikes = spikes(rec.r)
        if n_spikes:
            lines.append(f"{name}: {n_spikes} isolated spikes in {np.asarray(rec.r).size} "
                         "samples")
        step = quantisation(rec.r)
        if step is not None:
            lines.append(f"{name}: resistance quantised in steps of {step:.3g} ohm")
    return alternating, lines


def diagnose_conditions(recordings: Mapping[str, Recording], calibration: Calibration, *,
                        validate_recordings: Mapping[str, Recording] | None = None,
                        tare: str = "calibration", margin: float = 0.03,
                        **options: Any) -> DiagnoseResult:
    """``diagnose`` under each condition of the module docstring; the chosen result, with
    every condition's record in ``conditions``."""
    alternating, readings = chain_readings(recordings, calibration)
    if validate_recordings is not None:  # what the validation runs show is tested as well
        more, lines = chain_readings(validate_recordings, calibration)
        alternating |= more
        readings += [f"{line} (validation run)" for line in lines]
    runs: list[tuple[str, str, Calibration, str]] = [
        ("as calibrated", "the calibration's rest resistance and input", calibration,
         "calibration")]
    if tare == "auto":
        runs.append(("tare", "each run tared at its start", calibration, "auto"))
    if alternating:
        fixed = _with_alternation(calibration, alternating)
        text = "; ".join(line for line in readings if "alternation" in line)
        runs.append(("alternation", f"pair means for {text}", fixed, "calibration"))
        if tare == "auto":
            runs.append(("alternation + tare", f"pair means and tare for {text}", fixed,
                         "auto"))
    results = [diagnose(recordings, cal, validate_recordings=validate_recordings,
                        margin=margin, tare=mode, **options) for _, _, cal, mode in runs]
    best = 0
    for k, result in enumerate(results[1:], start=1):
        if result.after["rmse"] < (1.0 - margin) * results[best].after["rmse"] \
                and result.after["rmse"] < (1.0 - margin) * results[0].after["rmse"]:
            best = k
    conditions = [{"name": name, "reading": reading, "before": r.before["rmse"],
                   "after": r.after["rmse"], "chosen": k == best}
                  for k, ((name, reading, _, _), r) in enumerate(zip(runs, results,
                                                                     strict=True))]
    conditions += [{"name": "measurement chain", "reading": line, "before": float("nan"),
                    "after": float("nan"), "chosen": False}
                   for line in readings if "alternation" not in line]
    return dataclasses.replace(results[best], conditions=conditions)
