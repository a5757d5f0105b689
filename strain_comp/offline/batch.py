"""``evaluate`` over one bag or many (docs/design.md): a table per bag and each sensor's
errors pooled over every sample of the bags it was scored in, serially or in a pool of
``jobs`` processes."""

from __future__ import annotations

import os
import signal
import sys
import tempfile
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path
from typing import Any

from strain_comp.core.calibration import strain_unit_words
from strain_comp.core.calibration_file import load_calibration
from strain_comp.core.metrics import ErrorAccumulator
from strain_comp.errors import (
    InputError,
    OutputError,
    StrainCompError,
    Terminated,
    raise_terminated,
)
from strain_comp.io.recording import load_recordings
from strain_comp.offline.evaluate import evaluate_bag
from strain_comp.offline.evaluation import score_lines
from strain_comp.offline.fit import in_run_bound
from strain_comp.offline.plots import evaluation_figures, write_plots
from strain_comp.offline.report_page import BagSection
from strain_comp.offline.series import SeriesCSV

STOP_SECONDS = 30.0
"""How long a stopped pool worker may take to remove its temporary files and exit."""


def _is_bag_dir(path: Path) -> bool:
    return (path / "metadata.yaml").is_file()


def expand_bags(paths: Sequence[str]) -> list[str]:
    """The bags named by ``paths``; a folder (not a rosbag2 directory) stands for its bags."""
    bags: list[str] = []
    for text in paths:
        path = Path(text)
        if path.is_dir() and not _is_bag_dir(path):
            found = sorted(str(p) for p in path.iterdir()
                           if (p.suffix in (".mcap", ".db3") and p.is_file()) or
                           (p.is_dir() and _is_bag_dir(p)))
            if not found:
                raise InputError(f"{text}: a folder without .mcap or .db3 files or rosbag2 "
                                 "directories")
            bags += found
        else:
            bags.append(text)
    return list(dict.fromkeys(bags))


def _evaluate_one(bag: str, calibration_path: str, tare: str, plot_points: int,
                  in_run: bool, plots_dir: str | None, series_to: SeriesCSV | str | None,
                  inputs: Sequence[str], out_of_range: str = "extend",
                  references_every: float | None = None, figures: bool = False,
                  keep_going: bool = True) -> BagSection:
    """``evaluate`` of one bag; ``series_to``: the open CSV or a worker's part's path."""
    table = SeriesCSV(series_to, bag=True) if isinstance(series_to, str) else series_to
    try:
        calibration = load_calibration(calibration_path)
        result, problems = evaluate_bag(bag, calibration, tare=tare, plot_points=plot_points,
                                        series=table, out_of_range=out_of_range,
                                        references_every=references_every)
        if in_run:
            in_run_bound(result, load_recordings(bag)[0], calibration)
        outcome = BagSection(bag, result, problems=problems)
        if plots_dir is not None or figures:  # drawn once for both
            drawn = evaluation_figures(result, calibration, bag=bag,
                                       calibration_path=calibration_path, tare=tare)
            if plots_dir is not None:
                outcome.plots = [str(p) for p in write_plots(drawn, plots_dir, inputs=inputs)]
            if figures:
                outcome.figures = drawn
        for ev in result.sensors.values():  # the arrays went into the plots
            ev.t = ev.r = ev.reference = ev.estimate = ev.direction = ev.scored = \
                ev.t[:0]
    except OutputError:  # an output could not be written: the command fails, not the bag
        if isinstance(series_to, str) and table is not None:
            table.discard()
        raise
    except StrainCompError as err:
        if not keep_going:
            raise
        outcome = BagSection(bag, None, error=" ".join(str(err).split()))
    except BrokenPipeError:  # stdout closed: the command ends, not this bag
        raise
    except OSError as err:
        if not keep_going:
            raise
        outcome = BagSection(bag, None, error=f"{err.filename or bag}: {err.strerror or err}")
    if isinstance(series_to, str) and table is not None:
        table.close()  # the parent copies the part into the table (``_copy_part``)
    return outcome


def plot_dirs(bags: Sequence[str], plots: str | None) -> list[str | None]:
    """A subfolder of ``plots`` per bag named by its stem (or ``bag``), ``_2``... if taken."""
    if plots is None:
        return [None] * len(bags)
    taken: set[str] = set()
    out: list[str | None] = []
    for bag in bags:
        stem = Path(bag.rstrip("/")).stem
        base = stem if stem and not stem.startswith(".") and "/" not in stem else "bag"
        name, k = base, 2
        while name in taken:
            name, k = f"{base}_{k}", k + 1
        taken.add(name)
        out.append(str(Path(plots) / name))
    return out


def _copy_part(part: str, table: SeriesCSV, target: str) -> None:
    """A worker's CSV part streamed into the table; an error names the table's target."""
    try:
        with open(part, encoding="utf-8") as handle:
            handle.readline()  # the part's own header
            while block := handle.read(2**20):
                table.write(block)
    except OSError as err:
        raise OutputError(f"{target}: cannot write: {err.strerror or err}") from None


def _stop_workers(pool: ProcessPoolExecutor) -> None:
    """Cancel what has not started, SIGTERM every worker, SIGKILL after ``STOP_SECONDS``."""
    # the pool's private attribute: no public API reaches its processes
    processes = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        if process.is_alive():
            process.terminate()
    for process in processes:  # each removes its temporary files, then exits
        process.join(timeout=STOP_SECONDS)
        if process.is_alive():
            process.kill()
            process.join()


_in_bag = False
"""In a pool worker: True while it evaluates a bag."""


def _worker_signals() -> None:
    """SIGTERM in a worker: ``Terminated`` inside a bag (its files removed), else exit."""
    def on_term(signum: int, frame: object) -> None:
        if _in_bag:
            raise_terminated(signum, frame)
        os._exit(143)

    signal.signal(signal.SIGTERM, on_term)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the parent, which ends us


def _evaluate_in_worker(*args: Any) -> BagSection:
    """``_evaluate_one`` in a pool worker (``_worker_signals``)."""
    global _in_bag
    _in_bag = True
    try:
        return _evaluate_one(*args)
    except Terminated:  # its temporary files are gone: end here, take no further bag
        os._exit(143)
    finally:
        _in_bag = False


def evaluate_bags(bags: Sequence[str], calibration_path: str, *, tare: str, jobs: int,
                  plot_points: int, in_run: bool, dirs: Sequence[str | None],
                  series: SeriesCSV | None, progress: Callable[[int, int, str], None],
                  out_of_range: str, references_every: float | None, figures: bool,
                  keep_going: bool) -> list[BagSection]:
    """Every bag evaluated, in the order given; ``dirs``: each bag's plots (``plot_dirs``)."""
    inputs = [*bags, calibration_path]
    outcomes: list[BagSection] = []
    if jobs == 1 or len(bags) == 1:
        for k, bag in enumerate(bags):
            outcomes.append(_evaluate_one(bag, calibration_path, tare, plot_points, in_run,
                                          dirs[k], series, inputs, out_of_range,
                                          references_every, figures, keep_going))
            progress(k + 1, len(bags), bag)
        return outcomes
    # fork on Linux (spawn re-imports numba: about 2 s per worker), spawn elsewhere (macOS)
    context = get_context("fork" if sys.platform == "linux" else "spawn")
    with tempfile.TemporaryDirectory(prefix="strain_comp_") as tmp, \
            ProcessPoolExecutor(max_workers=min(jobs, len(bags)), mp_context=context,
                                initializer=_worker_signals) as pool:
        parts = [None if series is None else os.path.join(tmp, f"{k}.csv")
                 for k in range(len(bags))]
        try:
            futures = [pool.submit(_evaluate_in_worker, bag, calibration_path, tare,
                                   plot_points, in_run, dirs[k], parts[k], inputs, out_of_range,
                                   references_every, figures)
                       for k, bag in enumerate(bags)]
            for k, future in enumerate(futures):  # in order: the CSV keeps the bags' order
                try:
                    outcome = future.result()
                except OutputError as err:  # a worker's part: the error names the table
                    part = parts[k]
                    raise OutputError(str(err) if series is None or part is None else
                                      str(err).replace(part, str(series.path))) from None
                part = parts[k]
                if series is not None and part is not None and os.path.exists(part):
                    _copy_part(part, series, str(series.path))
                    os.unlink(part)
                outcomes.append(outcome)
                progress(k + 1, len(bags), bags[k])
        except BaseException:  # SIGTERM, Ctrl-C, a failed output: end every worker first
            _stop_workers(pool)
            raise
    return outcomes


def aggregate(outcomes: Sequence[BagSection]) -> dict[str, tuple[ErrorAccumulator, int, str,
                                                                    str]]:
    """The errors of every sensor pooled over the bags."""
    pooled: dict[str, tuple[ErrorAccumulator, int, str, str]] = {}
    for outcome in outcomes:
        if outcome.result is None:
            continue
        for name, ev in outcome.result.sensors.items():
            acc, n_bags, _, _ = pooled.get(name, (ErrorAccumulator(), 0, ev.model, ev.unit))
            acc.merge(ev.errors)
            pooled[name] = (acc, n_bags + 1, ev.model, ev.unit)
    return pooled


def format_aggregate(outcomes: Sequence[BagSection]) -> str:
    """The pooled table: every sensor over every bag it was scored in."""
    pooled = aggregate(outcomes)
    done = sum(o.result is not None for o in outcomes)
    lines = [f"== {done} of {len(outcomes)} bags evaluated: errors pooled over them",
             *score_lines([(name, model, n_bags, acc.stats(), acc.coverage_95())
                           for name, (acc, n_bags, model, _) in pooled.items()], bags=True)]
    units = {unit for *_, unit in pooled.values()}
    words = ", ".join(strain_unit_words(u) for u in sorted(units)) or "% strain"
    lines.append(f"errors in {words}, over all samples of all bags together")
    return "\n".join(lines)


def to_json(outcomes: Sequence[BagSection]) -> dict[str, Any]:
    bags: dict[str, Any] = {}
    for outcome in outcomes:
        bags[outcome.bag] = ({"error": outcome.error} if outcome.result is None
                             else outcome.result.to_json())
    pooled: dict[str, dict[str, Any]] = {}
    for name, (acc, n_bags, model, unit) in aggregate(outcomes).items():
        pooled[name] = {**acc.stats().to_dict(), "n_bags": n_bags, "model": model,
                        "unit": unit}
        if acc.coverage_95() is not None:
            pooled[name]["coverage_95"] = acc.coverage_95()
    return {"bags": bags, "aggregate": {"sensors": pooled}}
