"""The ``fit --option K=V`` options of every model, with their types and ranges: the keyword
arguments of each model's ``fit`` and the direction-detector options every model takes.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

from strain_comp.core.chain import PAIR_BRANCHES
from strain_comp.errors import InputError
from strain_comp.models import MODEL_NAMES
from strain_comp.models.apl import M_MAX, N_MAX
from strain_comp.models.apl_kernels import P_MIN
from strain_comp.models.creep_pi import LAM_MAX, N_PLAY_MAX, N_TAU_MAX, TAU_RANGE
from strain_comp.models.rational import MODES

Check = Callable[[Any], str | None]
"""None when the value is acceptable, else what it must be."""

MAX_LIST = 100
MAX_COUNT = 100_000


def _number(lo: float, *, strict: bool = False, hi: float = math.inf) -> Check:
    def check(value: Any) -> str | None:
        ok = (isinstance(value, (int, float)) and not isinstance(value, bool)
              and math.isfinite(value) and (value > lo if strict else value >= lo)
              and value <= hi)
        return None if ok else f"a number {'>' if strict else '>='} {lo:g}" + (
            f" and <= {hi:g}" if math.isfinite(hi) else "")
    return check


def _integer(lo: int, hi: int, *, odd: bool = False) -> Check:
    def check(value: Any) -> str | None:
        ok = (isinstance(value, int) and not isinstance(value, bool) and lo <= value <= hi
              and (not odd or value % 2 == 1))
        return None if ok else f"an {'odd ' if odd else ''}integer in [{lo}, {hi}]"
    return check


def _choice(*names: str) -> Check:
    def check(value: Any) -> str | None:
        return None if value in names else f"one of {', '.join(names)}"
    return check


def _boolean(value: Any) -> str | None:
    return None if isinstance(value, bool) else "true or false"


def _progress(value: Any) -> str | None:
    """true or false from the user; the API passes its progress bar's callback."""
    return None if isinstance(value, bool) or callable(value) else "true or false"


def _number_list(lo: float, *, strict: bool = False, hi: float = math.inf,
                 max_len: int = MAX_LIST) -> Check:
    item = _number(lo, strict=strict, hi=hi)

    def check(value: Any) -> str | None:
        ok = (isinstance(value, list) and 1 <= len(value) <= max_len
              and all(item(v) is None for v in value))
        return None if ok else (f"a list of 1 to {max_len} numbers "
                                f"{'>' if strict else '>='} {lo:g}"
                                + (f" and <= {hi:g}" if math.isfinite(hi) else ""))
    return check


def model_options(model: str) -> dict[str, Check]:
    """The options of ``model``'s fit (without the direction options)."""
    if model in ("apl", "pl", "mpi"):
        return {
            "N": _integer(1, N_MAX), "M": _integer(1, M_MAX, odd=True),
            "sigma_grid": _number_list(0.0, strict=True), "p_grid": _number_list(P_MIN),
            "refine": _boolean, "cell_weights": _choice("signed", "lead", "lag", "free"),
            "eps": _number(0.0, strict=True), "ridge": _number(0.0),
            "output_nfev": _integer(0, MAX_COUNT), "search_nfev": _integer(0, MAX_COUNT),
            "search_top": _integer(0, MAX_COUNT), "progress": _progress,
        }
    if model == "sinh_pl":
        return {"n_cells": _integer(1, 3), "max_nfev": _integer(1, MAX_COUNT)}
    if model == "rational":
        return {"mode": _choice(*MODES)}
    if model == "spike_decay":
        return {"hold_rate": _number(0.0, strict=True), "min_hold": _number(0.0, strict=True)}
    if model == "creep_pi":
        return {"taus": _number_list(TAU_RANGE[0], hi=TAU_RANGE[1], max_len=N_TAU_MAX),
                "n_play": _integer(1, N_PLAY_MAX), "lam": _number(0.0, hi=LAM_MAX)}
    if model == "cubic":
        return {}
    raise InputError(f"--model {model!r}: unknown model; known: {', '.join(MODEL_NAMES)}")


DIRECTION_OPTIONS: dict[str, Check] = {
    "deadzone": _number(0.0, strict=True), "k_sigma": _number(0.0, strict=True),
    "tau": _number(0.0), "alternation": _boolean, "pair": _choice(*PAIR_BRANCHES),
}
"""Options every model takes: the direction detector and the measurement chain."""

MEANINGS: dict[str, str] = {
    "N": "creep-play cells (default 11)",
    "M": "segments of the output map f (default 9)",
    "sigma_grid": "creep rates to search [1/s] (default 13 from the data's time scales)",
    "p_grid": "creep exponents to search (default 0.3 .. 3)",
    "refine": "output-error refinement after the QP (default true)",
    "cell_weights": "signed as in the paper, or free (default signed)",
    "eps": "lowest slope of f, normalised (default 1e-3)",
    "ridge": "ridge on f's slopes and the cell weights (default 1e-6)",
    "output_nfev": "evaluations of the final refinement, 0 = the QP only (default 100)",
    "search_nfev": "evaluations per scored grid point (default 10)",
    "search_top": "grid points re-scored (default 5)",
    "progress": "a line per grid row on stderr for long fits (default true)",
    "n_cells": "sinh cells (default 1)",
    "max_nfev": "least-squares evaluations (default 100)",
    "mode": "combined, or split: loading and unloading fits (default combined)",
    "hold_rate": "a hold moves slower than this [strain unit/s] (default 0.2 % of span/s)",
    "min_hold": "shortest hold [s] (default 1)",
    "taus": "creep time constants [s] (default [0.3, 3, 30, 300])",
    "n_play": "play operators (default 8)",
    "lam": "ridge penalty (default: chosen by cross-validation over the runs)",
    "deadzone": "direction dead zone [input unit/s: ohm/s, or as --input-unit] (default "
                "k_sigma x noise of a hold)",
    "k_sigma": "dead zone in noise sigmas (default 4)",
    "tau": "low-pass of dR/dt [s] (default from the data)",
    "alternation": "read the input in pairs (default: detected)",
    "pair": "pair value: mean, upper or lower (default: detected)",
}
"""What each option sets, with its default (``strain-comp fit --help``)."""


def describe_options() -> str:
    """Every model's options with meaning and range, for ``strain-comp fit --help``."""
    groups = (("apl, pl, mpi", "apl"), ("sinh_pl", "sinh_pl"), ("rational", "rational"),
              ("spike_decay", "spike_decay"), ("creep_pi", "creep_pi"),
              ("every model", None))
    lines = ["fit options (--option K=V; cubic has only those of every model):"]
    for title, model in groups:
        lines.append(f"  {title}:")
        table = DIRECTION_OPTIONS if model is None else model_options(model)
        for key, check in table.items():
            # what the check accepts: its answer to a value no check accepts
            lines.append(f"    {key:<13}{MEANINGS.get(key, '')}; {check(object()) or ''}")
    return "\n".join(lines)


FIT_OPTIONS: dict[str, Check] = {
    "fit_budget": _integer(1000, 10**12),  # strain_comp.offline.reduce.FIT_SAMPLE_BUDGET
}
"""Options of the fit itself, for every model."""


def check_fit_options(model: str, options: Mapping[str, Any]) -> None:
    known = {**model_options(model), **DIRECTION_OPTIONS, **FIT_OPTIONS}
    for key, value in options.items():
        if key not in known:
            raise InputError(f"--option {key}: model {model!r} has no such option; its "
                             f"options: {', '.join(known)}")
        problem = known[key](value)
        if problem is not None:
            raise InputError(f"--option {key}={value!r}: must be {problem}")
