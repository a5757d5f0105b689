"""Series out (``replay --csv``, ``evaluate --csv``) and ``evaluate`` over many bags: the
CSV's rows give the table's errors, replay and evaluate give the same rows, the pooled
errors are those of all samples together, and ``--jobs`` changes nothing."""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from strain_comp.cli import main
from strain_comp.core.metrics import ErrorAccumulator, error_stats

ERROR = "strain-comp: error: "


@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two short rig bags and a cubic calibration fitted on the first."""
    work = tmp_path_factory.mktemp("series")
    for seed, name in ((1, "a.mcap"), (2, "b.mcap")):
        assert main(["simulate", "--scenario", "triangle", "--out", str(work / name),
                     "--seed", str(seed), "--duration", "40", "-q"]) == 0
    assert main(["fit", str(work / "a.mcap"), "--model", "cubic", "--sensor", "all",
                 "--out", str(work / "cal.yaml"), "-q"]) == 0
    return work


def read_rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as handle:
        return list(csv.DictReader(handle))


def errors_of(rows: list[dict[str, str]]) -> tuple[np.ndarray, np.ndarray]:
    """Estimate and reference of the rows the table scores (good, with a reference)."""
    used = [r for r in rows if r["status"] in ("good", "out_of_range") and r["reference"]]
    return (np.array([float(r["estimate"]) for r in used]),
            np.array([float(r["reference"]) for r in used]))


def test_replay_and_evaluate_write_the_same_series_and_it_gives_the_table(
        work: Path, capsys: pytest.CaptureFixture[str]) -> None:
    capsys.readouterr()
    assert main(["evaluate", str(work / "b.mcap"), "--calibration", str(work / "cal.yaml"),
                 "--csv", str(work / "ev.csv"), "--json", str(work / "ev.json"), "-q"]) == 0
    assert main(["replay", str(work / "b.mcap"), "--calibration", str(work / "cal.yaml"),
                 "--out", str(work / "rp.mcap"), "--csv", str(work / "rp.csv"), "-q"]) == 0
    assert (work / "ev.csv").read_bytes() == (work / "rp.csv").read_bytes()
    rows = read_rows(work / "ev.csv")
    assert list(rows[0]) == ["sensor", "time_s", "resistance_ohm", "estimate", "reference",
                             "unit", "direction", "status"]
    document = json.loads((work / "ev.json").read_text())
    for name, record in document["sensors"].items():
        mine = [r for r in rows if r["sensor"] == name]
        assert record["n_samples"] == len(mine)
        assert {r["direction"] for r in mine} <= {"-1", "0", "1"}
        stats = error_stats(*errors_of(mine))
        assert stats.n == record["n"]
        assert stats.rmse == pytest.approx(record["rmse"], rel=1e-12)
    # the replayed bag's strain is the CSV's estimate
    from strain_comp.io.bag import read_bag

    name = next(iter(document["sensors"]))
    replayed = read_bag(work / "rp.mcap").series[f"/{name}/strain"].values
    np.testing.assert_array_equal(replayed, [float(r["estimate"]) for r in rows
                                             if r["sensor"] == name])


def test_dash_writes_to_stdout_alone(work: Path, capsys: pytest.CaptureFixture[str]) -> None:
    capsys.readouterr()
    assert main(["evaluate", str(work / "b.mcap"), "--calibration", str(work / "cal.yaml"),
                 "--json", "-"]) == 0
    out, err = capsys.readouterr()
    assert "sensors" in json.loads(out) and "RMSE" in err  # the table went to stderr
    assert not Path("-").exists()
    assert main(["evaluate", str(work / "b.mcap"), "--calibration", str(work / "cal.yaml"),
                 "--csv", "-", "-q"]) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[0].startswith("sensor,time_s") and "RMSE" not in out
    assert main(["evaluate", str(work / "b.mcap"), "--calibration", str(work / "cal.yaml"),
                 "--csv", "-", "--json", "-"]) == 2


def test_a_csv_output_that_is_an_input_is_refused(work: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    before = (work / "cal.yaml").read_bytes()
    capsys.readouterr()
    assert main(["evaluate", str(work / "b.mcap"), "--calibration", str(work / "cal.yaml"),
                 "--csv", str(work / "cal.yaml")]) == 2
    assert capsys.readouterr().err.startswith(ERROR)
    assert (work / "cal.yaml").read_bytes() == before


def test_many_bags_a_table_each_and_errors_pooled(work: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    folder = work / "study"
    folder.mkdir(exist_ok=True)
    for name in ("a.mcap", "b.mcap"):
        shutil.copy(work / name, folder / name)
    capsys.readouterr()
    outputs = {}
    for jobs in ("1", "2"):
        assert main(["evaluate", str(folder), "--calibration", str(work / "cal.yaml"),
                     "--json", str(work / f"many{jobs}.json"), "--csv",
                     str(work / f"many{jobs}.csv"), "--jobs", jobs, "-q"]) == 0
        outputs[jobs] = (json.loads((work / f"many{jobs}.json").read_text()),
                         (work / f"many{jobs}.csv").read_bytes())
    out = capsys.readouterr().out
    assert out.count("== ") == 2 * 3  # two bags and the pooled table, twice
    assert outputs["1"] == outputs["2"]  # the process pool changes nothing
    document = outputs["1"][0]
    bags = [str(folder / "a.mcap"), str(folder / "b.mcap")]
    assert list(document["bags"]) == bags
    rows = read_rows(work / "many1.csv")
    for name, pooled in document["aggregate"]["sensors"].items():
        estimate, reference = errors_of([r for r in rows if r["sensor"] == name])
        truth = error_stats(estimate, reference)  # every sample of both bags at once
        assert pooled["n"] == truth.n == sum(document["bags"][b]["sensors"][name]["n"]
                                             for b in bags)
        for key in ("rmse", "mae", "max_abs", "r2"):
            assert pooled[key] == pytest.approx(getattr(truth, key), rel=1e-9)
        assert pooled["n_bags"] == 2
        single = document["bags"][bags[1]]["sensors"][name]
        capsys.readouterr()
        assert main(["evaluate", bags[1], "--calibration", str(work / "cal.yaml"), "--json",
                     "-", "-q"]) == 0
        assert json.loads(capsys.readouterr().out)["sensors"][name] == single


def test_a_bag_that_fails_is_reported_and_the_others_evaluated(
        work: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    broken = tmp_path / "broken.mcap"
    broken.write_bytes(b"not a bag at all")
    capsys.readouterr()
    code = main(["evaluate", str(work / "a.mcap"), str(broken), "--calibration",
                 str(work / "cal.yaml"), "--json", str(tmp_path / "j.json")])
    out, err = capsys.readouterr()
    assert code == 2 and err.strip().splitlines()[-1].startswith(ERROR + "1 of 2 bags")
    document = json.loads((tmp_path / "j.json").read_text())
    assert "error" in document["bags"][str(broken)]
    assert "sensors" in document["bags"][str(work / "a.mcap")]
    assert "not evaluated" in out
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["evaluate", str(empty), "--calibration", str(work / "cal.yaml")]) == 2


def test_error_accumulators_merge_into_the_statistics_of_all_samples() -> None:
    rng = np.random.default_rng(3)
    parts = [(rng.normal(size=n), rng.normal(size=n) * 3 + k) for k, n in enumerate((5, 40, 1))]
    pooled = ErrorAccumulator()
    for estimate, reference in parts:
        one = ErrorAccumulator()
        one.add(estimate, reference)
        pooled.merge(one)
    pooled.merge(ErrorAccumulator())
    truth = error_stats(np.concatenate([p[0] for p in parts]),
                        np.concatenate([p[1] for p in parts]))
    got = pooled.stats()
    assert got.n == truth.n
    for key in ("rmse", "mae", "max_abs", "r2"):
        assert getattr(got, key) == pytest.approx(getattr(truth, key), rel=1e-12)


def test_csv_to_fit_to_csv_round_trip(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                      ) -> None:
    """docs/csv.md's generic mapping (ms, kohm, a fraction, decimal commas) imported, fitted
    and evaluated back out as a table; its estimate tracks the CSV's strain."""
    t = np.arange(0.0, 60.0, 0.02)
    s = 0.1 * np.abs(((t / 10.0) % 2.0) - 1.0)
    r = 35.2 * (1.0 + 2.0 * s + 0.5 * s * s)
    lines = ["time_ms;R_kohm;strain"] + [f"{a * 1000:.0f};{b:.6f};{c:.6f}".replace(".", ",")
                                        for a, b, c in zip(t, r, s, strict=True)]
    (tmp_path / "run.csv").write_text("\n".join(lines) + "\n")
    assert main(["import-csv", str(tmp_path / "run.csv"), "--out", str(tmp_path / "run.mcap"),
                 "--sensor", "s1", "--format", "generic", "--columns",
                 "time=time_ms,resistance=R_kohm,strain=strain", "--scales",
                 "time=1e-3,resistance=1000,strain=100", "-q"]) == 0
    assert main(["fit", str(tmp_path / "run.mcap"), "--model", "cubic", "--sensor", "s1",
                 "--out", str(tmp_path / "s1.yaml"), "-q"]) == 0
    assert main(["evaluate", str(tmp_path / "run.mcap"), "--calibration",
                 str(tmp_path / "s1.yaml"), "--csv", str(tmp_path / "out.csv"), "-q"]) == 0
    rows = read_rows(tmp_path / "out.csv")
    assert len(rows) == t.size and rows[0]["unit"] == "%"
    np.testing.assert_allclose([float(x["time_s"]) for x in rows], t, atol=1e-9)
    np.testing.assert_allclose([float(x["resistance_ohm"]) for x in rows], r * 1000, rtol=1e-6)
    np.testing.assert_allclose([float(x["reference"]) for x in rows], 100 * s, atol=1e-4)
    np.testing.assert_allclose([float(x["estimate"]) for x in rows], 100 * s, atol=0.05)


def test_a_failed_command_leaves_the_csv_as_it_was(tmp_path: Path) -> None:
    """``series_csv`` (evaluate, replay): an error in the block keeps the earlier file and
    leaves no temporary beside it; a clean end commits header and rows."""
    from strain_comp.offline.series import COLUMNS, series_csv

    target = tmp_path / "s.csv"
    target.write_text("earlier\n", encoding="utf-8")
    with pytest.raises(RuntimeError), series_csv(target) as table:
        assert table is not None
        table.add("s1", np.array([0.5]), np.array([100.0]), np.array([1.0]), None,
                  np.array([1]), np.array([0]), unit="%")
        raise RuntimeError("failed mid-run")
    assert target.read_text(encoding="utf-8") == "earlier\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.csv"]
    with series_csv(None) as none:
        assert none is None
    with series_csv(target) as table:
        assert table is not None
        table.add("s1", np.array([0.5]), np.array([100.0]), np.array([1.0]), None,
                  np.array([1]), np.array([0]), unit="%")
    assert read_rows(target) == [dict(zip(COLUMNS, ["s1", "0.5", "100.0", "1.0", "", "%",
                                                    "1", "good"], strict=True))]
