"""Command-line contracts on hostile inputs: one error line or a usable result.

* ``fit`` and ``recalibrate`` on seeded hostile data (scales from 1e-300 to 1e300, constant
  and NaN stretches, negative resistances, steps) either exit 2 with exactly one
  ``strain-comp: error:`` line (nothing else on the file descriptor: no LAPACK lines) or
  write a calibration that ``load_calibration`` loads and ``evaluate`` runs on.
* A damaged bag: ``fit``, ``evaluate`` and ``replay`` that fail name the damage in their one
  error line.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from strain_comp.cli import main as run_cli
from strain_comp.core.calibration_file import load_calibration
from strain_comp.io.bag import BagWriter

ROOT = Path(__file__).resolve().parent.parent
MODELS = ("cubic", "pl", "rational", "sinh_pl")
STRAIN_SCALES = (1e-300, 1e-3, 1.0, 1.0, 1.0, 10.0, 1e300)
OHM_SCALES = (1e-3, 1.0, 1.0, 1e5)
POINT_OHM = (10.5, 12.0, 15.0, 20.0, 25.0, 29.0, 1e-300)
POINT_STRAIN = (-1e300, 0.0, 5.0, 20.0, 50.0, 1e7, 1e300)


def _hostile_bag(path: Path, seed: int) -> Path:
    """Resistance and reference of one seeded hostile run (200 samples at 100 Hz)."""
    rng = np.random.default_rng(seed)
    t = 1.0 + np.arange(200) * 0.01
    phase = np.sin(np.linspace(0, 4 * np.pi, t.size))
    r = 100.0 + 10.0 * phase
    s = 20.0 + 20.0 * phase
    r *= rng.choice(OHM_SCALES)
    s *= rng.choice(STRAIN_SCALES)
    for _ in range(int(rng.integers(0, 3))):
        a = int(rng.integers(0, t.size - 20))
        kind = rng.integers(0, 4)
        if kind == 0:
            r[a:a + 20] = r[a]  # a constant stretch
        elif kind == 1:
            s[a:a + 20] = np.nan
        elif kind == 2:
            r[a:a + 5] = -r[a:a + 5]
        else:
            s[a:] += 1e3 * (s.max() - s.min())  # a step in the reference
    with BagWriter(path) as writer:
        writer.write_float64("/s1/resistance", t, r)
        writer.write_float64("/s1/strain_reference", t, s)
    return path


def cli(args: list[str]) -> int:
    """The command line in this process; it must emit no warning (a line on stderr)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        code = run_cli(args)
    assert not [str(w.message) for w in caught if w.category is RuntimeWarning], caught
    return code


def _one_line_or_loadable(code: int, err: str, out: Path) -> None:
    lines = err.strip().splitlines()
    if code == 2:
        assert len(lines) == 1 and lines[0].startswith("strain-comp: error: "), err
        assert not out.exists()
    else:
        assert code == 0 and "unexpected" not in err, err
        load_calibration(out)  # what evaluate, replay and the node read


@pytest.mark.parametrize("seed", range(12))
def test_fit_on_hostile_data_gives_one_line_or_a_loadable_file(
        tmp_path: Path, capfd: pytest.CaptureFixture[str], seed: int) -> None:
    bag = _hostile_bag(tmp_path / "hostile.mcap", seed)
    model = MODELS[seed % len(MODELS)]
    fitted = tmp_path / "fitted.yaml"
    code = cli(["fit", str(bag), "--model", model, "--sensor", "s1", "--out", str(fitted)])
    _one_line_or_loadable(code, capfd.readouterr().err, fitted)
    if code == 0:
        code = cli(["evaluate", str(bag), "--calibration", str(fitted)])
        err = capfd.readouterr().err.strip().splitlines()
        assert code == 0 or (code == 2 and len(err) == 1), err


@pytest.mark.parametrize("seed", range(12))
def test_recalibrate_on_hostile_points_and_bags_gives_one_line_or_a_loadable_file(
        tmp_path: Path, capfd: pytest.CaptureFixture[str], seed: int) -> None:
    bag = _hostile_bag(tmp_path / "hostile.mcap", seed)
    rng = np.random.default_rng(seed)
    points = [f"{rng.choice(POINT_OHM):g}:{rng.choice(POINT_STRAIN):g}" for _ in range(2)]
    recal = tmp_path / "recal.yaml"
    code = cli(["recalibrate", str(ROOT / "config" / "demo_calibration.yaml"),
                "--point", points[0], "--point", points[1], "--out", str(recal)])
    _one_line_or_loadable(code, capfd.readouterr().err, recal)
    recal.unlink(missing_ok=True)
    code = cli(["recalibrate", str(ROOT / "config" / "demo_calibration.yaml"),
                "--from", str(bag), "--out", str(recal)])
    _one_line_or_loadable(code, capfd.readouterr().err, recal)


def test_a_reference_near_1e_300_is_one_line_without_lapack(
        tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    t = 1.0 + np.arange(300) * 0.01
    phase = np.sin(np.linspace(0, 4 * np.pi, t.size))
    bag = tmp_path / "tiny.mcap"
    with BagWriter(bag) as writer:
        writer.write_float64("/s1/resistance", t, 100.0 + 10.0 * phase)
        writer.write_float64("/s1/strain_reference", t, 1e-300 * (1.0 + phase))
    for model in ("cubic", "apl"):
        code = cli(["fit", str(bag), "--model", model, "--sensor", "s1",
                    "--out", str(tmp_path / "c.yaml")])
        err = capfd.readouterr().err.strip().splitlines()
        assert code == 2 and len(err) == 1 and "a fit needs a span of at least" in err[0], err


def test_a_damaged_bag_is_named_in_the_one_error_line(
        tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    """The bag cut inside its first chunk: nothing is readable; each command's one error
    line says why (the truncation), fit included (it printed the damage on a line of its
    own before)."""
    cut = tmp_path / "cut.mcap"
    cut.write_bytes((ROOT / "bags" / "steps.mcap").read_bytes()[:30_000])
    calibration = str(ROOT / "config" / "demo_calibration.yaml")
    for args in (["fit", str(cut), "--model", "cubic", "--sensor", "s1",
                  "--out", str(tmp_path / "c.yaml")],
                 ["evaluate", str(cut), "--calibration", calibration],
                 ["replay", str(cut), "--calibration", calibration,
                  "--out", str(tmp_path / "r.mcap")]):
        code = cli(args)
        err = capfd.readouterr().err.strip().splitlines()
        assert code == 2 and len(err) == 1, (args[0], err)
        assert "truncated at byte" in err[0], (args[0], err)
