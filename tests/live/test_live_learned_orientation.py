"""Live targets of a model that learned orientations and timing carry the model's orientation
and a feed-forward velocity (the bridge serves the canal's whole tracker geometry, as
``Canal.tracker`` does), not the pose's own orientation."""

from __future__ import annotations

import numpy as np
import pytest
from canal_client.live import PoseStreamer
from live_helpers import arc
from scipy.spatial.transform import Rotation

import canal_core

pytestmark = pytest.mark.timeout(60)


@pytest.fixture(scope="module")
def turning(live):
    """A skill whose demos turn 90 degrees about z along the arc, over 3 s."""
    client = live.client
    r = client.post("/skills", json={"name": "turn3", "dim": 3})
    assert r.status_code == 201, r.text
    for j in range(4):
        positions = arc(j)
        n = len(positions)
        quats = Rotation.from_euler("z", np.linspace(0.0, np.pi / 2, n)[:, None]).as_quat()
        r = client.post("/skills/turn3/demonstrations", json={
            "positions": positions.tolist(), "orientations": quats.tolist(),
            "timestamps": np.linspace(0.0, 3.0, n).tolist()})
        assert r.status_code == 201, r.text
    r = client.post("/skills/turn3/fit", json={"n_samples": 100})
    assert r.status_code == 201, r.text
    body = client.get("/skills/turn3/models/latest", params={"serialized": True}).json()
    canal = canal_core.Canal.from_dict(body["serialized"])
    assert canal.orientation is not None and canal.section_times is not None
    return canal


@pytest.mark.parametrize("encoding", ["json", "binary"])
def test_targets_carry_the_models_orientation_and_velocity(live, turning, encoding):
    canal = turning
    identity = (0.0, 0.0, 0.0, 1.0)
    with PoseStreamer("turn3", f"learned-{encoding}", endpoint=live.endpoint,
                      encoding=encoding) as ps:
        answer = ps.wait_for(ps.send(canal.directrix[70], identity, restart=True), 2.0)
    assert answer is not None and answer.status == "ok", answer
    assert answer.orientation is not None
    # the model's orientation at the target's section (a few sections ahead of the robot's:
    # the tracker's lookahead), about 70 degrees about z here, not the identity the robot sent
    got = Rotation.from_quat(answer.orientation)
    ahead = canal.orientation.means[answer.section:answer.section + 6]
    angle_to_model = min((got.inv() * Rotation.from_quat(q)).magnitude() for q in ahead)
    angle_to_pose = got.magnitude()
    assert angle_to_model < 1e-6, (answer.orientation, ahead)
    assert angle_to_pose > np.radians(45), answer.orientation
    # timing learned: a feed-forward velocity along the canal's direction of travel
    assert answer.velocity is not None
    velocity = np.asarray(answer.velocity)
    assert float(velocity @ canal.tangents[answer.section]) > 0.0
