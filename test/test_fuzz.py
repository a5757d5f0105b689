"""A bounded, seeded run of scripts/fuzz.py (issue 7), plus the regressions it found.

The calibration loader may only raise CalibrationError (one line naming the file), and a
file that loads must run through the engine; the bag reader may only raise BagError or
return what it could read, and replay may only raise BagError. The long run is
``python scripts/fuzz.py --seconds 120``.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest
from test_properties import fitted

from strain_comp.calibration import save_calibration
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
