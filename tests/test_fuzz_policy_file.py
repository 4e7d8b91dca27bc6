"""Property tests (hypothesis) of the learned-policy file loader: corrupt, truncated, edited and
pickled ``.npz`` files.

load_policy either returns a policy whose outputs are valid gait parameters for every observation
the gait policy node can feed it, or raises ConfigError naming the file (and the key where one is
at fault). Never another exception, never a large allocation driven by a forged header.
"""

from __future__ import annotations

import io
import json
import pickle
import warnings
import zipfile

import numpy as np
import pytest
from a1_common.config import ConfigError
from gait_policy_node.learned_policy import MAX_POLICY_BYTES, NetworkPolicy, load_policy, read_npz, save_policy
from gait_policy_node.train_config import train_config_from_mapping
from hypothesis import example, given
from hypothesis import strategies as st

CONFIG = train_config_from_mapping({"policy": {"hidden_units": 8}})
KEYS = ["format_version", "kind", "observation", "hidden_units", "params", "obs_mean", "obs_std",
        "frequency_range", "swing_ratio_range", "offset_prior", "offset_prior_weight", "config_json",
        "config_hash", "iteration"]
# Observations the node can produce: desired x within +-5 m/s, measured velocity within +-10 m/s per axis.
NODE_OBSERVATIONS = np.array([[0.0, 0.0, 0.0, 0.0], [5.0, 10.0, 10.0, 10.0], [-5.0, -10.0, 10.0, -10.0],
                              [2.5, 2.4, 0.1, 0.0], [5.0, -10.0, -10.0, 10.0]])


class _Bytes(bytes):
    def __repr__(self) -> str:  # keeps hypothesis' failure reports readable
        return f"<{len(self)} bytes of a valid policy file>"


@pytest.fixture(scope="module")
def valid_file(tmp_path_factory) -> bytes:
    policy = NetworkPolicy.from_config(CONFIG)
    policy.set_params(np.random.default_rng(0).normal(0, 0.3, policy.num_params))
    path = tmp_path_factory.mktemp("policy") / "valid.npz"
    save_policy(path, policy, CONFIG, iteration=3)
    return _Bytes(path.read_bytes())


@pytest.fixture(scope="module")
def scratch(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz_policy")


def arrays_of(data: bytes) -> dict[str, np.ndarray]:
    with np.load(io.BytesIO(data), allow_pickle=False) as npz:
        return {k: npz[k] for k in npz.files}


def npz_bytes(arrays: dict, compressed: bool = False) -> bytes:
    buf = io.BytesIO()
    (np.savez_compressed if compressed else np.savez)(buf, **arrays)
    return buf.getvalue()


def check_loads_or_refuses(path, fuzz_cases, target: str) -> None:
    try:
        policy, _ = load_policy(path)
    except ConfigError as exc:
        fuzz_cases[target]["refused"] += 1
        assert f"policy file {path}" in str(exc)
        return
    fuzz_cases[target]["loaded"] += 1
    for obs in NODE_OBSERVATIONS:
        params = policy(obs).validated()  # raises ConfigError if the output left the paper's ranges
        assert 0 < params.stepping_frequency <= 4


# --- byte-level damage -------------------------------------------------------------------------------
damage = st.one_of(
    st.tuples(st.just("truncate"), st.integers(0, 10_000), st.binary(max_size=0)),
    st.tuples(st.just("overwrite"), st.integers(0, 10_000), st.binary(min_size=1, max_size=8)),
    st.tuples(st.just("insert"), st.integers(0, 10_000), st.binary(min_size=1, max_size=8)),
    st.tuples(st.just("replace"), st.just(0), st.binary(max_size=200)),
)


@given(damages=st.lists(damage, min_size=1, max_size=3))
@example(damages=[("truncate", 1000, b"")])
@example(damages=[("truncate", 0, b"")])  # an empty file
@example(damages=[("replace", 0, pickle.dumps({"params": [0.0] * 10}))])  # a plain pickle
@example(damages=[("overwrite", 600, b"\xff" * 8)])  # inside a member: CRC mismatch
def test_damaged_bytes_are_refused_or_harmless(valid_file, scratch, fuzz_cases, damages):
    data = bytearray(valid_file)
    for kind, at, payload in damages:
        at = min(at, len(data))
        if kind == "truncate":
            del data[at:]
        elif kind == "overwrite":
            data[at:at + len(payload)] = payload
        elif kind == "insert":
            data[at:at] = payload
        else:
            data = bytearray(payload)
    path = scratch / "damaged.npz"
    path.write_bytes(bytes(data))
    check_loads_or_refuses(path, fuzz_cases, "policy file, damaged bytes")


# --- well-formed .npz files with hostile content --------------------------------------------------------
hostile_arrays = st.one_of(
    st.builds(np.array, st.floats(allow_nan=True, allow_infinity=True)),
    st.builds(np.array, st.integers(-2**63, 2**63 - 1)),
    st.builds(np.array, st.text(max_size=20)),
    st.builds(np.array, st.booleans()),
    st.lists(st.floats(), min_size=0, max_size=12).map(lambda v: np.array(v, dtype=float)),
    st.lists(st.floats(-1e7, 1e7), min_size=1, max_size=12).map(lambda v: np.array(v, dtype=float)),
    st.sampled_from([np.zeros((2, 2)), np.zeros(0), np.array(b"bytes"), np.array([1 + 2j]),
                     np.zeros(4, dtype=np.float32), np.array([1e-300] * 4), np.array([1e300] * 4)]),
)


@given(key=st.sampled_from([*KEYS, "extra_key"]), value=st.none() | hostile_arrays, compressed=st.booleans())
@example(key="obs_std", value=np.array([1e-300] * 4), compressed=False)  # makes the network overflow
@example(key="params", value=None, compressed=False)
@example(key="format_version", value=np.array(2), compressed=True)
@example(key="config_json", value=np.array("[" * 100_000), compressed=True)  # JSON nested too deeply
def test_hostile_members_are_refused_naming_the_key(valid_file, scratch, fuzz_cases, key, value, compressed):
    arrays = arrays_of(valid_file)
    if value is None:
        arrays.pop(key, None)
    else:
        arrays[key] = value
    path = scratch / "edited.npz"
    path.write_bytes(npz_bytes(arrays, compressed))
    try:
        load_policy(path)
    except ConfigError as exc:
        fuzz_cases["policy file, edited member"]["refused"] += 1
        assert f"policy file {path}" in str(exc)
        if key in KEYS and key not in ("config_json", "config_hash"):  # (those two name each other)
            assert key in str(exc), str(exc)
        return
    fuzz_cases["policy file, edited member"]["loaded"] += 1
    check_loads_or_refuses(path, fuzz_cases, "policy file, edited member (loaded twice)")


@given(section=st.sampled_from(["policy", "env", "reward"]),
       key=st.sampled_from(["hidden_units", "kind", "observation", "frequency_range", "action", "junk"]),
       value=st.one_of(st.integers(-10, 10_000), st.floats(), st.text(max_size=8), st.none(),
                       st.lists(st.floats(), max_size=3)))
def test_edited_training_config_in_the_file_is_refused(valid_file, scratch, fuzz_cases, section, key, value):
    """config_json edited and its hash recomputed to match: the content itself must be checked."""
    arrays = arrays_of(valid_file)
    edited = json.loads(str(arrays["config_json"]))
    edited.setdefault(section, {})[key] = value
    arrays["config_json"] = np.array(json.dumps(edited))
    try:
        config = train_config_from_mapping(json.loads(json.dumps(edited)))
        arrays["config_hash"] = np.array(config.policy_hash())
    except ConfigError:
        pass
    path = scratch / "config.npz"
    path.write_bytes(npz_bytes(arrays))
    check_loads_or_refuses(path, fuzz_cases, "policy file, edited config_json")


# --- forged headers: no allocation beyond what the file holds ----------------------------------------------
def _zip_with_member(name: str, npy: bytes, compress: int = zipfile.ZIP_STORED) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=compress) as zf:
        zf.writestr(name, npy)
    return buf.getvalue()


def _npy_header(shape, descr="<f8") -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": descr, "fortran_order": False, "shape": shape})
    return buf.getvalue()


@given(shape=st.lists(st.integers(0, 2**40), min_size=1, max_size=3).map(tuple), pad=st.integers(0, 64))
@example(shape=(10**12,), pad=16)  # 7 TiB announced, 16 bytes present
def test_a_header_announcing_more_data_than_present_is_refused_without_allocating(scratch, fuzz_cases, shape, pad):
    path = scratch / "forged.npz"
    path.write_bytes(_zip_with_member("params.npy", _npy_header(shape) + b"\0" * pad))
    try:
        arrays = read_npz(path)
    except ConfigError as exc:
        fuzz_cases["policy file, forged .npy header"]["refused"] += 1
        assert str(path) in str(exc)
        return
    fuzz_cases["policy file, forged .npy header"]["read"] += 1
    assert arrays["params"].nbytes <= pad


@pytest.mark.parametrize("content", ["object_array", "raw_member", "plain_npy", "bomb", "duplicate"])
def test_not_an_array_archive_is_refused(scratch, content):
    path = scratch / f"{content}.npz"
    if content == "object_array":  # np.save pickles object arrays
        buf = io.BytesIO()
        np.save(buf, np.array([{"evil": 1}], dtype=object), allow_pickle=True)
        path.write_bytes(_zip_with_member("params.npy", buf.getvalue()))
    elif content == "raw_member":  # a member without the .npy magic
        path.write_bytes(_zip_with_member("format_version.npy", b"junk"))
    elif content == "plain_npy":  # a .npy, not an archive
        buf = io.BytesIO()
        np.save(buf, np.zeros(3))
        path.write_bytes(buf.getvalue())
    elif content == "bomb":  # compresses to a few hundred kB, unpacks beyond the policy limit
        buf = io.BytesIO()
        np.save(buf, np.zeros(MAX_POLICY_BYTES // 8 + 1))
        path.write_bytes(_zip_with_member("params.npy", buf.getvalue(), zipfile.ZIP_DEFLATED))
    else:
        buf = io.BytesIO()
        with zipfile.ZipFile(buf, "w") as zf, warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # zipfile warns about the duplicate it writes
            for _ in range(2):
                zf.writestr("params.npy", _npy_header((0,)))
        path.write_bytes(buf.getvalue())
    with pytest.raises(ConfigError, match=r"policy file .*not a readable \.npz"):
        load_policy(path)
