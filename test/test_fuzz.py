"""A bounded, seeded run of scripts/fuzz.py, plus the regressions it found.

The calibration loader may only raise CalibrationError (one line naming the file), and a
file that loads must run through the engine; the bag reader may only raise BagError or
return what it could read, and replay may only raise BagError. The long run is
``python scripts/fuzz.py --seconds 120``.
"""

from __future__ import annotations

import importlib.util
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import fitted

from strain_comp.core.calibration import Calibration
from strain_comp.core.calibration_file import load_calibration, save_calibration
from strain_comp.errors import CalibrationError
from strain_comp.models import MODEL_NAMES

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def fuzz():
    spec = importlib.util.spec_from_file_location("strain_comp_fuzz", ROOT / "scripts" /
                                                  "fuzz.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def every_model() -> dict:
    return {model: fitted(model) for model in MODEL_NAMES}


def _report(stats) -> str:
    return "\n\n".join(trace for _, trace in stats.crashes[:3])


def test_fuzz_calibration_loader(fuzz, every_model, tmp_path: Path) -> None:
    seed = tmp_path / "seed.yaml"
    save_calibration(fuzz.seed_calibration(every_model), seed)
    assert fuzz.check_yaml(seed)  # the seed loads and runs
    stats = fuzz.fuzz_yaml(seed.read_bytes(), np.random.default_rng(0), tmp_path,
                           iterations=40, timeout=20.0)
    assert not stats.crashes, _report(stats)
    assert stats.accepted and stats.rejected  # both paths were exercised


def test_fuzz_bag_reader_and_replay(fuzz, every_model, tmp_path: Path) -> None:
    seeds = fuzz.seed_bags(tmp_path)
    calibration = fuzz.replay_calibration(every_model)
    for data in seeds:
        path = tmp_path / "clean.mcap"
        path.write_bytes(data)
        assert fuzz.check_bag(path, calibration)
    stats = fuzz.fuzz_bag(seeds, calibration, np.random.default_rng(0), tmp_path,
                          replay_every=10, iterations=200, timeout=20.0)
    assert not stats.crashes, _report(stats)
    assert stats.accepted > 50


def test_fuzz_db3_reader(fuzz, tmp_path: Path) -> None:
    """Damaged .db3 files, hostile rows (a column of another type, huge messages, dropped
    tables) and hostile metadata.yaml (listings repeated thousands of times, QoS nested 3000
    deep): only BagError, one line, or consistent series (``python scripts/fuzz.py --target
    db3 --seconds 600`` for long runs)."""
    stats = fuzz.fuzz_db3(np.random.default_rng(0), tmp_path, iterations=120, timeout=20.0)
    assert not stats.crashes, _report(stats)
    assert stats.accepted > 20 and stats.rejected > 20, stats.line()


def test_fuzz_api_for_a_few_seconds(fuzz) -> None:
    """Random calls of the API with hostile arrays, frames and keyword types: only a
    StrainCompError of one line (``python scripts/fuzz.py --target api --seconds 600
    --seed 7`` for the long run)."""
    stats = fuzz.fuzz_api(np.random.default_rng(7), iterations=1000, timeout=20.0)
    assert not stats.internal, stats.line() + "".join(
        f"\n{trace}" for trace in stats.traces.values())
    assert stats.refused > 100 and stats.calls - stats.refused > 20, stats.line()


def test_calibration_truncated_at_any_line_loads_or_is_refused_cleanly(
        fuzz, every_model, tmp_path: Path) -> None:
    seed = tmp_path / "seed.yaml"
    save_calibration(fuzz.seed_calibration(every_model), seed)
    text = seed.read_bytes()
    cuts = [i for i, byte in enumerate(text) if byte == ord("\n")][::4]
    cuts += [len(text) // 3 + 7, len(text) // 2 + 3]  # mid-line, mid-number
    outcomes = set()
    for cut in cuts:
        path = tmp_path / "cut.yaml"
        path.write_bytes(text[:cut])
        outcomes.add(fuzz.check_yaml(path))  # raises on anything but CalibrationError
    assert outcomes == {False, True}  # early cuts refused; a cut in provenance may load


@pytest.mark.parametrize(("effect", "field"), [
    ({"name": "e", "kind": {"offset": None}, "coef": 0.1}, "effects.0.kind"),
    ({"name": "e", "kind": ["offset"], "coef": 0.1}, "effects.0.kind"),
    ({"name": "e", "kind": "rate", "params": {1: 2.0, "x": 1.0}, "coef": 0.1},
     "effects.0.params.1"),
])
def test_regression_fuzz_effect_of_wrong_type(every_model, tmp_path: Path, effect: dict,
                                              field: str) -> None:
    """Found by scripts/fuzz.py: an effect ``kind`` that is a mapping or a list raised
    TypeError (unhashable) and mixed-type ``params`` keys raised TypeError (sorting) in
    strain_comp.core.effects.regressor_from_dict instead of a CalibrationError."""
    path = tmp_path / "cal.yaml"
    save_calibration(Calibration({"s": replace(every_model["cubic"], name="s")}), path)
    data = yaml.safe_load(path.read_text())
    data["sensors"]["s"]["effects"] = [effect]
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(CalibrationError) as info:
        load_calibration(path)
    assert str(info.value).startswith(f"{path}: sensors.s.{field}: "), str(info.value)


def test_regression_fuzz_rational_pole_inside_the_valid_range(every_model,
                                                               tmp_path: Path) -> None:
    """Found by scripts/fuzz.py: a mutated denominator put a rational's pole inside its
    valid range; the engine raised ZeroDivisionError, then read NaN at a good sample. The
    loader refuses it in one line naming the resistance."""
    path = tmp_path / "cal.yaml"
    save_calibration(Calibration({"s": replace(every_model["rational"], name="s")}), path)
    data = yaml.safe_load(path.read_text())
    sensor = data["sensors"]["s"]
    params, norm = sensor["model"]["params"], sensor["normalisation"]
    lo, hi = sensor["valid_range"]["resistance"]
    r_mid = 0.5 * (lo + hi)
    for branch in ("combined", "loading", "unloading"):
        if branch in params:  # den = (xi - xi_mid) xi: a pole at the middle of the range
            params[branch]["q"] = [-(r_mid / norm["r0"] + norm["alpha"]), 0.0]
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(CalibrationError, match=r"no finite strain at R = .* \(a pole\)"):
        load_calibration(path)


def _raw_array_bag(path: Path, rows: list[tuple[str, list[float]]]) -> None:
    """Float64MultiArray messages on /a/resistance with the given (labels, data), as
    a foreign or damaged recorder might write them (BagWriter refuses such rows)."""
    from mcap.writer import Writer

    from strain_comp.io.bag.schemas import SCHEMAS
    from strain_comp.io.cdr import message_encoder

    kind = "std_msgs/msg/Float64MultiArray"
    encode = message_encoder(kind)
    with path.open("wb") as f:
        writer = Writer(f)
        writer.start(profile="ros2")
        schema = writer.register_schema(kind, "ros2msg", SCHEMAS[kind].encode())
        channel = writer.register_channel("/a/resistance", "cdr", schema)
        for i, (labels, data) in enumerate(rows):
            payload = encode({"layout": {"dim": [{"label": labels, "size": len(data),
                                                  "stride": len(data)}], "data_offset": 0},
                              "data": data})
            writer.add_message(channel, (i + 1) * 10**8, payload, (i + 1) * 10**8)
        writer.finish()


def test_regression_fuzz_empty_array_message_first(tmp_path: Path) -> None:
    """Found by scripts/fuzz.py: when the first decodable Float64MultiArray held no values,
    it fixed the layout at k = 0 and the bulk decoder's reshape raised ValueError."""
    from strain_comp.io.bag import read_bag

    path = tmp_path / "empty_first.mcap"
    _raw_array_bag(path, [("s1,p", [])] + [("s1,p", [15.0, 16.0])] * 5)
    contents = read_bag(path)
    series = contents.series["/a/resistance"]
    assert series.values.shape == (5, 2) and contents.labels["/a/resistance"] == ["s1", "p"]
    assert any("malformed or wrong-size" in p for p in contents.problems)
    only_empty = tmp_path / "only_empty.mcap"
    _raw_array_bag(only_empty, [("s1,p", [])] * 3)
    contents = read_bag(only_empty)
    assert "/a/resistance" not in contents.series and contents.problems


def test_regression_labels_that_do_not_match_the_values(fuzz, every_model,
                                                        tmp_path: Path) -> None:
    """Found while turning the fuzz crashes into tests: an array whose label list has more
    or fewer names than values made replay fail inside the engine (InputError without the
    file); the reader now skips and counts such arrays (as the node refuses them: a given
    label must name the sensors), and replay refuses cleanly."""
    from strain_comp.errors import BagError
    from strain_comp.io.bag import read_bag
    from strain_comp.offline.replay import replay_bag

    path = tmp_path / "labels.mcap"
    _raw_array_bag(path, [("s1,p", [15.0, 16.0, 17.0])] * 4)
    contents = read_bag(path)
    assert contents.series["/a/resistance"].values.shape == (0, 3)
    assert "/a/resistance" not in contents.labels
    assert any("4 arrays whose dim[0].label does not name one sensor for each of the 3 "
               "values skipped" in p for p in contents.problems)
    with pytest.raises(BagError, match="no /NAME/resistance"):
        replay_bag(path, fuzz.replay_calibration(every_model), tmp_path / "out.mcap")


def test_fuzz_csv_importer(fuzz, tmp_path: Path) -> None:
    stats = fuzz.fuzz_csv(np.random.default_rng(0), tmp_path, iterations=150, timeout=20.0)
    assert not stats.crashes, _report(stats)
    assert stats.accepted and stats.rejected


def test_fuzz_live_node_for_a_few_seconds(fuzz, tmp_path: Path,
                                         monkeypatch: pytest.MonkeyPatch) -> None:
    """The node in its own process under a hostile peer: alive, no traceback, every strain
    it published finite (the long run: ``scripts/fuzz.py --target node``)."""
    from ros_env import ros_env

    for key, value in ros_env(9).items():
        monkeypatch.setenv(key, value)
    stats = fuzz.fuzz_node(np.random.default_rng(0), tmp_path / "node", seconds=6.0)
    assert not stats.failed, stats.line() + "\n" + "\n".join(stats.tracebacks[:2])
    assert stats.outputs > 0 and stats.sent.get("clock", 0) > 0
    assert sum(stats.clock_modes.values()) >= 3  # the clock changed its mode on the way


def test_fuzz_evaluate_over_folders_of_damaged_bags(fuzz, every_model, tmp_path: Path) -> None:
    """``evaluate FOLDER --csv --json --plots --jobs 1|2`` over seed and damaged bags (the
    long run: ``scripts/fuzz.py --target evaluate``): one line on failure, no temporary
    file, nothing outside ``--plots``. Seed 0's first three runs: ``--jobs 1`` and ``2``,
    a ``...mcap`` under each, damaged and clean bags, a refusal and a success."""
    stats = fuzz.fuzz_evaluate(fuzz.seed_bags(tmp_path), fuzz.replay_calibration(every_model),
                               np.random.default_rng(0), tmp_path / "evaluate", iterations=3)
    assert not stats.crashes, "\n\n".join(trace for _, trace in stats.crashes[:2])
    assert stats.runs == 3 and 0 in stats.exits and 2 in stats.exits, stats.exits
