"""Node parameters: the ``<node>: ros__parameters:`` YAML of the rclpy node (layout, checks
and path resolution: docs/architecture.md, "Inside the node"; docs/ros.md)."""

from __future__ import annotations

import difflib
import os
import re
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import yaml

from strain_comp import models  # noqa: F401  (registers the families calibrations name)
from strain_comp.base.samples import DEFAULT_GAP_RESET
from strain_comp.core.calibration import MAX_FILE_BYTES, Calibration, SensorCalibration
from strain_comp.core.calibration_file import load_calibration
from strain_comp.core.engine import Engine
from strain_comp.core.tare import TARE_MODES
from strain_comp.errors import InputError, ParameterError
from strain_comp.io.safe_yaml import LimitError, load_limited

PACKAGE = "strain_comp"


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: ROS type name, default, inclusive range, description, read-only."""

    name: str
    type: str  # "double" | "integer" | "string" | "string_array" | "bool"
    default: Any
    range: tuple[float, float] | None
    description: str
    read_only: bool


TUNABLES: tuple[ParamSpec, ...] = (
    ParamSpec("deadzone_scale", "double", 1.0, (0.01, 100.0),
              "Multiplies every sensor's direction dead zone [ohm/s] from its calibration.",
              False),
    ParamSpec("publish_rate_limit_hz", "double", 0.0, (0.0, 10000.0),
              "Maximum output rate per sensor or array [Hz]; 0 publishes every input.", False),
    ParamSpec("stale_after_s", "double", 1.0, (0.001, 3600.0),
              "Diagnostics report a sensor STALE after this long without a good sample [s].",
              False),
    ParamSpec("gap_reset_s", "double", DEFAULT_GAP_RESET, (0.001, 3600.0),
              "A jump between good samples longer than this resets the model state [s].", False),
    ParamSpec("diagnostics_period_s", "double", 1.0, (0.01, 60.0),
              "Period of the /diagnostics publication [s].", True),
    ParamSpec("batch_period_s", "double", 0.01, (0.0005, 1.0),
              "Inputs that arrived are handled together every this many seconds of the "
              "steady clock, each sample with its own outputs and stamp: a longer period "
              "costs less CPU and adds up to that much latency [s].", True),
    ParamSpec("span_strain", "double", 0.0, (0.0, 1e6),
              "The known strain (calibration's unit) every sensor is held at when ~/span is "
              "called; 0: not set (~/span refuses).", False),
    ParamSpec("known_strain", "double", 0.0, (-1e6, 1e6),
              "The known strain (calibration's unit) every sensor is at when ~/reference is "
              "called (fuse_references: true); 0 (default): at rest.", False),
)
TUNABLE = {spec.name: spec for spec in TUNABLES}
EXECUTORS = ("events", "single_threaded")
ROS_OWNED = ("use_sim_time", "qos_overrides", "start_type_description_service")
"""Parameters ROS itself declares; accepted in a params file and ignored here."""


def structural_specs(sensors: list[str], arrays: list[str]) -> list[ParamSpec]:
    """Read-only parameters for the given sensor and array names (declare in this order)."""
    specs = [ParamSpec("sensors", "string_array", [], None,
                       "Names of single sensors, each with a NAME.* map.", True),
             ParamSpec("arrays", "string_array", [], None,
                       "Names of sensor arrays, each with a NAME.* map.", True),
             ParamSpec("tare", "string", "calibration", None,
                       "calibration: the calibrated zero; auto: the rest resistance of the "
                       "first seconds at rest becomes the zero.", True),
             ParamSpec("executor", "string", "events", None,
                       "events: rclpy's EventsExecutor (about 3x less CPU per message); "
                       "single_threaded: rclpy's SingleThreadedExecutor.", True),
             ParamSpec("baseline_tracking", "string", "off", None,
                       "off, the only value: the rest level is the calibration's or the "
                       "tare's (baseline tracking was removed; on is refused).", True),
             ParamSpec("fuse_references", "bool", False, None,
                       "false (default) or true: known strains on NAME/strain_reference (an "
                       "array: ARRAY/strain_reference, NaN for none) and ~/reference "
                       "(known_strain) are fused into each sensor's output gain and offset "
                       "(shown in /diagnostics).", True)]
    for name in sensors:
        specs += [ParamSpec(f"{name}.topic", "string", f"{name}/resistance", None,
                            "Input topic (std_msgs/Float64, ohm or divider volts).", True),
                  ParamSpec(f"{name}.calibration", "string", "", None,
                            "Calibration YAML of this sensor.", True)]
    for name in arrays:
        specs += [ParamSpec(f"{name}.topic", "string", f"{name}/resistance", None,
                            "Input topic (std_msgs/Float64MultiArray), one value per sensor.",
                            True),
                  ParamSpec(f"{name}.sensors", "string_array", [], None,
                            "Ordered sensor names of the array's vector.", True),
                  ParamSpec(f"{name}.calibration", "string", "", None,
                            "Calibration YAML holding every sensor of the array.", True)]
    return specs


def validate_tunable(name: str, value: Any) -> float:
    spec = TUNABLE[name]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParameterError(name, f"must be a number, got {value!r}")
    lo, hi = spec.range if spec.range is not None else (-float("inf"), float("inf"))
    if not lo <= float(value) <= hi:
        raise ParameterError(name, f"must be in [{lo}, {hi}], got {value}")
    return float(value)


@dataclass(frozen=True)
class InputTopic:
    """A subscribed resistance topic: one sensor (``sensors`` of length 1) or an array."""

    name: str
    topic: str
    sensors: tuple[str, ...]
    calibration_path: Path
    is_array: bool


@dataclass
class NodeParams:
    """Validated parameters: inputs, the merged calibration, tunable values."""

    inputs: list[InputTopic]
    calibration: Calibration
    tunables: dict[str, float] = field(default_factory=dict)
    tare: str = "calibration"
    executor: str = "events"
    fuse_references: bool = False

    def build_engine(self) -> Engine:
        """The Engine these parameters describe (gap, stale and dead-zone tunables applied)."""
        arrays = {i.name: list(i.sensors) for i in self.inputs if i.is_array}
        return Engine(self.calibration, arrays=arrays,
                      gap_reset=self.tunables["gap_reset_s"],
                      stale_after=self.tunables["stale_after_s"],
                      deadzone_scale=self.tunables["deadzone_scale"])


def _flatten(node: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested mappings to ROS's dotted parameter names."""
    flat: dict[str, Any] = {}
    for key, value in node.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(_flatten(value, f"{name}."))
        else:
            flat[name] = value
    return flat


def resolve_path(value: str, base_dir: Path | None) -> Path:
    """A calibration path: absolute, in base_dir (else cwd), the share dir or the checkout."""
    path = Path(os.path.expanduser(value))
    if path.is_absolute():
        return path
    shares = []
    try:
        from ament_index_python.packages import get_package_share_directory

        shares.append(Path(get_package_share_directory(PACKAGE)))
    except (ImportError, LookupError, OSError):  # no ament index (AMENT_PREFIX_PATH unset)
        pass  # or the package is not in it
    checkout = Path(__file__).resolve().parents[2]  # an editable install has no share dir
    shares += [Path(sys.prefix) / "share" / PACKAGE, checkout]
    bases = [base_dir if base_dir is not None else Path.cwd()]
    for share in shares:
        bases += [share, share / "config"]
    for base in bases:
        if (base / path).is_file():
            return base / path
    return (base_dir or Path.cwd()) / path


def _string(flat: Mapping[str, Any], key: str, default: str | None = None) -> str:
    value = flat.get(key, default)
    if value is None:
        raise ParameterError(key, "missing")
    if not isinstance(value, str) or not value:
        raise ParameterError(key, f"must be a non-empty string, got {value!r}")
    return value


def _choice(flat: Mapping[str, Any], key: str, default: str, choices: tuple[str, ...]
            ) -> str:
    value = _string(flat, key, default)
    if value not in choices:
        raise ParameterError(key, f"must be one of {', '.join(choices)}, got {value!r}")
    return value


_TOKEN = r"[A-Za-z_][A-Za-z0-9_]*"
NAME_RULE = ("letters, digits and underscores, not starting with a digit, no double "
             "underscore")
"""ROS 2's rule for a name token (a sensor or array name; each part of a topic)."""


def _ros_name(value: str, key: str, *, topic: bool = False) -> str:
    """``value`` if it is a valid ROS name (or topic name); ParameterError otherwise."""
    body = value[2:] if topic and value.startswith("~/") else (
        value[1:] if topic and value.startswith("/") else value)
    pattern = rf"{_TOKEN}(/{_TOKEN})*" if topic else _TOKEN
    if not re.fullmatch(pattern, body) or "__" in value:
        what = "topic name" if topic else "name"
        raise ParameterError(key, f"{value!r} is not a valid ROS {what} ({NAME_RULE}"
                             + ("; parts joined by '/'" if topic else "") + ")")
    return value


def _names(flat: Mapping[str, Any], key: str) -> list[str]:
    """A list of names (null, as older ``ros2 param dump`` files write [], is empty)."""
    value = flat.get(key)
    if value is None:
        return []
    if not isinstance(value, list) or not all(isinstance(v, str) and v for v in value):
        raise ParameterError(key, f"must be a list of names, got {value!r}")
    if len(set(value)) != len(value):
        raise ParameterError(key, f"names repeat: {value}")
    return [_ros_name(v, key) for v in value]


def _sensor_from(calibration: Calibration, name: str, where: str) -> SensorCalibration:
    if name in calibration.sensors:
        return calibration.sensors[name]
    if len(calibration.sensors) == 1:
        return replace(next(iter(calibration.sensors.values())), name=name)
    raise ParameterError(where, f"sensor {name!r} is not in the calibration file "
                                f"(it has {', '.join(calibration.sensors)})")


def parse_values(flat: Mapping[str, Any], *, base_dir: Path | None = None) -> NodeParams:
    """Validate flat (dotted) parameter values and load every calibration file."""
    sensors = _names(flat, "sensors")
    arrays = _names(flat, "arrays")
    if not sensors and not arrays:
        raise ParameterError("sensors", "no sensors and no arrays: nothing to compensate")
    known = {spec.name for spec in structural_specs(sensors, arrays)} | set(TUNABLE)
    for key in flat:
        if key not in known and key.split(".")[0] not in ROS_OWNED:
            raise ParameterError(key, unknown_hint(key, known, sensors + arrays))
    tare = _choice(flat, "tare", "calibration", TARE_MODES)
    executor = _choice(flat, "executor", "events", EXECUTORS)
    if _string(flat, "baseline_tracking", "off") != "off":
        raise ParameterError("baseline_tracking", "baseline tracking was removed; only off "
                             "remains")
    fuse = flat.get("fuse_references", False)
    if not isinstance(fuse, bool):
        raise ParameterError("fuse_references", f"must be true or false, got {fuse!r}")
    # before any calibration loads: its probe compiles kernels, seconds on a first start
    tunables = {spec.name: validate_tunable(spec.name, flat.get(spec.name, spec.default))
                for spec in TUNABLES}
    inputs: list[InputTopic] = []
    merged: dict[str, SensorCalibration] = {}
    loaded: dict[Path, Calibration] = {}
    for name, is_array in [(n, False) for n in sensors] + [(n, True) for n in arrays]:
        topic = _ros_name(_string(flat, f"{name}.topic", f"{name}/resistance"),
                          f"{name}.topic", topic=True)
        path = resolve_path(_string(flat, f"{name}.calibration"), base_dir)
        if path not in loaded:
            loaded[path] = load_calibration(path)
        members = _names(flat, f"{name}.sensors") if is_array else [name]
        if not members:
            raise ParameterError(f"{name}.sensors", "an array needs its ordered sensor names")
        for member in members:
            if member in merged:
                raise ParameterError(f"{name}.sensors" if is_array else "sensors",
                                     f"sensor {member!r} appears twice")
            merged[member] = _sensor_from(loaded[path], member, f"{name}.calibration")
        inputs.append(InputTopic(name, topic, tuple(members), path, is_array))
    topics = [i.topic for i in inputs]
    if len(set(topics)) != len(topics):
        raise ParameterError("topic", f"two inputs share a topic: {topics}")
    return NodeParams(inputs, Calibration(merged), tunables, tare, executor, fuse)


def unknown_hint(key: str, known: set[str], names: list[str]) -> str:
    """'unknown parameter' with the closest valid name, or the missing list entry."""
    head = key.split(".")[0]
    if "." in key and head not in names:
        return (f"unknown parameter: {head!r} is not listed in 'sensors' or 'arrays' "
                f"(listed: {', '.join(names) or 'none'})")
    close = difflib.get_close_matches(key, sorted(known), n=1)
    return "unknown parameter" + (f"; did you mean {close[0]!r}?" if close else "")


def read_blocks(path: str | os.PathLike[str]) -> dict[str, Any]:
    """A params file's top-level node blocks (names without a leading '/')."""
    path = Path(path)
    try:
        with path.open("rb") as handle:  # a calibration file's size budget
            data = handle.read(MAX_FILE_BYTES + 1)
        if len(data) > MAX_FILE_BYTES:
            raise InputError(f"{path}: params file refused: larger than {MAX_FILE_BYTES} bytes")
        root = load_limited(data.decode("utf-8"))
    except OSError as err:
        raise InputError(f"{path}: cannot read params file: {err.strerror or err}") from None
    except LimitError as err:
        raise InputError(f"{path}: params file refused: {err}") from None
    except (UnicodeDecodeError, yaml.YAMLError) as err:
        raise InputError(f"{path}: not a YAML params file: "
                         + " ".join(str(err).split())) from None
    if not isinstance(root, Mapping) or not root:
        raise InputError(f"{path}: must be a mapping '<node>: ros__parameters: ...'")
    return {str(k).lstrip("/"): v for k, v in root.items()}


def read_params(files: list[Path], name: str = "compensator", namespace: str = "/"
                ) -> tuple[dict[str, Any], Path | None]:
    """The files' values for the node (blocks as rcl matches them) and the base folder."""
    ns = namespace.strip("/")
    fqn = f"{ns}/{name}" if ns else name
    values: dict[str, Any] = {}
    base = named = None
    for path in files:
        blocks = read_blocks(path)
        mine = [blocks[b] for b in ("**", f"{ns}/*" if ns else "*", f"**/{name}", fqn)
                if b in blocks]
        if not mine and (name != "compensator" or len(files) == 1):
            raise InputError(f"{path}: no parameters for node '/{fqn}' (the file holds: "
                             f"{', '.join(blocks)}); name a block '/{fqn}' or '/**/{name}'")
        for block in mine:
            if not (isinstance(block, Mapping)
                    and isinstance(block.get("ros__parameters"), Mapping)):
                raise InputError(f"{path}: /{fqn}: missing 'ros__parameters' mapping")
            flat = _flatten(block["ros__parameters"])
            base = path.resolve().parent
            if any(key.rpartition(".")[2] == "calibration" for key in flat):
                named = base  # the last file naming a calibration (ros2 launch's does not)
            values.update(flat)
    return values, named or base


def load_params(path: str | os.PathLike[str]) -> NodeParams:
    """Read a ROS 2 params file's values for the node ``compensator`` and validate them."""
    path = Path(path)
    values, base_dir = read_params([path])
    try:
        return parse_values(values, base_dir=base_dir)
    except ParameterError as err:
        raise ParameterError(f"{path}: {err.field}", err.problem) from None
