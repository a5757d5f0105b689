"""Measurement-chain findings and the tare on a slice of a real recording (carbon black v9:
+-10 uA excitation whose sign alternates every sample).

The data live outside the repository: ``STRAIN_COMP_MEASURED_DATA`` or
``../shared/data/measured`` relative to the project root; the test skips without them.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from strain_comp.core.chain import alternation, pair_means, pair_values
from strain_comp.core.direction import DirectionSettings
from strain_comp.core.tare import rest_resistance_at_start
from strain_comp.io.recording import Recording
from strain_comp.offline.fit import pair_side

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("STRAIN_COMP_MEASURED_DATA", ROOT.parent / "shared" / "data"
                          / "measured"))
V9 = DATA / "cb_pdms_7p5wt" / "2_7-5_E4pin_20mm_v9_0.2Strain_velocityprof.csv"


@pytest.fixture(scope="module")
def v9_head() -> tuple[np.ndarray, np.ndarray]:
    if not V9.is_file():
        pytest.skip(f"measured data not found at {DATA} (set STRAIN_COMP_MEASURED_DATA)")
    rows = np.loadtxt(V9, delimiter=",", max_rows=6000)
    return rows[:, 2], rows[:, 0]  # t_R [s], R_outer [ohm]


def test_the_alternating_excitation_is_found_and_cancelled(v9_head: tuple) -> None:
    _, r = v9_head
    unloaded, loaded = alternation(r[:3000]), alternation(r[3000:])
    assert unloaded.present and loaded.present
    # its size follows the state (about 20-30 ohm unloaded, about 410 ohm loaded), so a
    # constant cannot be subtracted; pair means cancel it whatever its size and phase
    assert 10.0 < abs(unloaded.amplitude) < 40.0
    assert 300.0 < abs(loaded.amplitude) < 500.0
    jumps = np.median(np.abs(np.diff(r[3000:])))
    assert np.median(np.abs(np.diff(pair_means(r[3000:])[1:]))) < 0.2 * jumps


def test_auto_tare_reads_the_rest_level_through_the_alternation(v9_head: tuple) -> None:
    t, r = v9_head
    detector = DirectionSettings(deadzone=200.0, tau=0.5)
    rest = rest_resistance_at_start(t, r, detector)
    start = r[t < t[0] + 5.0]
    assert rest == pytest.approx(0.5 * (start.min() + start.max()), rel=0.01)


def test_a_one_sided_alternation_switches_on_in_a_loaded_hold() -> None:
    """v9, fourth loaded hold (1500-1600 s, 20 % strain): at about 1537 s every other
    sample starts to read about 680 ohm low while the others continue the level. The pair
    mean steps down by half that (what a memory model takes for unloading); the upper pair
    value stays on the level."""
    if not V9.is_file():
        pytest.skip(f"measured data not found at {DATA} (set STRAIN_COMP_MEASURED_DATA)")
    rows = np.loadtxt(V9, delimiter=",", skiprows=13291, max_rows=800)
    t, r = rows[:, 2], rows[:, 0]
    before, after = (t > 1525.0) & (t < 1535.0), (t > 1540.0) & (t < 1550.0)
    def fall(series: np.ndarray) -> float:
        return float(np.median(series[before[1:]]) - np.median(series[after[1:]]))

    upper, mean = fall(pair_values(r, branch="upper")[1:]), fall(pair_means(r)[1:])
    assert abs(upper) < 100.0  # the hold's own relaxation over 15 s
    assert 280.0 < mean - upper < 420.0  # half the 680 ohm drop of every other sample


def test_fit_reads_v9_through_the_upper_pair_value() -> None:
    """Over the whole v9 run the steps of the alternation's size in its holds (on at 1537 s
    and 2100 s, off at each loading) are taken by the lower side: ``pair_side`` chooses
    ``upper``."""
    if not V9.is_file():
        pytest.skip(f"measured data not found at {DATA} (set STRAIN_COMP_MEASURED_DATA)")
    rows = np.loadtxt(V9, delimiter=",")
    strain = 100.0 * np.abs(rows[:, 3]) / 40.0
    assert pair_side([Recording("cb", rows[:, 2], rows[:, 0], strain)]) == "upper"
