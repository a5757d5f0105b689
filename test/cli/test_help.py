"""Help a user can live in, and the exact messages: every subcommand describes itself with
an example, every option has a help line, ``fit --help`` lists the model options from
``offline/options.py``, ``--version``, and usage errors point to the subcommand's help."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pytest

from strain_comp import __version__
from strain_comp.cli import build_parser, main
from strain_comp.core.tare import tare_engine
from strain_comp.offline.options import DIRECTION_OPTIONS, MEANINGS, model_options


def subparsers() -> dict[str, argparse.ArgumentParser]:
    action = next(a for a in build_parser()._actions
                  if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def test_every_subcommand_has_a_description_an_example_and_option_help() -> None:
    for name, parser in subparsers().items():
        assert parser.description, name
        assert parser.epilog and "example:" in parser.epilog and f"strain-comp {name}" in \
            parser.epilog, name
        for action in parser._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            assert action.help, f"{name} {action.option_strings or action.dest}: no help"


def test_fit_help_lists_every_model_option_with_meaning_and_range(
        capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["fit", "--help"]) == 0
    text = capsys.readouterr().out
    for model in ("apl", "sinh_pl", "rational", "spike_decay", "creep_pi", "cubic"):
        for key in {**model_options(model), **DIRECTION_OPTIONS}:
            line = next(line for line in text.splitlines()
                        if line.split() and line.split()[0] == key)
            assert MEANINGS[key] in line, key
    assert "an odd integer in [1," in text  # M's range, from the same table the check uses


def test_version_and_usage_errors(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"strain-comp {__version__}"
    assert main(["evaluate", "x.mcap", "--calibration", "c.yaml", "--bogus", "1"]) == 2
    err = capsys.readouterr().err
    assert err.strip() == ("strain-comp: error: evaluate: unrecognized arguments: --bogus 1 "
                           "(see strain-comp evaluate --help)")


def test_a_declined_tare_says_why_once() -> None:
    from conftest import cubic_cal, engine_of

    engine = engine_of(cubic_cal(rest_resistance=1000.0))
    t = np.arange(0.0, 10.0, 0.1)
    lines = tare_engine(engine, {"s1": (t, 1000.0 + 50.0 * t)}, "auto")  # moving from the start
    assert lines["s1"].startswith("not tared: the run does not start at rest")
    assert "tare:" not in lines["s1"]


def test_replay_counts_the_resistance_messages_it_compensated(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bag, cal = tmp_path / "sim.mcap", tmp_path / "cal.yaml"
    assert main(["simulate", "--scenario", "triangle", "--out", str(bag), "--duration", "20",
                 "-q"]) == 0
    assert main(["fit", str(bag), "--model", "cubic", "--sensor", "all", "--out", str(cal),
                 "-q"]) == 0
    from strain_comp.io.bag import read_bag

    contents = read_bag(bag)
    n_resistance = sum(s.t.size for topic, s in contents.series.items()
                       if topic.endswith("/resistance"))
    capsys.readouterr()
    assert main(["replay", str(bag), "--calibration", str(cal), "--out",
                 str(tmp_path / "o.mcap"), "-q"]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"replayed {n_resistance} resistance messages")


def test_diagnose_says_what_the_automatic_tare_did_on_each_run() -> None:
    """``diagnose --tare auto``'s tare condition reads the tare taken or declined per run,
    never "tared at its start" for a run that was not."""
    from conftest import cubic_cal

    from strain_comp.core.calibration import Calibration
    from strain_comp.diagnosis.conditions import _tare_outcome
    from strain_comp.io.recording import Recording

    cal = cubic_cal(rest_resistance=1000.0)
    t = np.arange(0.0, 10.0, 0.1)
    moving = Recording("s1", t, 1000.0 + 50.0 * t, None)
    at_rest = Recording("s1", t, np.where(t < 3.0, 1010.0, 1010.0 + 50.0 * (t - 3.0)), None)
    text = _tare_outcome(Calibration({"s1": cal}), {"s1": moving}, {"s1": at_rest})
    first, second = text.split("; ")
    assert first.startswith("training run s1: not tared: ")
    assert second.startswith("validation run s1: rest resistance ")


def test_node_without_rclpy_says_how_to_install_it(monkeypatch: pytest.MonkeyPatch,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "rclpy" else real(name, *a))
    params = Path(__file__).resolve().parents[2] / "config" / "compensator_params.yaml"
    capsys.readouterr()
    assert main(["node", "--params", str(params)]) == 2
    assert "pip install '.[ros]'" in capsys.readouterr().err


def test_fit_help_names_every_model_and_auto(capsys: pytest.CaptureFixture[str]) -> None:
    """``fit --help`` names every registered model (creep_pi included) and ``auto``; the
    command list names ``start``."""
    from strain_comp.models import MODEL_NAMES

    assert main(["fit", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    model_help = text[text.index("--model MODEL auto"):text.rindex("--candidates M1,M2")]
    assert "auto" in model_help
    for model in MODEL_NAMES:
        assert model in model_help, model
    assert main(["--help"]) == 0
    assert "start " in capsys.readouterr().out


def test_the_tare_and_evaluate_advise_start_not_each_other() -> None:
    """A run that starts while the resistance drifts is not tared, and the tare says what to
    record or to start the session; evaluate's out-of-range note says to start the session,
    never to try the tare (which sent the user back to evaluate)."""
    from strain_comp.base.direction import DirectionSettings
    from strain_comp.cli.common import OUT_OF_RANGE_HINT
    from strain_comp.core.tare import rest_resistance_at_start
    from strain_comp.errors import InputError

    t = np.arange(0.0, 30.0, 0.1)
    with pytest.raises(InputError) as refused:
        rest_resistance_at_start(t, 1000.0 * (1.0 + 0.01 * t), DirectionSettings(deadzone=1e6))
    assert "still drifts" in str(refused.value) and "strain-comp start" in str(refused.value)
    assert "--tare" not in OUT_OF_RANGE_HINT and "strain-comp start" in OUT_OF_RANGE_HINT
