"""CSV import: the two measured formats and the generic mapping, on synthetic files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from strain_comp.errors import InputError
from strain_comp.io.csv_import import import_csv, repair_position_glitches
from strain_comp.io.recording import load_recordings, write_recordings


def _cb_pdms(tmp_path: Path, glitches: tuple[int, ...] = (30, 50)) -> tuple[Path, np.ndarray]:
    n = 200
    t_pos = 0.004 + np.arange(n) * 0.08
    pos = -8.0 * np.abs(np.sin(t_pos / 3))  # sign differs between runs: abs is taken
    true = pos.copy()
    pos[list(glitches)] = 0.0
    t_r = t_pos + 0.03
    r = 1000 + 50 * np.abs(true)
    rows = np.column_stack([r, -r, t_r, pos, t_pos, np.zeros(n), t_pos + 0.05])
    path = tmp_path / "cb.csv"
    np.savetxt(path, rows, delimiter=",")
    return path, np.interp(t_r, t_pos, 100 * np.abs(true) / 40)


def test_cb_pdms_glitches_repaired_and_reference_interpolated(tmp_path: Path) -> None:
    path, strain = _cb_pdms(tmp_path)
    rec, report = import_csv(path, fmt="cb_pdms", sensor="cb")
    assert report.glitches_repaired == 2
    assert rec.name == "cb" and rec.r.size == 200
    ok = ~np.isnan(rec.s)
    assert ok.sum() == 199  # the last t_R lies after the last t_pos
    np.testing.assert_allclose(rec.s[ok], strain[ok], atol=0.2)
    with pytest.raises(InputError, match="no good row"):  # R_inner: all negative here
        import_csv(path, fmt="cb_pdms", sensor="cb", columns={"resistance": 1})
    half, _ = import_csv(path, fmt="cb_pdms", sensor="cb", gauge_length_mm=80.0)
    np.testing.assert_allclose(half.s[ok], strain[ok] / 2, atol=0.1)


def test_repair_leaves_real_zeros() -> None:
    pos = np.array([0.0, 0.0, 1.0, 2.0, 0.0, 2.0, 1.0, 0.0, 0.0])
    fixed, n = repair_position_glitches(pos)
    assert n == 1 and fixed[4] == 2.0 and fixed[0] == 0.0 and fixed[-1] == 0.0


def test_fiber_with_and_without_gauge_length(tmp_path: Path) -> None:
    t = np.arange(50.0)
    ext = 10 * np.abs(np.sin(t / 8))
    path = tmp_path / "fiber.csv"
    np.savetxt(path, np.column_stack([t, ext, ext * 0.1, 70 + ext]), delimiter=",")
    mm, report = import_csv(path, fmt="fiber", sensor="f")
    assert report.strain_unit == "mm" and any("mm" in n for n in report.notes)
    np.testing.assert_allclose(mm.s, ext)
    pct, report = import_csv(path, fmt="fiber", sensor="f", gauge_length_mm=50.0)
    np.testing.assert_allclose(pct.s, 2 * ext)
    assert report.strain_unit == "%"


def test_bad_rows_are_counted_and_dropped(tmp_path: Path) -> None:
    path = tmp_path / "bad.csv"
    path.write_text("0,0,0,10\n1,0.1,0,11\n2,abc,0,12\n3,0.3,0,nan\n4,0.4,0,-5\n"
                    "3.5,0.5,0,13\n5,0.6\n6,0.6,0,14\n6,0.7,0,15\n7,0.8,0,inf\n8,0.9,0,16\n"
                    "7.5,1.0,0,17\n")
    rec, report = import_csv(path, fmt="fiber", sensor="f")
    d = report.dropped
    assert d["unparsable or missing field"] == 2  # nan R, short row
    assert d["resistance <= 0 ohm"] == 1
    assert d["resistance not finite"] == 1
    assert d["time not increasing"] == 2  # the repeated 6 and the 7.5 after 8
    # 3.5 follows a dropped row (t=4, R<0): it beats the last *good* time, so it is kept;
    # the unparsable strain of t=2 leaves its reference to interpolation
    np.testing.assert_array_equal(rec.t, [0, 1, 2, 3.5, 6, 8])
    np.testing.assert_allclose(rec.s, [0, 0.1, 0.26, 0.5, 0.6, 0.9])


def test_generic_mapping_with_header_and_scales(tmp_path: Path) -> None:
    path = tmp_path / "g.tsv"
    path.write_text("ms\tstrain_pct\tohm\n0\t0\t10\n100\t1\t11\n200\t2\t12\n")
    rec, _ = import_csv(path, fmt="generic", sensor="g", delimiter="\t",
                        columns={"time": "ms", "resistance": "ohm", "strain": "strain_pct"},
                        scales={"time": 1e-3})
    np.testing.assert_allclose(rec.t, [0, 0.1, 0.2])
    np.testing.assert_allclose(rec.r, [10, 11, 12])
    np.testing.assert_allclose(rec.s, [0, 1, 2])
    with pytest.raises(InputError, match="not found"):
        import_csv(path, fmt="generic", sensor="g", delimiter="\t",
                   columns={"time": "seconds", "resistance": "ohm"})
    with pytest.raises(InputError, match="needs 'time'"):
        import_csv(path, fmt="generic", sensor="g", columns={"resistance": 2})


def test_bag_round_trip(tmp_path: Path) -> None:
    path, _ = _cb_pdms(tmp_path)
    rec, _ = import_csv(path, fmt="cb_pdms", sensor="cb")
    write_recordings({rec.name: rec}, tmp_path / "cb.mcap")
    recs, problems = load_recordings(tmp_path / "cb.mcap")
    assert problems == []
    np.testing.assert_array_equal(recs["cb"].r, rec.r)
    np.testing.assert_array_equal(recs["cb"].s, rec.s)  # NaN where no reference, kept


def test_measured_files(measured_data: Path) -> None:
    cb = measured_data / "cb_pdms_7p5wt"
    v9 = import_csv(cb / "2_7-5_E4pin_20mm_v9_0.2Strain_velocityprof.csv",
                    fmt="cb_pdms", sensor="cb")
    v10 = import_csv(cb / "2_7-5_E4pin_20mm_v10_0.3Strain.csv", fmt="cb_pdms", sensor="cb")
    for (rec, report), top in ((v9, 20.0), (v10, 30.0)):
        assert report.glitches_repaired > 0
        assert np.nanmin(rec.s) == pytest.approx(0.0, abs=0.5)
        assert np.nanmax(rec.s) == pytest.approx(top, abs=0.5)
        assert report.kept == report.rows
    fiber, report = import_csv(
        measured_data / "conductive_fiber" / "oldthread_sensorfiber_5x_1_synced.csv",
        fmt="fiber", sensor="fib")
    assert report.strain_unit == "mm" and np.nanmax(fiber.s) > 50


def test_delimiter_decimal_comma_and_units_from_the_command_line(tmp_path: Path) -> None:
    """The same recording written as a comma file in s and ohm, as a semicolon file with
    decimal commas in ms and kohm with the strain as a fraction, and space separated: every
    one imports (delimiter detected, units from --scales) to the same samples."""
    from strain_comp.cli import main

    t = np.arange(50) * 0.02
    r = 1500.0 + 400.0 * np.sin(t)
    s = 20.0 * np.sin(t)
    plain = tmp_path / "plain.csv"
    plain.write_text("t_s,r_ohm,s_pct\n" + "".join(
        f"{a:.17g},{b:.17g},{c:.17g}\n" for a, b, c in zip(t, r, s, strict=True)))
    local = tmp_path / "local.csv"
    local.write_text("ms;kohm;fraction\n" + "".join(
        f"{a * 1e3:.1f};{b / 1e3:.10f};{c / 100:.12f}\n".replace(".", ",")
        for a, b, c in zip(t, r, s, strict=True)))
    spaced = tmp_path / "spaced.txt"
    spaced.write_text("".join(f"  {a:.17g}   {b:.17g} {c:.17g}\n"
                              for a, b, c in zip(t, r, s, strict=True)))
    runs = {plain: ["--columns", "time=t_s,resistance=r_ohm,strain=s_pct"],
            local: ["--columns", "time=ms,resistance=kohm,strain=fraction",
                    "--scales", "time=1e-3,resistance=1000,strain=100"],
            spaced: ["--columns", "time=0,resistance=1,strain=2"]}
    for path, flags in runs.items():
        out = tmp_path / f"{path.stem}.mcap"
        assert main(["import-csv", str(path), "--out", str(out), "--sensor", "s1",
                     "--format", "generic", *flags]) == 0
        rec = load_recordings(out)[0]["s1"]
        np.testing.assert_allclose(rec.t, t, atol=1e-9)
        np.testing.assert_allclose(rec.r, r, rtol=1e-9)
        np.testing.assert_allclose(rec.s, s, rtol=1e-9, atol=1e-9)
    with pytest.raises(InputError, match="scale"):
        import_csv(plain, fmt="generic", sensor="g", scales={"time": 0.0},
                   columns={"time": "t_s", "resistance": "r_ohm"})
