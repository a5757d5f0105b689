"""Shared test fixtures and factories.

* A small calibration world for the engine tests: a cubic and a first-order lag model
  (``Lag``, a compensator with state, so a poisoned or missing reset would show) over
  100-200 ohm and 0-50 %, with ``cubic_cal``, ``lag_cal``, ``engine_of`` and
  ``noisy_stream`` (a signal with every kind of fault injected).
* ``fitted(model)``: one calibration per model, fitted once per pytest run on a short
  simulated rig run by the same ``strain_comp.offline.fit.fit_sensor`` the command line
  uses, so the calibrations carry a real valid range and direction settings.
* ``measured_data``: the lab recordings, found through ``STRAIN_COMP_MEASURED_DATA`` or
  ``../shared/data/measured`` relative to the project root (not part of the repository).
* ``context``: an rclpy context per test module (rclpy imported only then, after the
  module has set its ROS environment with ``ros_env.use_ros_env``).
* ``NodeUnderTest``: the node in this process with a probe node on one executor, and the
  probe's side of the harness (matched publishers, Trigger calls) the in-process ROS tests
  share (rclpy imported only when one is made).

Test modules take the fixtures as arguments and the plain factories with
``from conftest import ...``; no test module imports another.
"""

from __future__ import annotations

import functools
import math
import os
import pickle
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from ros_env import ros_env

from strain_comp.base.compensator import Compensator, Normalisation, Segment
from strain_comp.base.direction import DirectionSettings
from strain_comp.base.samples import Status
from strain_comp.core.calibration import (
    Calibration,
    InputSettings,
    SensorCalibration,
    ValidRange,
    provenance,
)
from strain_comp.core.engine import Engine
from strain_comp.core.outputs import ArrayOutput, SensorOutput
from strain_comp.core.range_policy import EXTEND_REACH, MARGIN, OPEN_FACTOR, SHORT_FACTOR
from strain_comp.io.recording import Recording
from strain_comp.offline.fit import fit_sensor
from strain_comp.offline.rig import simulate

PROJECT_ROOT = Path(__file__).resolve().parents[1]
CONFIG = PROJECT_ROOT / "config"
BAGS = PROJECT_ROOT / "bags"

R_LO, R_HI, S_LO, S_HI = 100.0, 200.0, 0.0, 50.0
NORM = Normalisation.from_ranges(R_LO, R_HI, S_LO, S_HI)
DIRECTION = DirectionSettings(deadzone=20.0, tau=0.05)


class Lag(Compensator):
    """Strain from a first-order lag of R (time constant tau): a model with state."""

    name = "lag"

    def __init__(self, tau: float = 0.3) -> None:
        super().__init__(NORM)
        self.tau = tau
        self.reset()

    def reset(self) -> None:
        self.x = math.nan
        self.t_last = math.nan

    def _run_into(self, t: np.ndarray, r: np.ndarray, out: np.ndarray) -> None:
        for i in range(t.size):
            if math.isnan(self.x):
                self.x = r[i]
            else:
                self.x += (1.0 - math.exp(-(t[i] - self.t_last) / self.tau)) * (r[i] - self.x)
            self.t_last = t[i]
            out[i] = 0.5 * (self.x - R_LO)

    def to_params(self) -> dict[str, Any]:
        return {"tau": self.tau}

    @classmethod
    def from_params(cls, params: Mapping[str, Any], normalisation: Normalisation, *,
                    direction: DirectionSettings) -> Lag:
        return cls(params["tau"])

    @classmethod
    def fit(cls, segments: Sequence[Segment], normalisation: Normalisation, *,
            direction: DirectionSettings, **options: Any) -> Lag:
        raise NotImplementedError


class LagCalibration(SensorCalibration):
    def build_model(self) -> Compensator:
        return Lag(self.params["tau"])


def cubic_cal(name: str = "s1", **changes: Any) -> SensorCalibration:
    cal = SensorCalibration(name=name, model="cubic", params={"c": [-60.0, 0.4, 1e-3, -2e-6]},
                            normalisation=NORM, valid_range=ValidRange(R_LO, R_HI, S_LO, S_HI),
                            direction=DIRECTION)
    return replace(cal, **changes)


def lag_cal(name: str = "s1", **changes: Any) -> SensorCalibration:
    cal = LagCalibration(name=name, model="lag", params={"tau": 0.3}, normalisation=NORM,
                         valid_range=ValidRange(R_LO, R_HI, S_LO, S_HI), direction=DIRECTION)
    return replace(cal, **changes)


def engine_of(*cals: SensorCalibration, **options: Any) -> Engine:
    return Engine(Calibration({c.name: c for c in cals}), **options)


def noisy_stream(rng: np.random.Generator, n: int = 600) -> tuple[np.ndarray, np.ndarray]:
    """A triangle-ish resistance signal at 100 Hz with every kind of fault injected."""
    t = np.cumsum(rng.uniform(0.005, 0.015, n))
    r = 150.0 + 45.0 * np.sin(2 * np.pi * 0.7 * t) + rng.normal(0, 0.3, n)
    faults = rng.choice(n, size=n // 6, replace=False)
    kinds = rng.integers(0, 9, faults.size)
    for i, kind in zip(faults, kinds, strict=True):
        if kind == 0:
            r[i] = np.nan
        elif kind == 1:
            r[i] = np.inf
        elif kind == 2:
            r[i] = -rng.uniform(0, 100)
        elif kind == 3:
            r[i] = 0.0
        elif kind == 4:
            r[i] = R_HI * OPEN_FACTOR * 2
        elif kind == 5:
            r[i] = R_LO * SHORT_FACTOR / 2
        elif kind == 6 and i > 0:
            t[i] = t[i - 1] - rng.uniform(0, 0.5)  # small step back: rejected
        elif kind == 7:
            r[i] = R_HI * rng.uniform(1.2, 3.0)  # out of range, still used
        elif kind == 8 and i > 0:
            t[i:] += rng.choice([6.0, -30.0])  # long gap or a clock reset: state reset
    return t, r


FAST_CELLS = {"sigma_grid": [0.03], "p_grid": [1.0], "refine": False}
"""APL/PL: one (sigma, p) point instead of the search; the tests need a sound model, not
the best one."""
FIT_OPTIONS = {"apl": FAST_CELLS, "pl": FAST_CELLS, "rational": {"mode": "split"}}
"""rational is fitted as separate loading/unloading curves, so its detector switch is used.
Every model gets tau = 0.2 s: it smooths the derivative enough for the 50 Hz rig noise
(with tau = 0 the dead zone exceeds the ramp rate and the detector never leaves hold)."""


@functools.cache
def training_recording() -> Recording:
    """120 s of the rig's random ramps and holds (50 Hz, noise, hysteresis, relaxation)."""
    return simulate("random", seed=1, duration=120.0)["s1"]


FITS = "STRAIN_COMP_TEST_FITS"
"""Environment variable: the folder where test/warm_kernels.py leaves ``fitted``'s
calibrations (pickled) for the pytest-xdist workers, which load them instead of refitting."""


@functools.cache
def fitted(model: str) -> SensorCalibration:
    """One calibration per model, fitted once per pytest run (shared with other files)."""
    folder = os.environ.get(FITS)
    if folder and (Path(folder) / f"{model}.pickle").exists():
        cal: SensorCalibration = pickle.loads((Path(folder) / f"{model}.pickle").read_bytes())
        return cal
    return fit_sensor([training_recording()], model, name="s1",
                      options={"tau": 0.2, **FIT_OPTIONS.get(model, {})})


def calibration_of(model: str, name: str = "s1") -> Calibration:
    cal = fitted(model)
    return Calibration({name: SensorCalibration(**{**vars(cal), "name": name})})


def strain_bounds(cal: SensorCalibration, out_of_range: str = "extend"
                  ) -> tuple[float, float]:
    """The bounds of the engine's estimate: with ``clamp``, the valid strain range widened
    by ``MARGIN`` of its span; with ``extend`` (the default), that widened further by
    ``EXTEND_REACH`` spans above and, below, down to zero strain at most."""
    vr = cal.valid_range
    span = vr.s_hi - vr.s_lo
    lo, hi = vr.s_lo - MARGIN * span, vr.s_hi + MARGIN * span
    if out_of_range == "clamp":
        return lo, hi
    reach = EXTEND_REACH * span
    return min(lo, max(0.0, vr.s_lo - reach)), vr.s_hi + reach


def measured_data_dir() -> Path | None:
    """The measured-data folder: ``STRAIN_COMP_MEASURED_DATA`` if set (it must exist),
    else ``../shared/data/measured`` beside the project root if present, else None."""
    configured = os.environ.get("STRAIN_COMP_MEASURED_DATA")
    if configured:
        path = Path(configured)
        if not path.is_dir():
            raise FileNotFoundError(f"STRAIN_COMP_MEASURED_DATA={configured} is not a directory")
        return path
    default = PROJECT_ROOT.parent / "shared" / "data" / "measured"
    return default if default.is_dir() else None


@pytest.fixture(scope="session")
def measured_data() -> Path:
    """The measured-data folder; the test skips only when no data are installed at all
    (they are an optional input without a licence, never part of the repository)."""
    path = measured_data_dir()
    if path is None:
        pytest.skip("measured data not installed: set STRAIN_COMP_MEASURED_DATA or put them "
                    "in ../shared/data/measured")
    return path


def make_calibration() -> Calibration:
    """A two-sensor cubic calibration with awkward floats (repr round trip matters)."""
    sensors = {}
    for i, name in enumerate(("left", "right")):
        sensors[name] = SensorCalibration(
            name=name,
            model="cubic",
            params={"c": [-69.5 + i / 3.0, 7.816, -0.2112, 0.003512 * math.pi]},
            normalisation=Normalisation(r0=7.16, alpha=-2.61, s0=25.0, beta=-1.0 / 3.0),
            valid_range=ValidRange(10.0, 30.0 + 1e-13, 0.0, 50.0),
            direction=DirectionSettings(deadzone=0.0048, tau=0.1, k_sigma=4.0),
            input=InputSettings("divider", r1=10.5, vin=3.2) if i else InputSettings(),
            effects=[{"name": "drift", "kind": "elapsed", "params": {}, "coef": 1e-3}] if i else [],
            provenance=provenance(["a.mcap"], fit_rmse=0.1234567890123, n_samples=20000),
        )
    return Calibration(sensors)


# ------------------------------------------------------ changed gains

CHANGED_SENSITIVITY = 0.8
"""Share of the strain ``changed_run``'s resistance follows: its calibration (``line_calibration``)
reads this share of the true strain."""


def line_calibration() -> Calibration:
    """S = 0.5 R - 50 ([Electrolycra] eq. (4) with c1 = 0.5, c0 = -50), R in 100..150."""
    cal = SensorCalibration(
        name="s1", model="cubic", params={"c": [-50.0, 0.5, 0.0, 0.0]},
        normalisation=Normalisation.from_ranges(100.0, 150.0, 0.0, 25.0),
        valid_range=ValidRange(95.0, 155.0, -2.5, 27.5),
        direction=DirectionSettings(deadzone=0.5, tau=0.0, k_sigma=4.0))
    return Calibration({"s1": cal})


def changed_run(seconds: float = 300.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, R, reference): 12 s cycles to 10-25 % strain; the resistance follows
    ``CHANGED_SENSITIVITY`` x the strain, so ``line_calibration`` reads that share of it."""
    rng = np.random.default_rng(2)
    t = np.arange(0.0, seconds, 0.05)
    peak = 10.0 + 15.0 * (np.floor(t / 12.0) % 4) / 3.0
    s = peak * 0.5 * (1.0 - np.cos(2 * np.pi * t / 12.0))
    r = (CHANGED_SENSITIVITY * s + 50.0) / 0.5 + rng.normal(0.0, 0.2, t.size)
    return t, r, s



def one_message(live: Any, name: str, t: float, value: Any) -> Any:
    """One message (a number, or an array's values) through ``LiveCompensator.on_input`` as
    a batch of one: its output, None when not published."""
    out, publish, _ = live.on_input(name, np.array([t]), np.asarray(value, float).reshape(1, -1))
    if not publish[0]:
        return None
    if np.ndim(value) == 0:
        return SensorOutput(float(out.strain[0, 0]), int(out.direction[0, 0]),
                            Status(int(out.status[0, 0])), bool(out.out_of_range[0, 0]),
                            std=math.nan if out.std is None else float(out.std[0, 0]))
    return ArrayOutput(out.strain[0], out.direction[0], out.status[0], out.out_of_range[0],
                       None if out.std is None else out.std[0])

# ---------------------------------------------------------------------------- markers
# ``pytest -m "not slow and not ros"`` is the quick run; scripts/test.sh (CI) runs all.
# The marks are given here, by module and test name, so that a test module needs no edit.

ROS_MODULES = frozenset({
    "test_node", "test_node_faults", "test_node_guards", "test_node_process",
    "test_node_references", "test_node_start", "test_ros2_cli",
})
"""Modules that need rclpy, the ros2 command line or colcon (marked ``ros``; so is any test
that takes the ``context`` fixture)."""

SLOW_MODULES = frozenset({"test_api_doc", "test_diagnose_day", "test_live_start",
                          "test_model_choice", "test_numba_setup", "test_progress"})
"""Modules whose every test takes about a second or more (marked ``slow``)."""

SLOW_TESTS: dict[str, tuple[str, ...]] = {
    "test_uncertainty_learn": ("test_fit_learns_a_band_from_several_runs_only",),
    "test_api": (
        "test_diagnose_gives_the_commands_report",
        "test_fit_options_and_unit",
        "test_recalibrate_prints_the_commands_readings",
        "test_the_api_writes_nothing_unless_asked",
    ),
    "test_apl": (
        "test_array_kernel_matches_per_sensor_models",
        "test_falling_resistance_sensor_fits_as_well_as_its_rising_mirror",
        "test_fit_recovers_known_forward_models",
        "test_kernel_matches_reference",
        "test_rate_sweep_apl_beats_mpi_beats_cubic",
    ),
    "test_array_budgets": (
        "test_1024_different_sensors_with_two_terms_each_load_as_written",
    ),
    "test_calibration": (
        "test_round_trip_is_exact",
    ),
    "test_cli": (
        "test_console_script_runs_as_a_process",
    ),
    "test_contracts": (
        "test_fit_on_hostile_data_gives_one_line_or_a_loadable_file",
    ),
    "test_creep_pi": (
        "test_array_steps_each_sensor_as_its_own_step",
    ),
    "test_csv_import": (
        "test_measured_files",
    ),
    "test_db3": (
        "test_a_zstd_bomb_per_message_is_skipped_and_counted",
        "test_damaged_db3_files_read_or_are_refused_in_one_line",
        "test_db3_evaluates_digit_for_digit",
        "test_db3_reads_as_the_mcap",
        "test_db3_replays_fits_and_diagnoses_like_the_mcap",
        "test_zstd_per_message_reads",
    ),
    "test_diagnose": (
        "test_a_clean_bag_gets_no_chain_condition",
        "test_a_long_run_is_thinned_to_the_row_budget_and_finds_the_same",
        "test_a_relaxing_start_is_left_out_and_the_spike_memory_found",
        "test_a_rest_level_that_moves_with_the_stretch_done_is_found",
        "test_finds_and_corrects_the_measurement_chain",
        "test_finds_crosstalk_between_array_neighbours",
        "test_finds_the_undeclared_effect",
        "test_json_contract_validation_bag_and_cal2",
        "test_no_missing_effect_adds_nothing",
        "test_per_run_baseline_only_when_runs_shift",
        "test_readings_and_errors_are_in_the_calibration_strain_unit",
    ),
    "test_diagnose_conditions": (
        "test_alternation_is_found_corrected_and_reported",
    ),
    "test_diagnose_creep": (
        "test_a_creep_the_calibration_lacks_is_named_and_carries",
    ),
    "test_effects_engine": (
        "test_array_crosstalk_replay_equals_step_array",
    ),
    "test_engine": (
        "test_batch_reads_but_never_writes_its_input",
    ),
    "test_evaluate": (
        "test_plots_are_written",
    ),
    "test_evaluate_stream": (
        "test_evaluate_command_json_and_plots_from_the_streamed_path",
        "test_nothing_to_score_names_both_sides",
        "test_streamed_evaluate_of_an_unchunked_bag_equals_the_whole_series",
        "test_streamed_evaluate_with_interpolated_references_equals_the_whole_series",
    ),
    "test_failed_writes": (
        "test_a_failed_write_leaves_no_temporary_file_and_names_its_target",
    ),
    "test_fit": (
        "test_a_slow_instrument_is_fitted_and_run_without_a_reset_at_every_sample",
    ),
    "test_fit_writes_loadable": (
        "test_sinh_pl_on_the_fibre_runs_writes_what_evaluate_loads",
        "test_whatever_fit_writes_evaluate_loads",
    ),
    "test_fuzz": (
        "test_calibration_truncated_at_any_line_loads_or_is_refused_cleanly",
        "test_fuzz_bag_reader_and_replay",
        "test_fuzz_calibration_loader",
        "test_fuzz_api_for_a_few_seconds",
        "test_fuzz_db3_reader",
        "test_fuzz_evaluate_over_folders_of_damaged_bags",
        "test_fuzz_live_node_for_a_few_seconds",
    ),
    "test_generalisation": (
        "test_cases_of_two_rig_runs",
    ),
    "test_hostile": (
        "test_a_killed_bag_writer_leaves_the_old_or_the_new_bag",
        "test_a_killed_replay_leaves_the_old_or_the_complete_new_output",
        "test_accepted_fit_options_always_fit_and_refused_ones_name_the_option",
        "test_concurrent_writers_end_with_one_complete_bag",
    ),
    "test_many_bags": (
        "test_a_bag_named_dots_gets_its_plots_inside_plots",
        "test_a_table_that_cannot_be_written_fails_the_command_and_keeps_the_old_one",
        "test_sigterm_ends_every_worker_and_removes_the_temporaries",
    ),
    "test_rational": (
        "test_split_beats_combined_on_hysteresis",
    ),
    "test_reduce": (
        "test_reduced_fit_error_on_the_full_data_is_close_to_the_full_fit",
    ),
    "test_reliability": (
        "test_killed_writer_leaves_the_old_or_the_new_file",
        "test_short_soak_every_model",
    ),
    "test_report_page": (
        "test_diagnose_report_holds_each_effect_and_the_error_before_and_after",
        "test_evaluate_report_over_several_bags",
    ),
    "test_series_and_batch": (
        "test_many_bags_a_table_each_and_errors_pooled",
    ),
    "test_sinh_pl": (
        "test_fit_recovers_forward_model",
    ),
    "test_spike_decay": (
        "test_kernel_matches_reference_and_step",
    ),
}
"""Per module, the tests (by function name: every parameter set) that take about a second
or more in a module of fast ones (marked ``slow``): 1.5 s or more in one full run with
``pytest --durations=0`` on the shared 2-core machine of docs/results.md (load average
about 5)."""


def _check_marked_names() -> None:
    """A marked module or test that no longer exists is a mark lost: fail the collection."""
    files = {path.stem: path for path in Path(__file__).parent.rglob("test_*.py")}
    missing = sorted((ROS_MODULES | SLOW_MODULES | set(SLOW_TESTS) | set(LONGEST_FIRST))
                     - set(files))
    for module, names in SLOW_TESTS.items():
        if module in files:
            text = files[module].read_text(encoding="utf-8")
            missing += [f"{module}::{name}" for name in names if f"def {name}(" not in text]
    if missing:
        raise pytest.UsageError(f"test/conftest.py marks tests that do not exist: {missing}")


LONGEST_FIRST = ("test_ros2_cli", "test_diagnose", "test_node_process", "test_failed_writes",
                 "test_fuzz", "test_progress", "test_hostile", "test_reliability",
                 "test_diagnose_creep", "test_api", "test_evaluate_stream",
                 "test_generalisation", "test_array_budgets", "test_db3", "test_many_bags",
                 "test_model_choice", "test_diagnose_day")
"""The modules that take longest in a full run (their tests' sum in ``scripts/test.sh
--durations=0``), longest first: they run first, so that neither worker of ``--dist
loadfile`` is left running one of them at the end while the other idles
(``pytest_configure`` keeps xdist from reordering the files by their number of tests, its
default, which started them last)."""


def pytest_configure(config: pytest.Config) -> None:
    """Under pytest-xdist (``-n N``), in the controller before the workers start: the numba
    kernels compiled into the cache and ``fitted``'s calibrations made (into ``FITS``) by two
    processes side by side (test/warm_kernels.py), so that the workers load them rather than
    each compile and fit the same ones. A part that fails is a warning: the tests then
    compile and fit what is missing, as without this step. The files are handed out in
    collection order (``LONGEST_FIRST``), not by their number of tests."""
    if hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", None):
        return
    config.option.loadscopereorder = False
    os.environ[FITS] = tempfile.mkdtemp(prefix="strain_comp_fits_")
    config.add_cleanup(functools.partial(shutil.rmtree, os.environ[FITS], ignore_errors=True))
    script = Path(__file__).with_name("warm_kernels.py")
    with tempfile.TemporaryFile() as log0, tempfile.TemporaryFile() as log1:
        runs = [(subprocess.Popen([sys.executable, str(script), str(part)], stdout=log,
                                  stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL), log)
                for part, log in enumerate((log0, log1))]
        for proc, log in runs:
            if proc.wait() != 0:
                log.seek(0)
                tail = log.read().decode(errors="replace")[-2000:]
                config.issue_config_time_warning(pytest.PytestWarning(
                    f"{script.name} {' '.join(proc.args[2:])} failed: {tail}"), stacklevel=2)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Mark each collected test ``ros`` and/or ``slow`` from the tables above; the modules of
    ``LONGEST_FIRST`` first, each module's tests kept together and in order."""
    _check_marked_names()
    for item in items:
        module = item.path.stem
        name = getattr(item, "originalname", item.name)
        if module in ROS_MODULES or "context" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.ros)
        if module in SLOW_MODULES or name in SLOW_TESTS.get(module, ()):
            item.add_marker(pytest.mark.slow)
    rank = {module: i for i, module in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.stem, len(rank)))  # stable: order kept


@pytest.fixture(scope="module", autouse=True)
def module_ros_env(request: pytest.FixtureRequest) -> None:
    """A module that starts ROS (``ROS_SLOT``) gets its own domain while its tests run:
    every module sets its environment when imported, and pytest imports them all before the
    first test, so the last one imported would otherwise speak for all."""
    slot = getattr(request.module, "ROS_SLOT", None)
    if slot is not None:
        os.environ.update(ros_env(slot))


@pytest.fixture(scope="module")
def context() -> Iterator[Any]:
    """An rclpy context for the module's nodes, shut down after its last test."""
    import rclpy

    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    yield ctx
    rclpy.try_shutdown(context=ctx)


class NodeUnderTest:
    """The node (``CompensatorNode`` with ``cli_args``, calibration paths
    relative to ``base_dir``), a probe node named ``probe_name`` and one executor spinning
    both, in this process."""

    def __init__(self, ctx: Any, base_dir: Path, cli_args: list[str],
                 probe_name: str = "probe") -> None:
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node

        from strain_comp.ros.compensator import CompensatorNode
        from strain_comp.ros.node import NODE_NAME

        self.node = CompensatorNode(NODE_NAME, base_dir=base_dir, context=ctx, cli_args=cli_args)
        self.probe = Node(probe_name, context=ctx)
        self.executor = SingleThreadedExecutor(context=ctx)
        self.executor.add_node(self.node)
        self.executor.add_node(self.probe)

    def spin_until(self, done: Callable[[], bool], timeout: float = 5.0) -> bool:
        """Spin until ``done()`` holds (True) or ``timeout`` seconds passed (False)."""
        from strain_comp.ros.player import spin_until

        return spin_until(self.executor, done, timeout)

    def wait_matched(self, pub: Any) -> Any:
        """``pub`` (a probe publisher) once the node subscribes to its topic."""
        assert self.spin_until(lambda: pub.get_subscription_count() > 0)
        return pub

    def call(self, service: str) -> Any:
        """The answer of the node's Trigger ``service``."""
        from std_srvs.srv import Trigger

        client = self.probe.create_client(Trigger, service)
        assert self.spin_until(client.service_is_ready)
        future = client.call_async(Trigger.Request())
        assert self.spin_until(future.done)
        return future.result()

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        self.probe.destroy_node()
