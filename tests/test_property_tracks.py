"""Issue 15, property-based: a tracks file mutated at random (keys deleted, wrong types, NaN and
infinity as numbers, as strings and as overflowing literals, lists truncated or lengthened,
visibility flipped to odd values, integers too long for a float) given to `galileo infer` (in-process, 1 chain of 1 sweep)
gives either a clean refusal, exit code 2 and exactly one stderr line `galileo: error: ...`,
with no result written, or a valid run, exit code 0 and a result whose every number is
finite. Never a traceback, never a NaN in an output.

Examples are derandomized (the same ones every run, so that the suite does not flake);
GALILEO_HYPOTHESIS_EXAMPLES=N GALILEO_HYPOTHESIS_RANDOM=1 explores N fresh ones."""
import contextlib
import copy
import io
import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import DATA
from galileo.cli import main

SCENE = DATA / "scene.json"
BASE = json.loads((DATA / "tracks.json").read_text())
N_FRAMES = len(BASE["time_s"])
EXAMPLES = int(os.environ.get("GALILEO_HYPOTHESIS_EXAMPLES", "100"))
RANDOM = os.environ.get("GALILEO_HYPOTHESIS_RANDOM") == "1"

# written into the JSON text unquoted: Python's json reads 1e400 as inf, and NaN / Infinity
# as themselves (JSON has neither; a hand-edited or foreign file may still hold them)
LITERALS = {"@inf@": "1e400", "@-inf@": "-1e400", "@nan@": "NaN", "@infinity@": "Infinity", "@bigint@": "1" + "0" * 400,
            "@-bigint@": "-1" + "0" * 400}

ODD = ["nan", "NaN", "inf", "-inf", "Infinity", "1e400", "yes", "no", "true", "false", "", "0", "1.5", None, True,
       False, 0, 1, -1, 0.0, 1.5, -0.5, 1e308, -1e308, 1e-320, 10**30, math.nan, math.inf, -math.inf, [], {}, [1, 2],
       [0.1, 0.1, 0.1], [0.1, 0.1, 0.1, 0.1], {"a": 1}, "box", "cone", *LITERALS]
VISIBILITY = [True, False, "true", "false", "yes", "no", 0, 1, None, 0.5, "", [], "True"]


def locations(draw) -> list:
    """A path into the tracks document, biased towards the places a tracks file holds."""
    kind = draw(st.sampled_from(["top", "object", "shape", "size", "visible", "row", "component", "time"]))
    i = draw(st.integers(0, 1))
    f = draw(st.integers(0, N_FRAMES - 1))
    if kind == "top":
        return [draw(st.sampled_from(["fps", "time_s", "objects", "notes"]))]
    if kind == "object":
        return ["objects", i, draw(st.sampled_from(["name", "role", "visible", "position_m", "velocity_mps", "shape",
                                                    "offset_units", "detected_by", "bottom_up"]))]
    if kind == "shape":
        return ["objects", i, "shape", draw(st.sampled_from(["type", "size_m"]))]
    if kind == "size":
        return ["objects", i, "shape", "size_m", draw(st.integers(0, 2))]
    if kind == "visible":
        return ["objects", i, "visible", f]
    if kind == "row":
        return ["objects", i, draw(st.sampled_from(["position_m", "velocity_mps"])), f]
    if kind == "component":
        return ["objects", i, draw(st.sampled_from(["position_m", "velocity_mps"])), f, draw(st.integers(0, 2))]
    return ["time_s", f]


def resolve(doc, path, create: bool = False):
    """(container, key) of path in doc, or None where the path no longer exists (with `create`,
    a key a dictionary lacks is there to be set)."""
    node = doc
    for k in path[:-1]:
        try:
            node = node[k]
        except (KeyError, IndexError, TypeError):
            return None
    key = path[-1]
    if (isinstance(node, dict) and (key in node or create)) or (
            isinstance(node, list) and isinstance(key, int) and key < len(node)):
        return node, key
    return None


@st.composite
def mutation(draw):
    """(description, function mutating the document in place)."""
    op = draw(st.sampled_from(["delete", "set", "truncate", "extend", "visibility", "hide_all", "hide_frames",
                               "number"]))
    path = locations(draw)
    value = draw(st.sampled_from(ODD))
    cut = draw(st.integers(0, N_FRAMES + 2))
    vis = draw(st.sampled_from(VISIBILITY))
    number = draw(st.floats(-5.0, 5.0, allow_nan=False))
    i = draw(st.integers(0, 1))
    span = sorted(draw(st.lists(st.integers(0, N_FRAMES), min_size=2, max_size=2)))

    def apply(doc):
        if op == "hide_frames":  # frames an object was not seen in (valid: rows null, or left and ignored)
            o = resolve(doc, ["objects", i])
            o = o[0][o[1]] if o is not None else None
            if isinstance(o, dict) and isinstance(o.get("visible"), list):
                for f in range(*span):
                    if f < len(o["visible"]):
                        o["visible"][f] = False
                        if isinstance(o.get("velocity_mps"), list) and f < len(o["velocity_mps"]) and value is None:
                            o["velocity_mps"][f] = None
            return
        if op == "hide_all":     # an object (or all) never seen
            for o in (doc.get("objects") or [])[i:] if isinstance(doc.get("objects"), list) else []:
                if isinstance(o, dict) and isinstance(o.get("visible"), list):
                    o["visible"] = [False] * len(o["visible"])
            return
        if op == "visibility":   # a frame's visibility (or the whole list) to an odd value
            where = resolve(doc, ["objects", i, "visible", path[-1] if isinstance(path[-1], int) else 0])
            if where is not None:
                where[0][where[1]] = vis
            return
        where = resolve(doc, path, create=op in ("set", "number"))
        if where is None:
            return
        node, key = where
        if op == "delete":
            if isinstance(node, dict):
                node.pop(key, None)
            else:
                del node[key]
        elif op == "set":
            node[key] = copy.deepcopy(value)
        elif op == "number":     # a plausible number where any value was
            node[key] = number
        elif op == "truncate" and isinstance(node[key], list):
            node[key] = node[key][:cut]
        elif op == "extend" and isinstance(node[key], list):
            node[key] = node[key] + [copy.deepcopy(node[key][-1] if node[key] else value)]
        elif op in ("truncate", "extend"):
            node[key] = copy.deepcopy(value)
    return f"{op} {path} {value!r}/{vis!r}/{number}/{cut}", apply


def text_of(doc) -> str:
    text = json.dumps(doc, allow_nan=True)
    for mark, literal in LITERALS.items():
        text = text.replace(json.dumps(mark), literal)
    return text


def finite_json(text: str) -> bool:
    """Every number in the JSON text is finite (NaN / Infinity tokens and overflowing literals
    included)."""
    bad = []

    def constant(name):
        bad.append(name)
        return 0.0

    def walk(x):
        if isinstance(x, float):
            return math.isfinite(x)
        if isinstance(x, dict):
            return all(walk(v) for v in x.values())
        if isinstance(x, list):
            return all(walk(v) for v in x)
        return True

    return walk(json.loads(text, parse_constant=constant)) and not bad


def run_infer(folder: Path, tracks_text: str) -> tuple[int, str, str, Path]:
    tracks, out = folder / "tracks.json", folder / "result.json"
    tracks.write_text(tracks_text)
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        rc = main(["infer", str(folder / "unused.mp4"), "--scene", str(SCENE), "--tracks", str(tracks),
                   "--chains", "1", "--sweeps", "1", "--workers", "1", "--out", str(out), "--quiet"])
    return rc, stdout.getvalue(), stderr.getvalue(), out


def check_outcome(rc: int, stderr: str, out: Path, what: str) -> None:
    lines = stderr.strip().splitlines()
    if rc == 2:
        assert len(lines) == 1 and lines[0].startswith("galileo: error: "), (what, stderr)
        assert not out.exists(), what
        return
    assert rc == 0, (what, rc, stderr)
    assert all(line.startswith("galileo: warning: ") for line in lines), (what, stderr)
    assert finite_json(out.read_text()), (what, "a number in the result is not finite")
    d = json.loads(out.read_text())
    with np.load(out.with_name(d["samples_file"]), allow_pickle=False) as z:
        for k in z.files:
            if np.issubdtype(z[k].dtype, np.floating):
                assert np.isfinite(z[k]).all() or k.startswith("proposal_"), (what, k)


@settings(max_examples=EXAMPLES, deadline=None, database=None, derandomize=not RANDOM,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(st.lists(mutation(), min_size=1, max_size=3))
def test_a_mutated_tracks_file_is_refused_in_one_line_or_infers_finitely(mutations):
    doc = copy.deepcopy(BASE)
    for _, apply in mutations:
        apply(doc)
    what = "; ".join(m[0] for m in mutations)
    with tempfile.TemporaryDirectory(prefix="galileo-prop-") as folder:
        rc, _, stderr, out = run_infer(Path(folder), text_of(doc))
        check_outcome(rc, stderr, out, what)


def test_the_unmutated_tracks_infer_finitely(tmp_path):
    rc, stdout, stderr, out = run_infer(tmp_path, json.dumps(BASE))
    assert rc == 0 and stdout.startswith("MAP: "), stderr
    check_outcome(rc, stderr, out, "unmutated")
