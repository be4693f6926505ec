"""Corrections and steering over a real Zenoh session: a person pushes or steers, the canal learns."""

from __future__ import annotations

import itertools
import threading
import time
from typing import Any

import numpy as np
import pytest
from canal_client import ArgumentError
from canal_client.live import LiveError, PoseStreamer, query_json
from live_helpers import make_skill, wait_until

import canal_core
from canal_core.steering import STEER_TIMEOUT_S, steering_axes
from canal_protocol import wire

pytestmark = pytest.mark.timeout(90)


def canal_of(live: Any, skill: str) -> canal_core.Canal:
    body = live.client.get(f"/skills/{skill}/models/latest", params={"serialized": True}).json()
    return canal_core.Canal.from_dict(body["serialized"])


class Robot:
    """An ideal robot on its own stream: it moves to each target it gets, at ``rate_hz``,
    and keeps every answer (to check that each pose is answered once, in order)."""

    def __init__(self, live: Any, skill: str, name: str, encoding: str = "binary") -> None:
        self.answers: list[wire.Target] = []
        self.ps = PoseStreamer(skill, name, endpoint=live.endpoint, encoding=encoding,
                               on_target=self.answers.append)
        self.sent = 0

    def run(self, start: np.ndarray, rate_hz: float, steps: int,
            held: np.ndarray | None = None, during: Any = None) -> np.ndarray:
        """Send ``steps`` poses; the position follows the latest target, or, where a person
        holds the arm, is ``held[k]`` (rows of NaN: not held)."""
        position = np.array(start, dtype=np.float64)
        path = []
        period = 1.0 / rate_hz
        next_at = time.perf_counter()
        for k in range(steps):
            if during is not None:
                during(k)
            self.ps.send(position.tolist())
            self.sent += 1
            path.append(position.copy())
            next_at += period
            time.sleep(max(next_at - time.perf_counter(), 0.0))
            latest = self.ps.latest()
            if latest is not None and latest.target is not None:
                position = np.array(latest.target)
            if held is not None and k + 1 < len(held) and not np.isnan(held[k + 1, 0]):
                position = held[k + 1].copy()
        return np.array(path)

    def all_answered_in_order(self, timeout: float = 5.0) -> bool:
        """Every pose sent is answered, in order, or counted as coalesced by the bridge (its
        overload policy when this shared machine stalls it: the newest pose of a backlog is
        answered, and the answer counts the ones skipped). None is lost silently."""
        wait_until(lambda: self.answers and len(self.answers) + self.answers[-1].coalesced
                   >= self.sent, timeout)
        seqs = [a.seq for a in self.answers]
        in_order = all(b is not None and a is not None and b > a for a, b in itertools.pairwise(seqs))
        skipped = self.answers[-1].coalesced if self.answers else 0
        return in_order and seqs[-1] == self.sent - 1 and len(seqs) + skipped == self.sent

    def close(self) -> None:
        self.ps.close()


@pytest.fixture(scope="module")
def corrected_skill(live: Any) -> str:
    make_skill(live.client, "press", 3)
    return "press"


def test_a_push_captured_live_becomes_an_exclude_and_streams_switch_in_place(
    live: Any, corrected_skill: str
) -> None:
    skill = corrected_skill
    canal = canal_of(live, skill)
    n = canal.n_sections
    before = live.client.get(f"/skills/{skill}/models/latest").json()["version"]
    pusher, other = Robot(live, skill, "pushed"), Robot(live, skill, "bystander", "json")
    try:
        # The bystander runs through the whole correction at 500 Hz.
        other_start = canal.directrix[2] - 0.3 * canal.radii[2] * canal.normals[2]
        bystander = threading.Thread(target=other.run, args=(other_start, 500.0, 700))
        bystander.start()
        # A person guides the arm along its own run and pushes it off the +normal wall
        # mid-way, by up to 40 % of the canal's radius.
        start = canal.directrix[5] + 0.8 * canal.radii[5] * canal.normals[5]
        run = canal.reproduce_detailed(start, persistence="constant", entry=0.0, end_decay=0.0).positions
        k = np.arange(run.shape[0])
        sec = np.clip(5 + k, 0, n - 1)
        bump = 0.4 * canal.radii[sec] * np.exp(-0.5 * ((k - 40) / 8.0) ** 2)
        held = run - bump[:, None] * canal.normals[sec]
        pusher.ps.start_correction("exclude", label="keep off the wall")
        pusher.run(start, 200.0, len(held), held)
        made = pusher.ps.stop_correction()
        bystander.join(30)
        assert made["version"] == before + 1 and made["parent_version"] == before
        assert made["correction"]["kind"] == "exclude" and made["corrections"] == [made["correction"]["id"]]
        assert other.all_answered_in_order() and pusher.all_answered_in_order()
        # The bystander switched to the new version at the section it had reached.
        versions = [a.model_version for a in other.answers]
        switched = [i for i in range(1, len(versions)) if versions[i] != versions[i - 1]]
        if switched:  # it may have finished before the new version landed
            i = switched[0]
            assert versions[i] == made["version"]
            sections = [a.section for a in other.answers]
            assert sections[i] >= sections[i - 1] - 1
        assert live.metric("canal_corrections_total", 'kind="exclude"') >= 1
        # The pusher's next run from the same start keeps off the side it was pushed from.
        refined = canal_of(live, skill)
        assert refined.corrections and refined.corrections[-1].correction.kind == "exclude"
    finally:
        pusher.close()
        other.close()


def test_live_correction_errors_name_the_field(live: Any, corrected_skill: str) -> None:
    with PoseStreamer(corrected_skill, "careless", endpoint=live.endpoint) as ps:
        with pytest.raises(LiveError, match=r'kind.*got "sideways"'):  # as JSON, as over REST
            ps.start_correction("sideways")
        with pytest.raises(LiveError, match="no correction"):
            ps.stop_correction()
        ps.start_correction("include")
        ps.send([50.0, 50.0, 50.0])
        ps.send([51.0, 50.0, 50.0])
        with pytest.raises(LiveError, match="samples"):
            ps.stop_correction()  # too short, and far from the canal


def test_a_weight_that_cannot_be_kept_is_refused_before_the_push(live: Any, corrected_skill: str) -> None:
    # A weight over the service's bound used to be accepted at correction/start and refused
    # only at stop, after the person had pushed the robot; a NaN weight went over the wire as
    # null, so steer/keep stored the default weight instead of what was asked.
    versions = live.client.get(f"/skills/{corrected_skill}/models").json()["total"]
    with PoseStreamer(corrected_skill, "heavy", endpoint=live.endpoint) as ps:
        with pytest.raises(LiveError, match=r"weight.*\(0, 1000\].*5000"):
            ps.start_correction("include", weight=5000.0)
        with pytest.raises(LiveError, match=r"weight.*got 0"):
            ps.start_correction("include", weight=0)
        # and a label a correction cannot keep (a demonstration's may be longer)
        with pytest.raises(LiveError, match=r"label.*at most 200"):
            ps.start_correction("include", label="x" * 230)
        for bad in (float("nan"), float("inf")):
            with pytest.raises(ArgumentError, match=r"^weight: expected a finite number, got (nan|inf)$"):
                ps.start_correction("include", weight=bad)
            with pytest.raises(ArgumentError, match=r"^weight: expected a finite number"):
                ps.keep_steered(weight=bad)
        with pytest.raises(LiveError, match="no correction"):
            ps.stop_correction()  # nothing was started
        # null is the default weight, as for every optional field of a live body
        started = query_json(ps.session, ps.keys.correction_start, {"kind": "include", "weight": None})
        assert started["capturing"] is True, started
    assert live.client.get(f"/skills/{corrected_skill}/models").json()["total"] == versions


def test_a_live_body_with_a_field_it_does_not_take_is_refused(live: Any, corrected_skill: str) -> None:
    # A misspelt field ("wieght") used to be left alone: the correction was captured with
    # the default weight and the person never told. Over REST the same body is a 422.
    versions = live.client.get(f"/skills/{corrected_skill}/models").json()["total"]
    with PoseStreamer(corrected_skill, "typist", endpoint=live.endpoint) as ps:
        for key, body, allowed in (
                (ps.keys.correction_start, {"kind": "include", "wieght": 5},
                 "kind, weight, label, from_seq"),
                (ps.keys.demo_start, {"lable": "pour"}, "from_seq, label"),
                (ps.keys.demo_stop, {"last": 3}, "last_seq"),
                (ps.keys.correction_stop, {"last_seq": 3, "kind": "include"}, "last_seq"),
                (ps.keys.steer_keep, {"label": "ok", "weight": 2, "kind": "include"},
                 "label, weight")):
            bad = next(k for k in body if k not in allowed.split(", "))
            with pytest.raises(LiveError, match=rf"expected only {allowed}, got \"{bad}\""):
                query_json(ps.session, key, body)
        # a label with a NUL is refused as that, not as too long
        with pytest.raises(LiveError, match=r"label.*without NUL"):
            query_json(ps.session, ps.keys.demo_start, {"label": "a\x00b"})
        with pytest.raises(LiveError, match="no correction"):
            ps.stop_correction()  # nothing was started
    assert live.client.get(f"/skills/{corrected_skill}/models").json()["total"] == versions


def test_a_correction_field_is_refused_alike_by_every_query_that_takes_it(
        live: Any, corrected_skill: str) -> None:
    # correction/start checked a label twice (as a demonstration's at 256 characters with
    # bad_payload, then as a correction's at 200 with invalid_input) and steer/keep refused
    # the same label and weight as bad_payload: one value, three answers.
    versions = live.client.get(f"/skills/{corrected_skill}/models").json()["total"]
    with PoseStreamer(corrected_skill, "alike", endpoint=live.endpoint) as ps:
        for key, body, field in (
                (ps.keys.correction_start, {"kind": "include", "label": "x" * 230}, "label"),
                (ps.keys.correction_start, {"kind": "include", "label": "x" * 300}, "label"),
                (ps.keys.steer_keep, {"label": "x" * 300}, "label"),
                (ps.keys.correction_start, {"kind": "include", "weight": 5000}, "weight"),
                (ps.keys.steer_keep, {"weight": 5000}, "weight"),
                (ps.keys.correction_start, {"weight": 2}, "kind"),
                (ps.keys.correction_start, {"kind": "widen"}, "kind")):
            with pytest.raises(LiveError) as refused:
                query_json(ps.session, key, body)
            error = refused.value.body["error"]
            assert (error["type"], error["field"]) == ("invalid_input", field), (body, error)
            assert error["message"].startswith(f"expected {field} as "), error
    assert live.client.get(f"/skills/{corrected_skill}/models").json()["total"] == versions


def test_a_capture_in_the_way_is_named_by_what_it_captures(live: Any, corrected_skill: str) -> None:
    # An exclude started while an include was captured was refused naming "demo".
    with PoseStreamer(corrected_skill, "busy", endpoint=live.endpoint) as ps:
        ps.start_correction("include")
        for start, busy in ((lambda: ps.start_correction("exclude"), "correction"),
                            (lambda: ps.start_demo(), "correction")):
            with pytest.raises(LiveError) as refused:
                start()
            error = refused.value.body["error"]
            assert (error["type"], error["field"]) == ("conflict", busy), error
            assert error["message"].startswith("a correction is being captured"), error
    with PoseStreamer(corrected_skill, "busy2", endpoint=live.endpoint) as ps:
        ps.start_demo()
        with pytest.raises(LiveError) as refused:
            ps.start_correction("exclude")
        error = refused.value.body["error"]
        assert (error["type"], error["field"]) == ("conflict", "demo"), error


def test_a_live_correction_leaves_out_the_glitch_pose_its_tracker_rejected(live: Any) -> None:
    # A guided include path 0.9 radii out with one pose 2.5 radii out: the tracker answers
    # that pose outside_canal (a glitch), and the correction captured leaves it out of the
    # canal too, saying so, instead of doubling the canal's radius there.
    make_skill(live.client, "glitchy", 3)
    canal = canal_of(live, "glitchy")
    idx = np.arange(20, 61)
    path = canal.directrix[idx] + 0.9 * canal.radii[idx, None] * canal.normals[idx]
    path[20] = canal.directrix[40] + 2.5 * canal.radii[40] * canal.normals[40]
    with PoseStreamer("glitchy", "guided", endpoint=live.endpoint, encoding="json") as ps:
        for i in range(20):
            ps.wait_for(ps.send((canal.directrix[i] + 0.9 * canal.radii[i] * canal.normals[i]).tolist(),
                                restart=(i == 0)), 10.0)
        ps.start_correction("include", label="guided, one glitch pose")
        answers = [ps.wait_for(ps.send(q.tolist()), 10.0) for q in path]
        made = ps.stop_correction()
    assert answers[20] is not None and answers[20].status == "outside_canal"
    assert made["correction"]["n_points"] == 41
    assert [n for n in made["notes"] if "glitch" in n] == [
        "1 of the 41 samples was left out as a glitch (far off the path and straight back, "
        "the rule demonstrations are cleaned by at fit): sample 20"]
    assert (canal_of(live, "glitchy").radii / canal.radii).max() < 1.5


@pytest.mark.parametrize("kind", ["include", "exclude"])
def test_one_pose_beyond_reach_does_not_cost_the_person_the_correction(
        live: Any, kind: str) -> None:
    # One pose a billion metres out (a sensor spike the decoder takes: it is a finite
    # number) made the stop fail on samples[20] "within 1e+06 canal sizes", and the capture
    # was gone with it: the person's whole push was lost.
    name = f"spiked{kind}"
    make_skill(live.client, name, 3)
    canal = canal_of(live, name)
    idx = np.arange(20, 61)
    side = 0.9 if kind == "include" else 0.4
    # an include runs along near the wall, an exclude is pushed from there half-way across
    push = 0.0 if kind == "include" else 0.8 * np.sin(np.linspace(0.0, np.pi, idx.size))
    path = canal.directrix[idx] + ((side - push) * canal.radii[idx])[:, None] * canal.normals[idx]
    path[20] = [1e9, 0.0, 0.0]
    with PoseStreamer(name, "spiked", endpoint=live.endpoint, encoding="json") as ps:
        for i in range(20):
            ps.wait_for(ps.send((canal.directrix[i] + side * canal.radii[i] * canal.normals[i]).tolist(),
                                restart=(i == 0)), 10.0)
        ps.start_correction(kind, label="one pose far off")
        for q in path:
            ps.wait_for(ps.send(q.tolist()), 10.0)
        made = ps.stop_correction()
    assert made["correction"]["n_points"] == 40, made
    far = [n for n in made["notes"] if "beyond" in n]
    assert len(far) == 1 and "1 of the 41 captured poses" in far[0], made["notes"]
    after = canal_of(live, name)
    assert np.isfinite(after.radii).all() and (after.radii / canal.radii).max() < 1.5


def test_steering_moves_the_plan_left_and_the_canal_keeps_it_inside(live: Any) -> None:
    make_skill(live.client, "steer3", 3)
    canal = canal_of(live, "steer3")
    axes = steering_axes(canal.tangents, canal.basis)
    robot = Robot(live, "steer3", "joy")
    try:
        start = canal.directrix[3].copy()

        def stick(k: int) -> None:
            if k % 10 == 0 and k < 250:
                robot.ps.steer(1.0, 0.0)

        path = robot.run(start, 250.0, 400, during=stick)
        assert robot.all_answered_in_order()
        targets = np.array([a.target for a in robot.answers if a.target is not None])
        assert canal.contains(targets).all()  # a steered target never leaves the canal
        # Where it steered, the plan went to the left (+u) side, as far as the tracker allows.
        loc = canal.locate(path[150:250])
        u_world = np.einsum("mk,mkd->md", axes[loc.index, 0], canal.basis[loc.index])
        offsets = path[150:250] - canal.directrix[loc.index]
        assert (np.einsum("md,md->m", offsets, u_world) > 0.3 * canal.radii[loc.index]).mean() > 0.9
        assert live.metric("canal_live_steer_inputs_total") >= 20
        time.sleep(STEER_TIMEOUT_S)
        kept = robot.ps.keep_steered(label="wider on the left")
        assert kept["correction"]["kind"] == "include" and kept["correction"]["label"] == "wider on the left"
        refined = canal_of(live, "steer3")
        assert refined.contains(path[10:250]).mean() > 0.99
        with pytest.raises(LiveError, match="no steered run"):
            robot.ps.keep_steered()
    finally:
        robot.close()


def test_a_simulated_person_keeps_the_robot_out_of_a_hidden_sphere(live: Any) -> None:
    from canal_client.sim import run_sim

    make_skill(live.client, "sphere3", 3)
    canal = canal_of(live, "sphere3")
    i = canal.n_sections // 2
    centre = canal.directrix[i] + 1.0 * canal.radii[i] * canal.normals[i]
    radius = 0.6 * float(canal.radii[i])
    start = canal.directrix[5] + 0.7 * canal.radii[5] * canal.normals[5]
    first = run_sim("sphere3", robot="taught", start=start, rate_hz=200.0, timeout_s=20.0,
                    endpoint=live.endpoint, keep_out=(centre, radius))
    assert first.reached_end and first.held > 0, (first.statuses, first.refused)
    assert len(first.corrections) == 1 and not first.refused
    again = run_sim("sphere3", robot="taught", start=start, rate_hz=200.0, timeout_s=20.0,
                    endpoint=live.endpoint, keep_out=(centre, radius))
    assert again.reached_end and again.held == 0 and again.corrections == []
    assert again.model_version == first.corrections[0]


def test_a_start_during_a_capture_of_its_kind_starts_it_over_and_says_what_it_discards(
        live: Any) -> None:
    # A second demo/start (or correction/start of the same kind) threw the poses captured so
    # far away and answered as a first start: the stored demonstration had fewer poses than
    # were sent since the first start, and nothing said so.
    make_skill(live.client, "twice", 3)
    path = canal_of(live, "twice").directrix
    with PoseStreamer("twice", "arm", endpoint=live.endpoint, encoding="json") as ps:
        k = itertools.count()

        def send(n: int) -> None:
            for _ in range(n):
                assert ps.wait_for(ps.send(path[min(next(k) // 2, len(path) - 1)]),
                                   timeout=5.0) is not None

        send(1)
        assert ps.start_demo()["discarded"] == 0
        send(20)
        again = ps.start_demo()
        assert again["capturing"] is True and again["discarded"] == 20, again
        send(15)
        assert ps.stop_demo()["n_points"] == 15
        assert ps.start_correction("include")["discarded"] == 0
        send(10)
        assert ps.start_correction("include")["discarded"] == 10
        # the other kind is still refused: the person stops the capture first
        with pytest.raises(LiveError) as err:
            ps.start_correction("exclude")
        assert (err.value.body["error"]["type"], err.value.body["error"]["field"]) == (
            "conflict", "correction"), err.value.body
        send(25)
        assert ps.stop_correction()["correction"]["n_points"] == 25


def test_a_refused_stop_leaves_the_capture_open(live: Any) -> None:
    # A demo/stop refused for what was captured (too few poses yet) ended the capture: the
    # poses were lost and the person had to begin again.
    make_skill(live.client, "refused", 3)
    path = canal_of(live, "refused").directrix
    n_demos = live.client.get("/skills/refused").json()["n_demonstrations"]
    with PoseStreamer("refused", "arm", endpoint=live.endpoint, encoding="json") as ps:
        assert ps.wait_for(ps.send(path[0]), timeout=5.0) is not None
        ps.start_demo()
        assert ps.wait_for(ps.send(path[1]), timeout=5.0) is not None
        with pytest.raises(LiveError) as err:
            ps.stop_demo()
        assert err.value.body["error"]["type"] == "invalid_input", err.value.body
        assert live.client.get("/skills/refused").json()["n_demonstrations"] == n_demos
        for p in path[2:40]:
            assert ps.wait_for(ps.send(p), timeout=5.0) is not None
        assert ps.stop_demo()["n_points"] == 39
    assert live.client.get("/skills/refused").json()["n_demonstrations"] == n_demos + 1
