"""Candidate effects of the residual loop (docs/design.md, "The loop's steps", 2)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from strain_comp.core.effects import STRETCH_FORMS, effect_dict, regressor_from_dict

RELAXATION_TAUS = tuple(round(2.0 ** (k / 2), 2) for k in range(-2, 15))
"""[s] relaxation after loading or unloading steps: 0.5-128 s, sqrt(2) apart (any within 19 %)."""
CREEP_TAUS = tuple(round(2.0 ** (k / 2), 2) for k in range(-4, 18))
"""[s] creep (one Prony state each): 0.25-362 s, sqrt(2) apart, covering ``creep_pi``'s states."""
MEMORY_TAUS = tuple(float(2 ** k) for k in range(9))
"""[s] resistance peak and trough: 1-256 s, a factor 2 apart."""
STRETCH_SCALES = (200.0, 2000.0)
"""Strain travel [%] over which a ``stretch`` term grows: one 0 -> 100 -> 0 % cycle, and ten."""
STRETCH_BAND = 0.5
"""Play [% strain] through which a ``stretch`` candidate counts travel (noise adds none)."""
BASELINE_WINDOW = 5.0
"""Seconds at the start of a run over which a ``baseline`` candidate averages S_hat."""


def default_candidates(*, temperature_ref: float | None = None,
                       neighbours: Sequence[str] = (),
                       baseline_rest: float = 0.0,
                       stretch_history: bool = False) -> list[dict[str, Any]]:
    """The generic candidate effects (calibration-file dicts, without ``coef``)."""
    out: list[dict[str, Any]] = [{"name": "offset", "kind": "offset", "params": {}}]
    out += [{"name": f"rate_{mode}", "kind": "rate", "params": {"tau": 1.0, "mode": mode}}
            for mode in ("signed", "direction")]
    out += [{"name": "direction", "kind": "direction", "params": {"mode": "sign", "hold": False}},
            {"name": "direction_held", "kind": "direction",
             "params": {"mode": "sign", "hold": True}},
            {"name": "direction_strain", "kind": "direction",
             "params": {"mode": "strain", "hold": True}}]
    for branch in ("both", "loading", "unloading"):
        out += [{"name": f"relaxation_{branch}_tau{tau:g}", "kind": "relaxation",
                 "params": {"tau": tau, "branch": branch}}
                for tau in (CREEP_TAUS if branch == "both" else RELAXATION_TAUS)]
    for form in ("relaxation", "peak", "trough"):
        out += [{"name": f"resistance_{form}_tau{tau:g}", "kind": "resistance_memory",
                 "params": {"tau": tau, "form": form}}
                for tau in (CREEP_TAUS if form == "relaxation" else MEMORY_TAUS)]
    out += [{"name": f"drift_{form}", "kind": "elapsed", "params": {"form": form, "scale": 100.0}}
            for form in ("linear", "sqrt", "log", "linear_strain")]
    if temperature_ref is not None:
        out += [{"name": f"temperature_{form}", "kind": "temperature",
                 "params": {"form": form, "t_ref": float(temperature_ref)}}
                for form in ("offset", "strain")]
    out += [{"name": f"strain_level_{p}", "kind": "strain_level", "params": {"power": p}}
            for p in (1, 2, 3)]
    out += [{"name": f"mullins_{form}", "kind": "mullins", "params": {"form": form, "n0": 1.0}}
            for form in ("gap", "gap_strain", "cycles_log")]
    out += [{"name": f"mullins_cycles_exp_n{n0:g}", "kind": "mullins",
             "params": {"form": "cycles_exp", "n0": n0}} for n0 in (1.0, 3.0)]
    out.append({"name": "mullins_peak_strain", "kind": "mullins",
                "params": {"form": "peak_strain", "n0": 1.0}})
    if stretch_history:
        out += [{"name": f"stretch_{form}_x{scale:g}", "kind": "stretch",
                 "params": {"form": form, "scale": scale, "band": STRETCH_BAND}}
                for form in STRETCH_FORMS for scale in STRETCH_SCALES]
    out.append({"name": "baseline", "kind": "baseline",
                "params": {"window": BASELINE_WINDOW, "rest": float(baseline_rest)}})
    out += [{"name": f"crosstalk_{nb}", "kind": "crosstalk", "params": {"neighbour": nb}}
            for nb in neighbours]
    return out


def added_effects(candidates: Sequence[dict[str, Any]], cols: Sequence[int],
                  coefs: Sequence[float], existing: Sequence[dict[str, Any]] = ()
                  ) -> list[dict[str, Any]]:
    """Calibration-file entries of candidates ``cols`` with ``coefs``, names made unique."""
    taken = {str(e["name"]) for e in existing}
    out = []
    for j, c in zip(cols, coefs, strict=True):
        name, k = str(candidates[j]["name"]), 2
        while name in taken:
            name, k = f"{candidates[j]['name']}_{k}", k + 1
        taken.add(name)
        out.append(effect_dict(name, regressor_from_dict(candidates[j]), float(c)))
    return out
