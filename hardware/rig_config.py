"""rig.toml: a lab writes its rig once (ports, rates, limits, calibration files).

Every key is checked when the file is read: unknown keys, wrong types and impossible values fail
with one line naming the file and the key, before anything is opened or written. Example:

    [hand]
    port = "/dev/ttyUSB0"     # or socket://host:port, or bh8emu:// (in-process emulator)
    baud = 9600               # the rate the hand powers up at
    switch_baud = 38400       # switch after connecting (0 keeps `baud`)
    rate_hz = 30.0
    watchdog_cycles = 3
    initialize = true         # send HI on connect (it opens the fingers)

    [limits]
    finger_counts = [0, 17800]
    spread_counts = [0, 3140]
    max_velocity_counts_s = 17000
    max_fingertip_force_kg = 2.0

    [tactile]
    port = "/dev/ttyUSB1"     # the PPS interface (frame layout: hardware/pps/frame.py)
    baud = 921600
    rate_hz = 30.0

    [stereo]                  # the Flea2 pair on two cv2.VideoCapture sources (hardware/cameras/driver.py)
    left = 0                  # device index, /dev path, URL, video file or image pattern
    right = 1
    backend = "any"           # any, firewire, v4l2, gstreamer, ffmpeg, images (as this OpenCV has)
    rate_hz = 30.0
    calibration = "calibration/stereo_calibration.json"   # relative to this file (optional)
    bbox = [112, 76, 105, 88] # the object's box on the first frame, rectified left pixels (optional)

    # Two pairs or more (two opposite ones give the Poisson ratio, `twin identify --poisson-from-cameras`):
    # [[stereo]] once per pair instead of [stereo], each with the keys above and a `name` (letters,
    # digits, _; the first may leave it out: "main"). The first is recorded as `stereo`, a further one
    # as `stereo_<name>`, and each pair's calibration file is its own.

    [calibration]             # paths relative to this file
    tactile_table = "calibration/tactile_table.csv"    # or tactile_points = "...points.csv"
"""

from __future__ import annotations

import tomllib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

from twin.hardware.bh262.driver import PortSettings
from twin.hardware.cameras.config import BACKENDS, StereoCaptureConfig

from twin.interface.backend import STEREO_CALIBRATION_KEY, stereo_calibration_key
from twin.interface.errors import ConfigError
from twin.interface.hand_spec import HandConfig
from twin.interface.tactile_spec import TactileConfig
from twin.safety import SafetyLimits
from twin.tactile.calibration import load_points, load_table
from twin.validation import check_number

_HAND_KEYS = {
    "port": str,
    "baud": int,
    "switch_baud": int,
    "rate_hz": float,
    "watchdog_cycles": int,
    "initialize": bool,
    "timeout_s": float,
    "realtime_timeout_s": float,
    "baud_switch_wait_s": float,
    "lcvc": int,
}
_TACTILE_KEYS = {"port": str, "baud": int, "rate_hz": float, "timeout_s": float}
_STEREO_KEYS = {
    "left": object,  # int or str: checked apart
    "right": object,
    "backend": str,
    "rate_hz": float,
    "latency_s": float,
    "native_width": int,
    "native_height": int,
    "width": int,
    "height": int,
    "timeout_s": float,
    "resync": bool,
    "calibration": str,
    "bbox": list,
    "name": str,
}
STEREO_CALIBRATION = STEREO_CALIBRATION_KEY
"""The key under which [stereo].calibration joins RigConfig.calibration (and the run's calibration/); a
further pair's is stereo_calibration_key(pair, name)."""
FIRST_PAIR_NAME = "main"
"""The name of a rig's first stereo pair when rig.toml gives none (twin.interface.backend)."""
MAX_STEREO_PAIRS = 4
CALIBRATION_FILES = {
    "tactile_table": "per-taxel lines (taxel,a_kpa_per_count,b_kpa): what eq. 5 loads",
    "tactile_points": "7-point calibration data (taxel,pressure_kpa,count): fitted when there is no table",
}
"""The calibration files a rig may name, and what each holds (twin/tactile/calibration.py)."""
_LIMIT_KEYS = {
    "finger_counts": list,
    "spread_counts": list,
    "max_velocity_counts_s": float,
    "max_fingertip_force_kg": float,
}
_POSITIVE_S = {"min": 0.0, "max": 60.0, "min_inclusive": False}
_RATE_HZ = {"min": 0.0, "max": 1000.0, "min_inclusive": False}
_PIXELS = {"min": 1, "max": 100_000}
_RANGES: dict[str, dict[str, Any]] = {
    "baud": {"min": 1, "max": 10_000_000},
    "switch_baud": {"min": 0, "max": 10_000_000},
    "rate_hz": _RATE_HZ,
    "watchdog_cycles": {"min": 1, "max": 1000},
    "timeout_s": _POSITIVE_S,
    "realtime_timeout_s": {"min": 0.0, "max": 10.0, "min_inclusive": False},
    "baud_switch_wait_s": {"min": 0.0, "max": 60.0},
    "lcvc": {"min": 1, "max": 255},
    "latency_s": {"min": 0.0, "max": 10.0},
    "native_width": _PIXELS,
    "native_height": _PIXELS,
    "width": _PIXELS,
    "height": _PIXELS,
    "max_velocity_counts_s": {"min": 0.0, "max": 1e6, "min_inclusive": False},
    "max_fingertip_force_kg": {"min": 0.0, "max": 100.0, "min_inclusive": False},
}
"""The range of every numeric key (any table): finite, and within what a rig can mean (twin.validation)."""


@dataclass(frozen=True, kw_only=True)
class HandPortConfig:
    """The serial hand of a rig: where it is and how the driver runs it."""

    port: PortSettings
    watchdog_cycles: int = 3
    initialize: bool = True
    lcvc: int = 1


@dataclass(frozen=True, kw_only=True)
class TactilePortConfig:
    """The PPS tactile interface of a rig: its port (a device path or pyserial URL) and line rate."""

    url: str
    baud: int = 921_600
    timeout_s: float = 0.5


@dataclass(frozen=True, kw_only=True)
class RigConfig:
    """A lab's rig: the hand (None: no hand configured), the hand's sampling, limits, calibration."""

    hand_port: HandPortConfig | None = None
    hand: HandConfig = field(default_factory=HandConfig)
    tactile_port: TactilePortConfig | None = None
    tactile: TactileConfig = field(default_factory=TactileConfig)
    stereo_pairs: tuple[StereoPairConfig, ...] = ()
    """Every stereo pair (none: no cameras), the first recorded as `stereo`; pair k's calibration file is
    calibration[stereo_calibration_key(k, name)]."""
    limits: SafetyLimits = field(default_factory=SafetyLimits)
    calibration: dict[str, Path] = field(default_factory=dict)
    source: Path | None = None

    @property
    def stereo(self) -> StereoCaptureConfig | None:
        """The first pair's capture (None: no cameras)."""
        return self.stereo_pairs[0].capture if self.stereo_pairs else None

    @property
    def stereo_bbox(self) -> tuple[int, int, int, int] | None:
        """The first pair's bbox: the default of `--bbox`."""
        return self.stereo_pairs[0].bbox if self.stereo_pairs else None

    def with_hand_port(self, url: str) -> RigConfig:
        """The same rig with the hand on `url` (the --hand flag overrides the file)."""
        if self.hand_port is None:
            return _replace(self, hand_port=HandPortConfig(port=PortSettings(url=url)))
        settings = self.hand_port.port
        port = PortSettings(**{**vars(settings), "url": url})
        return _replace(self, hand_port=_replace(self.hand_port, port=port))

    def to_json(self) -> dict[str, Any]:
        """What run.json records about the rig."""
        hp = self.hand_port
        return {
            "source": str(self.source) if self.source else None,
            "hand_port": None
            if hp is None
            else {
                "url": hp.port.url,
                "baud": hp.port.baud,
                "switch_baud": hp.port.switch_baud,
                "watchdog_cycles": hp.watchdog_cycles,
            },
            "tactile_port": vars(self.tactile_port) if self.tactile_port else None,
            "stereo": vars(self.stereo) if self.stereo else None,
            "stereo_pairs": [{"name": p.name, **vars(p.capture)} for p in self.stereo_pairs],
            "limits": vars(self.limits),
            "calibration": {k: str(v) for k, v in self.calibration.items()},
        }


@dataclass(frozen=True, kw_only=True)
class StereoPairConfig:
    """One stereo pair of a rig: its name (the run's `stereo_<name>` stream after the first), its capture
    and the object's box on its first frame (rectified left pixels; None: `--bbox` or the backend's)."""

    name: str
    capture: StereoCaptureConfig
    bbox: tuple[int, int, int, int] | None = None


def _replace(obj: Any, **changes: Any) -> Any:
    import dataclasses

    return dataclasses.replace(obj, **changes)


def _typed(where: str, table: dict, schema: dict) -> dict:
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: expected a table")
    unknown = set(table) - set(schema)
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {', '.join(sorted(unknown))}; known: {', '.join(schema)}")
    out = {}
    for key, value in table.items():
        kind = schema[key]
        ok = isinstance(value, kind) and not (kind is int and isinstance(value, bool))
        if kind is float and isinstance(value, int) and not isinstance(value, bool):
            value, ok = float(value), True
        if not ok:
            raise ConfigError(f"{where}.{key}: expected {kind.__name__}, got {value!r}")
        if kind in (int, float):
            value = check_number(value, f"{where}.{key}", kind=kind, **_RANGES[key])
        out[key] = value
    return out


def load_rig(path: Path | str) -> RigConfig:
    """Read and check a rig.toml; ConfigError (one line) on any problem."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"--rig {path}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"--rig {path}: cannot read ({exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"--rig {path}: not valid TOML ({exc})") from None
    except RecursionError:
        raise ConfigError(f"--rig {path}: not valid TOML (nested too deeply)") from None
    unknown = set(data) - {"hand", "tactile", "stereo", "limits", "calibration"}
    if unknown:
        raise ConfigError(
            f"{path}: unknown table(s) {', '.join(sorted(unknown))}; "
            "known: hand, tactile, stereo, limits, calibration"
        )
    hand = _typed(f"{path}: [hand]", data.get("hand", {}), _HAND_KEYS)
    limits = _typed(f"{path}: [limits]", data.get("limits", {}), _LIMIT_KEYS)
    tactile = _typed(f"{path}: [tactile]", data.get("tactile", {}), _TACTILE_KEYS)
    calibration = data.get("calibration", {})
    if not isinstance(calibration, dict) or not all(isinstance(v, str) for v in calibration.values()):
        raise ConfigError(f"{path}: [calibration] maps names to file paths (strings)")
    unknown = set(calibration) - set(CALIBRATION_FILES)
    if unknown:
        raise ConfigError(
            f"{path}: [calibration] unknown file name(s) {', '.join(sorted(unknown))}; known: "
            + ", ".join(CALIBRATION_FILES)
        )
    files = {k: _named_file(path, f"[calibration].{k}", v) for k, v in calibration.items()}
    for key, file in files.items():
        _check_tactile_file(key, file)
    stereo_pairs = _stereo_pairs(path, data["stereo"], files) if "stereo" in data else ()
    for key in ("finger_counts", "spread_counts"):
        if key in limits:
            pair = limits[key]
            if len(pair) != 2 or not all(isinstance(v, int | float) for v in pair) or not pair[0] < pair[1]:
                raise ConfigError(f"{path}: [limits].{key} must be [low, high] with low < high")
            limits[key] = (float(pair[0]), float(pair[1]))
    try:
        safety = SafetyLimits(**limits)
        hand_config = HandConfig(rate_hz=hand.pop("rate_hz", HandConfig().rate_hz))
        hand_port = None
        if "port" in hand:
            port_keys = ("baud", "timeout_s", "realtime_timeout_s", "baud_switch_wait_s")
            settings = {k: hand[k] for k in port_keys if k in hand}
            if "switch_baud" in hand:
                settings["switch_baud"] = hand["switch_baud"] or None
            hand_port = HandPortConfig(
                port=PortSettings(url=hand["port"], **settings),
                **{k: hand[k] for k in ("watchdog_cycles", "initialize", "lcvc") if k in hand},
            )
        elif set(hand) - {"rate_hz"}:
            raise ConfigError("[hand] settings given without a port")
        tactile_config = TactileConfig(rate_hz=tactile.pop("rate_hz", TactileConfig().rate_hz))
        tactile_port = None
        if "port" in tactile:
            tactile_port = TactilePortConfig(url=tactile.pop("port"), **tactile)
            if not {"tactile_table", "tactile_points"} & set(files):
                raise ConfigError(
                    "[tactile] pads need their calibration: "
                    "name tactile_table or tactile_points in [calibration]"
                )
        elif tactile:
            raise ConfigError("[tactile] settings given without a port")
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    return RigConfig(
        hand_port=hand_port,
        hand=hand_config,
        tactile_port=tactile_port,
        tactile=tactile_config,
        stereo_pairs=stereo_pairs,
        limits=safety,
        calibration=files,
        source=path,
    )


def _named_file(rig: Path, key: str, name: str, *, exists: bool = True) -> Path:
    """A file a rig.toml names: relative to the rig file, and inside its directory once every link is
    followed (a rig file copies its calibration into every run: it may not reach for anything else).
    `exists`: refuse a name that is not a regular file here (else its loader says what is wrong)."""
    if not name or "\0" in name:
        raise ConfigError(f"{rig}: {key}: {name!r} is not a file name")
    base = rig.parent.resolve()
    file = rig.parent / name
    try:
        inside = Path(name).is_absolute() is False and file.resolve().is_relative_to(base)
    except (OSError, RuntimeError, ValueError):  # a symlink loop, a name the OS refuses
        inside = False
    if not inside:
        raise ConfigError(
            f"{rig}: {key}: {name!r} is outside the rig file's directory {base}; "
            "put the file beside rig.toml (or below it) and name it relative to it"
        )
    if exists and not file.is_file():
        raise ConfigError(f"{rig}: {key}: no such file {file}")
    return file


def _check_tactile_file(key: str, file: Path) -> None:
    """Parse a tactile calibration file now (whether or not [tactile] is configured): a file that is
    not one is refused in one line before anything runs, and never copied into a run."""
    (load_table if key == "tactile_table" else load_points)(file)


def _stereo_pairs(path: Path, tables: Any, files: dict[str, Path]) -> tuple[StereoPairConfig, ...]:
    """[stereo] (one pair) or [[stereo]] (one table per pair), each pair's calibration file (checked)
    joining `files` under its own key."""
    if isinstance(tables, dict):
        tables = [tables]
    if not isinstance(tables, list) or not tables:
        raise ConfigError(f"{path}: [stereo]: expected a table, or [[stereo]] tables, one per pair")
    if len(tables) > MAX_STEREO_PAIRS:
        raise ConfigError(f"{path}: [[stereo]]: {len(tables)} pairs (at most {MAX_STEREO_PAIRS})")
    pairs: list[StereoPairConfig] = []
    for k, table in enumerate(tables):
        label = "[stereo]" if len(tables) == 1 else f"[[stereo]] #{k + 1}"
        pairs.append(_stereo(label, path, k, table, files, [p.name for p in pairs]))
    return tuple(pairs)


def _stereo(
    label: str, path: Path, pair: int, table: Any, files: dict[str, Path], taken: list[str]
) -> StereoPairConfig:
    """One [stereo] table (`label` in messages) as its name, the driver's config and the optional box;
    its calibration file (checked) joins `files`."""
    where = f"{path}: {label}"
    stereo = _typed(where, table, _STEREO_KEYS)
    name = stereo.pop("name", None)
    if name is None and pair > 0:
        raise ConfigError(f"{where}.name: missing (every pair after the first needs one: lateral, opposite)")
    name = FIRST_PAIR_NAME if name is None else name
    if not (name.isascii() and name.replace("_", "").isalnum() and len(name) <= 32):
        raise ConfigError(f"{where}.name: {name!r} is not letters, digits and _ (at most 32)")
    if name in taken:
        raise ConfigError(f"{where}.name: {name!r} names two pairs")
    for side in ("left", "right"):
        if side not in stereo:
            raise ConfigError(f"{where}.{side}: missing (a device index, path, URL or file pattern)")
        value = stereo[side]
        if isinstance(value, bool) or not isinstance(value, int | str):
            raise ConfigError(f"{where}.{side}: expected a device index or a string, got {value!r}")
    if stereo.get("backend", "any") not in BACKENDS:
        raise ConfigError(f"{where}.backend: {stereo['backend']!r} is not one of {', '.join(BACKENDS)}")
    bbox = stereo.pop("bbox", None)
    if bbox is not None:
        if len(bbox) != 4 or not all(isinstance(v, int) and not isinstance(v, bool) for v in bbox):
            raise ConfigError(f"{where}.bbox: expected [x, y, w, h] in pixels, got {bbox!r}")
        if bbox[2] <= 0 or bbox[3] <= 0:
            raise ConfigError(f"{where}.bbox: {bbox} is empty (width and height must be > 0)")
        bbox = tuple(bbox)
    calibration = stereo.pop("calibration", None)
    if calibration is not None:
        file = _named_file(path, f"{label}.calibration", calibration, exists=False)
        from twin.vision.calibration import StereoCalibration, StereoCalibrationError  # a rig with cameras

        try:
            StereoCalibration.load(file)  # one line naming the file and what is wrong with it
        except StereoCalibrationError as exc:
            raise StereoCalibrationError(f"{where}.calibration: {exc}") from None
        files[stereo_calibration_key(pair, name)] = file
    try:
        return StereoPairConfig(name=name, capture=StereoCaptureConfig(**stereo), bbox=bbox)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None


class StereoPairFile(NamedTuple):
    """A stereo pair as rig_toml writes it: its name (None: the first, unnamed), left and right sources,
    its calibration file (relative to rig.toml) and the object's box."""

    name: str | None
    sources: tuple[str, str]
    calibration: str | None = None
    bbox: tuple[int, int, int, int] | None = None


EMULATED_TIMEOUT_S = 10.0
"""The pads' and cameras' timeout in a rig file written for emulators on the same host (rig_toml)."""


def rig_toml(
    hand_url: str,
    *,
    baud: int = 9600,
    switch_baud: int | None = 38400,
    tactile_url: str | None = None,
    tactile_table: str | None = None,
    stereo: tuple[str, str] | None = None,
    stereo_backend: str = "ffmpeg",
    stereo_rate_hz: float = 30.0,
    stereo_calibration: str | None = None,
    stereo_bbox: tuple[int, int, int, int] | None = None,
    more_stereo: Sequence[StereoPairFile] = (),
    emulated: bool = False,
) -> str:
    """A rig.toml for a hand on `hand_url` (and tactile pads), what `twin emulate rig --rig-file` writes.

    `emulated`: the devices are emulators sharing this host's CPU (twin-rendered frames, a twin-driven
    pad scan): the pads' and cameras' timeouts are then EMULATED_TIMEOUT_S, since a loaded host delivers
    their frames late, not never (a real device's default stays the hang detector it is). `more_stereo`:
    further pairs beside `stereo`, named (then every pair is a [[stereo]] table)."""
    text = (
        "# written by `twin emulate rig`\n"
        "[hand]\n"
        f'port = "{hand_url}"\n'
        f"baud = {baud}\n"
        f"switch_baud = {switch_baud or 0}\n"
        "rate_hz = 30.0\n"
        "watchdog_cycles = 3\n"
    )
    timeout = f"timeout_s = {EMULATED_TIMEOUT_S!r}  # emulated on this host: late, not lost\n"
    timeout = timeout if emulated else ""
    if tactile_url:
        text += f'\n[tactile]\nport = "{tactile_url}"\nrate_hz = 30.0\n{timeout}'
    pairs = [StereoPairFile(None, stereo, stereo_calibration, stereo_bbox)] if stereo else []
    pairs += list(more_stereo)
    for pair in pairs:
        head = "[stereo]" if len(pairs) == 1 else "[[stereo]]"
        text += f"\n{head}\n" + (f'name = "{pair.name}"\n' if pair.name else "")
        text += (
            f'left = "{pair.sources[0]}"\nright = "{pair.sources[1]}"\n'
            f'backend = "{stereo_backend}"\nrate_hz = {float(stereo_rate_hz)!r}\n{timeout}'
        )
        if pair.calibration:
            text += f'calibration = "{pair.calibration}"\n'
        if pair.bbox:
            text += f"bbox = [{', '.join(str(int(v)) for v in pair.bbox)}]\n"
    if tactile_table:
        text += f'\n[calibration]\ntactile_table = "{tactile_table}"\n'
    return text
