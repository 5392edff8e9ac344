"""Property-based fuzzing of the readers: random truncations, byte flips and structural mutations of
valid files. Whatever the damage, a reader returns a valid result or raises its one deliberate error
(DataError for data files, ProfileError for profiles); never another exception, never a hang."""

from __future__ import annotations

import json
import time

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from weldcell.plugins.handeye.samples_io import read_samples
from weldcell.plugins.scan_plan.scans_io import load_posed_scans
from weldcell.sdk.cloud import load_cloud_file
from weldcell.sdk.errors import DataError, ProfileError
from weldcell.sdk.profile import load_profile

from .test_bad_clouds import GOOD_PCD, GOOD_PLY, PTS, pcd_ascii, ply_ascii
from .test_bad_handeye_files import base_doc as samples_doc

FUZZ = settings(
    max_examples=int(__import__("os").environ.get("WELDCELL_FUZZ_EXAMPLES", "40")),
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
BASES = {"a.ply": GOOD_PLY, "b.ply": ply_ascii(), "c.pcd": GOOD_PCD, "d.pcd": pcd_ascii()}


@st.composite
def damaged(draw, data: bytes):
    """``data`` cut short, with bytes overwritten, a header digit changed, or bytes inserted."""
    kind = draw(st.sampled_from(["cut", "flip", "digit", "insert"]))
    b = bytearray(data)
    if kind == "cut":
        return bytes(b[: draw(st.integers(0, len(b) - 1))])
    if kind == "flip":
        for _ in range(draw(st.integers(1, 8))):
            # most flips land in the header, where they change what the body must be
            i = draw(st.integers(0, min(len(b) - 1, 400) if draw(st.booleans()) else len(b) - 1))
            b[i] = draw(st.integers(0, 255))
        return bytes(b)
    if kind == "digit":
        digits = [i for i, c in enumerate(b[:400]) if chr(c).isdigit()]
        b[draw(st.sampled_from(digits))] = ord(str(draw(st.integers(0, 9))))
        return bytes(b)
    i = draw(st.integers(0, len(b)))
    return bytes(b[:i]) + draw(st.binary(min_size=1, max_size=40)) + bytes(b[i:])


@FUZZ
@given(st.sampled_from(sorted(BASES)).flatmap(lambda n: st.tuples(st.just(n), damaged(BASES[n]))))
def test_damaged_clouds_are_read_whole_or_refused(tmp_path_factory, case):
    name, data = case
    f = tmp_path_factory.mktemp("fuzz") / name
    f.write_bytes(data)
    t0 = time.perf_counter()
    try:
        cloud = load_cloud_file(f)
    except DataError as e:
        assert e.fix and "\n" not in e.message
    else:
        # accepted: then it holds every declared point (a flipped byte in the data may move one)
        assert len(cloud) == len(PTS)
    assert time.perf_counter() - t0 < 10.0


JSON_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers(-(10**6), 10**6) | st.floats() | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=6), inner, max_size=4),
    max_leaves=12,
)


@st.composite
def mutated_json(draw, doc):
    """``doc`` with one node (at a random path) replaced by a random JSON value, or a key renamed."""
    doc = json.loads(json.dumps(doc))
    parent, key = None, None
    node = doc
    for _ in range(draw(st.integers(0, 4))):
        if isinstance(node, dict) and node:
            k = draw(st.sampled_from(sorted(node)))
        elif isinstance(node, list) and node:
            k = draw(st.integers(0, len(node) - 1))
        else:
            break
        parent, key, node = node, k, node[k]
    if parent is None:
        return draw(JSON_VALUES) if draw(st.booleans()) else doc
    if isinstance(parent, dict) and draw(st.booleans()):
        parent[key + draw(st.sampled_from(["_", "s", "x"]))] = parent.pop(key)  # a misspelt key
    else:
        parent[key] = draw(JSON_VALUES)
    return doc


@FUZZ
@given(mutated_json(samples_doc()))
def test_mutated_samples_files_are_read_or_refused(tmp_path_factory, doc):
    f = tmp_path_factory.mktemp("fuzz") / "samples.json"
    f.write_text(json.dumps(doc))
    try:
        ss = read_samples(f)
    except DataError as e:
        assert e.fix and e.message
    else:
        for s in ss.samples:
            assert s.T_base_flange is None or np.all(np.isfinite(s.T_base_flange))


SCANS = {
    "schema": "weldcell/posed-scans@1",
    "units": "m",
    "roi_min": [0, 0, 0],
    "scans": [{"cloud": "000.ply", "T_base_flange": np.eye(4).tolist(), "stamp": 0.0}],
}


@FUZZ
@given(mutated_json(SCANS))
def test_mutated_scan_lists_are_read_or_refused(tmp_path_factory, doc):
    d = tmp_path_factory.mktemp("fuzz")
    (d / "000.ply").write_bytes(GOOD_PLY)
    (d / "scans.json").write_text(json.dumps(doc))
    try:
        data = load_posed_scans(d)
    except DataError as e:
        assert e.fix and e.message
    else:
        assert all(isinstance(s.timestamp, float) and np.isfinite(s.timestamp) for s in data.scans)


PROFILE = b"""schema = "weldcell/profile@1"
name = "fuzz"
extends = "base.toml"
[job]
name = "scan-and-plan"
[job.settings]
max_captures = 4
[devices.robot]
plugin = "robot.sim"
"""


@FUZZ
@given(damaged(PROFILE))
def test_damaged_profiles_load_or_are_refused(tmp_path_factory, data):
    d = tmp_path_factory.mktemp("fuzz")
    (d / "base.toml").write_bytes(b'name = "base"\n')
    (d / "p.toml").write_bytes(data)
    try:
        load_profile(d / "p.toml")
    except ProfileError as e:
        assert e.fix and e.message
