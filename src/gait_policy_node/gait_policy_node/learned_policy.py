"""Learned gait policies: a numpy network from observation to the paper's gait parameters, and its file.

Network (paper, appendix C): normalised observation -> one hidden layer of tanh units -> 8
outputs -> tanh; or a linear map -> tanh. Flat parameter layout (what the trainers search over):
mlp = W1 (hidden x obs, row-major), b1, W2 (8 x hidden), b2; linear = W (8 x obs), b. The 8
outputs decode into [f, p_swing, theta_FL, theta_RR, theta_RL] as train_config.ActionConfig says.

File: ``.npz`` read with ``allow_pickle=False``. Keys: format_version, kind, observation,
hidden_units, params, obs_mean, obs_std, frequency_range, swing_ratio_range, offset_prior,
offset_prior_weight, config_json (the whole training config), config_hash (train_config's
policy_hash of it), iteration. Anything missing, mis-shaped, non-finite, beyond VALUE_BOUND or
inconsistent is refused with a ConfigError naming the key. The same file is what gait_policy_node loads.
"""

from __future__ import annotations

import json
import math
import os
import struct
import zipfile
import zlib
from pathlib import Path

import numpy as np
from a1_common.config import ConfigError
from a1_common.files import TEMPORARY_MARK, write_npz_atomically
from convex_mpc_node.gait import TWO_PI, GaitParams

from gait_policy_node.train_config import OBSERVATION_SIZES, ActionConfig, TrainConfig, train_config_from_mapping

ACTION_SIZE = 8  # f, 3 x sin, 3 x cos, p_swing
FORMAT_VERSION = 1
MAX_NPZ_BYTES = 1 << 30  # uncompressed size read_npz accepts by default (training checkpoints)
MAX_POLICY_BYTES = 64 << 20  # a policy file: the largest network (4096 hidden units) needs about 2 MB
VALUE_BOUND = 1e6  # |weights|, |obs_mean| and 1 / obs_std in a policy file (trained ones are O(1))
# The trained policy this package ships (package data, installed with it), selected by this name.
SHIPPED_POLICY = "learned"
SHIPPED_POLICY_FILE = Path(__file__).with_name("policies") / "learned_gait.npz"


def _from_unit(a: float, low: float, high: float, centre: float | None) -> float:
    """a in [-1, 1] -> [low, high]: affine (centre None: the reference's, kept to the last bit), or
    linear on each side of a = 0 -> centre."""
    if centre is None:
        return low + 0.5 * (a + 1.0) * (high - low)
    return centre + a * ((high - centre) if a >= 0.0 else (centre - low))


def _to_unit(value: float, low: float, high: float, centre: float | None) -> float:
    """Inverse of _from_unit (unclipped: ``encode_action`` clips)."""
    if centre is None:
        return 2.0 * (value - low) / (high - low) - 1.0
    return (value - centre) / ((high - centre) if value >= centre else (centre - low))


def decode_action(a: np.ndarray, cfg: ActionConfig) -> GaitParams:
    """Network outputs a in [-1, 1]^8 -> gait parameters (see ActionConfig)."""
    a = np.clip(np.asarray(a, dtype=float), -1.0, 1.0)
    f_centre, p_centre = cfg.timing_prior or (None, None)
    f = _from_unit(a[0], *cfg.frequency_range, f_centre)
    p = _from_unit(a[7], *cfg.swing_ratio_range, p_centre)
    prior = np.asarray(cfg.offset_prior, dtype=float)
    b = cfg.offset_prior_weight
    theta = np.arctan2(b * np.sin(prior) + a[1:4], b * np.cos(prior) + a[4:7]) % TWO_PI
    theta = np.where(theta >= TWO_PI, 0.0, theta)  # -0.0 % 2pi can round up to 2pi
    return GaitParams(float(f), float(p), (0.0, *(float(t) for t in theta)))


def encode_action(gait: GaitParams, cfg: ActionConfig, like: np.ndarray, limit: float = 1.0) -> np.ndarray:
    """Network outputs within +-``limit`` that ``decode_action`` turns into ``gait`` (f and p_swing
    clipped into their ranges). The offsets' (sin, cos) pairs keep the lengths they have in ``like``
    (outputs of the network the result is meant for), so that mostly their angles change; a pair is
    shortened where that length would put an output beyond ``limit`` (always possible: the prior's
    weight is under 1), so the offsets decode exactly."""
    like = np.asarray(like, dtype=float)
    f_centre, p_centre = cfg.timing_prior or (None, None)
    a = np.empty(ACTION_SIZE)
    a[0] = _to_unit(gait.stepping_frequency, *cfg.frequency_range, f_centre)
    a[7] = _to_unit(gait.swing_ratio, *cfg.swing_ratio_range, p_centre)
    prior = np.asarray(cfg.offset_prior, dtype=float)
    b = cfg.offset_prior_weight
    sin_prior, cos_prior = b * np.sin(prior), b * np.cos(prior)
    theta = np.asarray(gait.phase_offsets[1:], dtype=float)
    radius = np.maximum(np.hypot(sin_prior + like[1:4], cos_prior + like[4:7]), 0.1)
    for component, offset in ((np.sin(theta), sin_prior), (np.cos(theta), cos_prior)):
        # |radius * component - offset| <= limit; only the side the component points to can bind.
        with np.errstate(divide="ignore"):
            bound = np.where(component > 0, (offset + limit) / component,
                             np.where(component < 0, (offset - limit) / component, np.inf))
        radius = np.minimum(radius, bound)
    a[1:4] = radius * np.sin(theta) - sin_prior
    a[4:7] = radius * np.cos(theta) - cos_prior
    return np.clip(a, -limit, limit)


def default_normalisation(observation: str) -> tuple[np.ndarray, np.ndarray]:
    """Observation mean and scale: velocities are O(1) m/s already; joint angles centre on the
    nominal pose (0, 0.9, -1.8) rad of each leg."""
    size = OBSERVATION_SIZES[observation]
    mean, std = np.zeros(size), np.ones(size)
    if observation == "extended":
        mean[9:21] = np.tile([0.0, 0.9, -1.8], 4)
        std[9:21] = 0.5
    return mean, std


class NetworkPolicy:
    """Observation -> GaitParams through the network; ``params`` is the flat vector trainers search."""

    def __init__(self, kind: str, observation: str, hidden_units: int, action: ActionConfig,
                 params: np.ndarray | None = None, obs_mean: np.ndarray | None = None,
                 obs_std: np.ndarray | None = None) -> None:
        self.kind, self.observation, self.hidden_units, self.action = kind, observation, hidden_units, action
        self.obs_size = OBSERVATION_SIZES[observation]
        default_mean, default_std = default_normalisation(observation)
        self.obs_mean = default_mean if obs_mean is None else np.asarray(obs_mean, dtype=float)
        self.obs_std = default_std if obs_std is None else np.asarray(obs_std, dtype=float)
        self.set_params(np.zeros(self.num_params) if params is None else params)

    @classmethod
    def from_config(cls, config: TrainConfig, params: np.ndarray | None = None) -> NetworkPolicy:
        p = config.policy
        return cls(p.kind, config.env.observation, p.hidden_units, p.action, params)

    @property
    def num_params(self) -> int:
        if self.kind == "linear":
            return ACTION_SIZE * (self.obs_size + 1)
        return self.hidden_units * (self.obs_size + 1) + ACTION_SIZE * (self.hidden_units + 1)

    def set_params(self, params: np.ndarray) -> None:
        params = np.asarray(params, dtype=float).reshape(-1)
        if params.size != self.num_params:
            raise ConfigError(f"params must have {self.num_params} entries for a {self.kind} policy "
                              f"({self.observation} observation, {self.hidden_units} hidden), got {params.size}")
        if not np.all(np.isfinite(params)):
            raise ConfigError("params must be finite")
        self.params = params.copy()
        o, h = self.obs_size, self.hidden_units
        if self.kind == "linear":
            self._layers = [(params[: ACTION_SIZE * o].reshape(ACTION_SIZE, o), params[ACTION_SIZE * o:])]
        else:
            w1_end = h * o
            b1_end = w1_end + h
            w2_end = b1_end + ACTION_SIZE * h
            self._layers = [(params[:w1_end].reshape(h, o), params[w1_end:b1_end]),
                            (params[b1_end:w2_end].reshape(ACTION_SIZE, h), params[w2_end:])]

    def raw_action(self, observation: np.ndarray) -> np.ndarray:
        """The 8 network outputs in (-1, 1) for one observation."""
        x = (np.asarray(observation, dtype=float) - self.obs_mean) / self.obs_std
        for w, b in self._layers:
            x = np.tanh(w @ x + b)
        return x

    def __call__(self, observation: np.ndarray) -> GaitParams:
        return decode_action(self.raw_action(observation), self.action)


def save_policy(path: str | os.PathLike, policy: NetworkPolicy, config: TrainConfig, iteration: int = 0) -> None:
    """Write the policy file atomically (temporary file in the same folder, then rename)."""
    path = Path(path)
    if path.suffix != ".npz":
        raise ConfigError(f"policy file name must end in .npz, got {path}")
    action = policy.action
    arrays = {
        "format_version": np.array(FORMAT_VERSION), "kind": np.array(policy.kind),
        "observation": np.array(policy.observation), "hidden_units": np.array(policy.hidden_units),
        "params": policy.params, "obs_mean": policy.obs_mean, "obs_std": policy.obs_std,
        "frequency_range": np.array(action.frequency_range, dtype=float),
        "swing_ratio_range": np.array(action.swing_ratio_range, dtype=float),
        "offset_prior": np.array(action.offset_prior, dtype=float),
        "offset_prior_weight": np.array(action.offset_prior_weight, dtype=float),
        "config_json": np.array(json.dumps(config.to_dict(), sort_keys=True)),
        "config_hash": np.array(config.policy_hash()), "iteration": np.array(iteration),
    }
    write_npz_atomically(path, arrays)


def policy_file(spec: str | os.PathLike) -> Path:
    """The file a policy spec names: ``learned`` is the shipped policy, anything else a path."""
    if str(spec) != SHIPPED_POLICY:
        return Path(spec)
    if not SHIPPED_POLICY_FILE.is_file():
        raise ConfigError(f"policy '{SHIPPED_POLICY}': the shipped policy file {SHIPPED_POLICY_FILE} is missing "
                          "(reinstall gait_policy_node, or pass a .npz from train_es)")
    return SHIPPED_POLICY_FILE


def remove_stale_temporaries(folder: Path) -> list[Path]:
    """Delete the temporary files write_npz_atomically left in ``folder``; returns them.

    A process killed mid-write (SIGKILL skips the cleanup above) leaves one behind, and the next
    writer's has another pid in its name, so nothing else would ever remove it. Only for a folder
    that one process writes at a time (a training run folder): a live writer's file would go too.
    """
    stale = sorted(folder.glob(f".*.npz{TEMPORARY_MARK}*"))
    for tmp in stale:
        tmp.unlink(missing_ok=True)
    return stale


def read_npz(path: str | os.PathLike, what: str = "file", max_bytes: int = MAX_NPZ_BYTES) -> dict[str, np.ndarray]:
    """All arrays of an ``.npz`` without pickle; unreadable, truncated or pickled files -> ConfigError.

    Read member by member with the .npy header checked first, so that neither a header claiming
    more data than its member holds nor more than ``max_bytes`` in all (uncompressed) can make
    this allocate memory it never fills; members that are not .npy arrays are refused.
    """
    try:
        with zipfile.ZipFile(path) as archive:
            infos = archive.infolist()
            total = sum(info.file_size for info in infos)
            if total > max_bytes:
                raise ValueError(f"{total} bytes uncompressed, more than the {max_bytes} allowed")
            arrays = {}
            for info in infos:
                key = info.filename.removesuffix(".npy")
                if key == info.filename or key in arrays:
                    raise ValueError(f"member {info.filename!r} is not a .npy array, or a duplicate")
                arrays[key] = _read_member(archive, info)
            return arrays
    except FileNotFoundError:
        raise ConfigError(f"{what} {path} does not exist") from None
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError, NotImplementedError, RuntimeError,
            zlib.error, struct.error) as exc:
        raise ConfigError(f"{what} {path} is not a readable .npz without pickled objects ({exc})") from None


def _read_member(archive: zipfile.ZipFile, info: zipfile.ZipInfo) -> np.ndarray:
    """One .npy member, its header checked against the member's size before any allocation."""
    with archive.open(info) as fh:
        version = np.lib.format.read_magic(fh)
        if version == (1, 0):
            shape, _, dtype = np.lib.format.read_array_header_1_0(fh)
        elif version == (2, 0):
            shape, _, dtype = np.lib.format.read_array_header_2_0(fh)
        else:
            raise ValueError(f"member {info.filename!r}: .npy format version {version} is not supported")
        if dtype.hasobject:
            raise ValueError(f"member {info.filename!r} holds pickled (object) data")
        if math.prod(shape) * dtype.itemsize > info.file_size - fh.tell():
            raise ValueError(f"member {info.filename!r} is truncated: its header announces {shape} {dtype}")
    with archive.open(info) as fh:
        return np.lib.format.read_array(fh, allow_pickle=False)


def _field(data: dict, key: str, path, kind: str, shape: tuple | None = None) -> np.ndarray:
    if key not in data:
        raise ConfigError(f"policy file {path}: missing '{key}'")
    value = data[key]
    if value.dtype.kind not in kind:
        raise ConfigError(f"policy file {path}: '{key}' has dtype {value.dtype}, expected kind '{kind}'")
    if shape is not None and value.shape != shape:
        raise ConfigError(f"policy file {path}: '{key}' has shape {value.shape}, expected {shape}")
    if value.dtype.kind in "fi" and not np.all(np.isfinite(value)):
        raise ConfigError(f"policy file {path}: '{key}' has non-finite values")
    return value


def load_policy(path: str | os.PathLike) -> tuple[NetworkPolicy, TrainConfig]:
    """Read and check a policy file (or the shipped one, ``learned``); returns the policy and the
    training config it was made with."""
    path = policy_file(path)
    data = read_npz(path, "policy file", MAX_POLICY_BYTES)
    version = int(_field(data, "format_version", path, "i", ()))
    if version != FORMAT_VERSION:
        raise ConfigError(f"policy file {path}: format_version {version}, this code reads {FORMAT_VERSION}")
    config_json = str(_field(data, "config_json", path, "U", ()))
    try:
        config = train_config_from_mapping(json.loads(config_json), "config_json")
    except ConfigError as exc:
        raise ConfigError(f"policy file {path}: {exc}") from None
    except json.JSONDecodeError as exc:
        raise ConfigError(f"policy file {path}: config_json is not JSON ({exc})") from None
    except RecursionError:
        raise ConfigError(f"policy file {path}: config_json is nested too deeply") from None
    stored_hash = str(_field(data, "config_hash", path, "U", ()))
    if stored_hash != config.policy_hash():
        raise ConfigError(f"policy file {path}: config_hash {stored_hash} does not match its config_json "
                          f"({config.policy_hash()}): the file was edited or corrupted")
    p = config.policy
    checks = {"kind": p.kind, "observation": config.env.observation}
    for key, expected in checks.items():
        if str(_field(data, key, path, "U", ())) != expected:
            raise ConfigError(f"policy file {path}: '{key}' does not match config_json ({expected!r})")
    if int(_field(data, "hidden_units", path, "i", ())) != p.hidden_units:
        raise ConfigError(f"policy file {path}: 'hidden_units' does not match config_json ({p.hidden_units})")
    for key in ("frequency_range", "swing_ratio_range", "offset_prior"):
        value = getattr(p.action, key)
        if not np.allclose(_field(data, key, path, "f", (len(value),)), value):
            raise ConfigError(f"policy file {path}: '{key}' does not match config_json ({list(value)})")
    if not math.isclose(float(_field(data, "offset_prior_weight", path, "f", ())), p.action.offset_prior_weight):
        raise ConfigError(f"policy file {path}: 'offset_prior_weight' does not match config_json")
    size = OBSERVATION_SIZES[config.env.observation]
    obs_mean = _field(data, "obs_mean", path, "f", (size,))
    obs_std = _field(data, "obs_std", path, "f", (size,))
    # Bounds far outside anything trained, inside which the network cannot overflow to NaN for the
    # observations the gait policy node feeds it (velocities clamped to 10 m/s).
    if np.any(obs_std < 1 / VALUE_BOUND) or np.any(obs_std > VALUE_BOUND):
        raise ConfigError(f"policy file {path}: 'obs_std' must be in [{1 / VALUE_BOUND:g}, {VALUE_BOUND:g}]")
    params = _field(data, "params", path, "f")
    for key, value in (("obs_mean", obs_mean), ("params", params)):
        if np.any(np.abs(value) > VALUE_BOUND):
            raise ConfigError(f"policy file {path}: '{key}' must be in [{-VALUE_BOUND:g}, {VALUE_BOUND:g}]")
    policy = NetworkPolicy(p.kind, config.env.observation, p.hidden_units, p.action, obs_mean=obs_mean,
                           obs_std=obs_std)
    try:
        policy.set_params(params)
    except ConfigError as exc:
        raise ConfigError(f"policy file {path}: {exc}") from None
    return policy, config
