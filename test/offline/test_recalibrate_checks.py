"""``recalibrate --input`` checks its points as the output form does (a point the engine
cannot read is refused), and ``--from`` needs a stretch of the range, not a few samples."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from strain_comp.cli import main
from strain_comp.io.bag import BagWriter

ROOT = Path(__file__).resolve().parents[2]
CAL = ROOT / "config" / "demo_calibration.yaml"
ERROR = "strain-comp: error: "


def one_error(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(ERROR), err
    return err[0]


@pytest.mark.parametrize("far", ["1e300", "2e-3", "5000"])
def test_an_input_point_the_engine_cannot_read_is_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], far: str) -> None:
    """``--point 11.5:0 --point 1e300:10`` wrote a span gain of 3e-300."""
    out = tmp_path / "c2.yaml"
    code = main(["recalibrate", str(CAL), "--input", "--point", "11.5:0", "--point",
                 f"{far}:10", "--out", str(out)])
    assert code == 2 and f"--point {float(far):g}:10" in one_error(capsys)
    assert not out.exists()


def test_input_points_inside_what_the_engine_reads_still_re_span(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A sensor that became more sensitive: its points lie beyond the calibrated range
    (29.6 ohm at its top) and are used."""
    out = tmp_path / "c2.yaml"
    assert main(["recalibrate", str(CAL), "--input", "--point", "11.5:0", "--point",
                 "40:50", "--out", str(out), "-q"]) == 0
    assert out.exists()


@pytest.mark.parametrize("n, seconds", [(2, 0.04), (400, 2.0)])
def test_from_needs_a_stretch_of_the_range(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                           n: int, seconds: float) -> None:
    """A 2-sample, 0.04 s bag (and 400 samples at one strain with noise) fitted a gain and
    offset; now refused in one line, nothing written."""
    bag = tmp_path / "short.mcap"
    t = np.linspace(0.0, seconds, n)
    rng = np.random.default_rng(0)
    with BagWriter(bag) as writer:
        writer.write_float64("/s1/resistance", t, 15.0 + rng.normal(0.0, 0.01, n))
        writer.write_float64("/s1/strain_reference", t, 10.0 + rng.normal(0.0, 0.1, n))
    out = tmp_path / "c2.yaml"
    code = main(["recalibrate", str(CAL), "--from", str(bag), "--out", str(out)])
    assert code == 2 and "recalibrate --from" in one_error(capsys)
    assert not out.exists()
