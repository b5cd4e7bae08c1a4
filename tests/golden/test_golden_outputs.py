"""Golden outputs of the per-instant path (group -> associate -> tracks -> fuse -> encode), pinned so that a
change meant only to make the path faster cannot change its results: the same inputs must give the same persons
(ids, counts, which body went to which track, contributors, n_agree, confidence identical) and the same numbers
(positions, orientations and position_std within 1e-9), through the people path (GroupFuser) and through the
node's fusion step (FusionCore.receive on encoded payloads, the published payloads decoded).

The takes' inputs are stored in the golden file beside the outputs (numpy's sin and cos differ in the last bits
between processors, so a rebuilt take is not bit-identical); the builder and runners are in
``tests/golden/golden_takes.py``. When a change is MEANT to change the outputs
(e.g. a fix of association or tracks), regenerate the file and say so in the commit::

    python scripts/make_golden_outputs.py
"""

from __future__ import annotations

import numpy as np
import pytest
from golden_takes import GOLDEN_PATH, TAKES, build_take, builder_drift, run_node, run_people, stored_take

EXACT = ("time_us", "n_persons", "track_ids", "n_agree", "confidence", "contributors")
MEMBERSHIPS = ("assignment", "body_track_ids", "coasting")
CLOSE = ("positions", "orientations", "position_std")
ATOL = 1e-9  # mm for positions and position_std; unit quaternion components for orientations


@pytest.fixture(scope="module")
def golden() -> dict[str, np.ndarray]:
    with np.load(GOLDEN_PATH) as data:
        return {key: data[key] for key in data.files}


def _check(name: str, got: dict[str, np.ndarray], golden: dict[str, np.ndarray], fields: tuple[str, ...]) -> None:
    for key in fields:
        want = golden[f"{name}/{key}"]
        if key in CLOSE:
            assert got[key].shape == want.shape, (name, key, got[key].shape, want.shape)
            np.testing.assert_allclose(got[key], want, rtol=0, atol=ATOL, equal_nan=True, err_msg=f"{name}/{key}")
        else:
            np.testing.assert_array_equal(got[key], want, err_msg=f"{name}/{key}")


@pytest.mark.parametrize("name", list(TAKES))
def test_people_path_and_node_step_reproduce_the_golden_outputs(name: str, golden: dict[str, np.ndarray]) -> None:
    take = stored_take(name, golden)
    assert golden[f"{name}/n_persons"].sum() > 0 and np.isfinite(golden[f"{name}/positions"]).any()
    people = run_people(take)
    _check(name, people, golden, EXACT + MEMBERSHIPS + CLOSE)
    node = run_node(take)
    _check(name, node, golden, EXACT + CLOSE)


@pytest.mark.parametrize("name", list(TAKES))
def test_the_take_builder_still_makes_the_stored_inputs(name: str, golden: dict[str, np.ndarray]) -> None:
    # The outputs are checked on the stored inputs; this says whether golden_takes.py (the crowd, the rig, the
    # seeded noise) still builds them, up to the processor's rounding. If a change there was meant, regenerate.
    drift = builder_drift(build_take(name), stored_take(name, golden))
    assert drift == [], f"golden take {name}: the builder now makes other {drift}; regenerate if that was meant"
