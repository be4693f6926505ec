"""What a newcomer meets in the first hour: the one-line canal summary, the pictures, the
example demonstration files, the web viewer link, ``canal sim`` finding the live bridge on its
own, the CLI's wording, and the service answering /healthz while it loads."""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

import httpx
import numpy as np
import pytest
from canal_client.cli import app as cli_app
from canal_client.cli.demos import cli_wording
from canal_client.cli.simulation import live_endpoint
from canal_service.app import create_app
from canal_service.core.cli import endpoints_line, settings_from_args
from canal_service.core.config import Settings
from canal_service.core.serve import Bootstrap
from canal_testing import LiveServer, free_port
from typer.testing import CliRunner

import canal_core
from canal_core import datasets

ROOT = Path(__file__).resolve().parents[2]
DEMOS = ROOT / "examples" / "demos"
os.environ.setdefault("RERUN_TELEMETRY_ENABLED", "false")


# ---- Canal's one-line summary ------------------------------------------------------------


@pytest.mark.parametrize("dim", [2, 3])
def test_canal_repr_and_str_are_one_short_line(dim: int) -> None:
    demos = datasets.task_one()
    if dim == 2:
        demos = [d[:, :2] for d in demos]
    canal = canal_core.fit(demos, n_samples=50)
    r, s = repr(canal), str(canal)
    for text in (r, s):
        assert "\n" not in text and len(text) < 160, text
        assert str(canal.n_sections) in text and canal.section_kind in text
        assert f"{canal.radii.min():.4g}" in text and f"{canal.radii.max():.4g}" in text
        length = canal.arclength[-1] - canal.arclength[0]
        assert f"{length:.4g}" in text
    assert r.startswith(f"Canal(dim={dim}, sections=50, kind={canal.section_kind!r}, demos=4,")
    assert s.startswith(f"{dim}-D canal: 50 {canal.section_kind} sections from 4 demos")
    # A container of canals prints one line per canal, not their arrays.
    assert len(repr([canal, canal]).splitlines()) == 1


# ---- canal_core.plot ------------------------------------------------------------------------


def test_plot_canal_draws_demos_directrix_and_reproductions(tmp_path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.image import imread

    from canal_core.plot import plot_canal

    for dim in (3, 2):
        demos = [d[:, :dim] for d in datasets.task_two()]
        canal = canal_core.fit(demos, n_samples=60)
        fig = plot_canal(canal, demos=demos, starts=2, seed=1)
        ax = fig.axes[0]
        # 3 demos + directrix + 2 reproductions
        assert len(ax.get_lines()) == 6
        assert ax.get_title() == str(canal)
        repro = ax.get_lines()[-1].get_data_3d() if dim == 3 else ax.get_lines()[-1].get_data()
        path = np.column_stack(repro)
        assert canal.contains(path).mean() > 0.95  # the drawn path is a real reproduction
        out = tmp_path / f"c{dim}.png"
        fig.savefig(out, dpi=50)
        assert imread(str(out))[..., :3].std() > 0.05
    with pytest.raises(canal_core.InvalidInputError) as info:
        plot_canal(canal, starts=[[np.nan, 0.0]])
    assert info.value.field == "starts"


# ---- examples/demos --------------------------------------------------------------------------


def test_example_demo_files_are_what_their_script_writes(tmp_path: Path) -> None:
    result = subprocess.run([sys.executable, str(DEMOS / "make_demos.py"), "--out",
                             str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    for name in ("demo_1.csv", "demo_2.npy", "demo_3.json"):
        assert (tmp_path / name).read_bytes() == (DEMOS / name).read_bytes(), name
    # The committed ROS 2 bag decodes to the fourth Task I demonstration, stamps at 10 Hz.
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with (DEMOS / "demo_4.mcap").open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        rows = [(m.log_time, msg.pose.position.x, msg.pose.position.y, msg.pose.position.z)
                for schema, channel, m, msg in reader.iter_decoded_messages()
                if channel.topic == "/ee_pose" and schema.name == "geometry_msgs/msg/PoseStamped"]
    got = np.array(rows)
    expected = datasets.task_one(n_points=41, noise=0.002, seed=7)[3]
    np.testing.assert_allclose(got[:, 1:], np.round(expected, 5))
    np.testing.assert_allclose(np.diff(got[:, 0]) / 1e9, 0.1, atol=1e-9)
    csv = np.loadtxt(DEMOS / "demo_1.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(csv[:, 1:], np.round(datasets.task_one(41, noise=0.002,
                                                                      seed=7)[0], 5), atol=1e-5)


# ---- the web viewer ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def viewer_service(tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    data = tmp_path_factory.mktemp("viewer") / "data"
    with LiveServer(create_app(Settings(data_dir=data, zenoh_enabled=False))) as live:
        demos = datasets.task_one(n_points=30)
        httpx.post(f"{live.url}/skills", json={"name": "pour", "dim": 3}).raise_for_status()
        for d in demos:
            httpx.post(f"{live.url}/skills/pour/demonstrations",
                       json={"positions": d.tolist()}).raise_for_status()
        httpx.post(f"{live.url}/skills/pour/fit", json={"n_samples": 40},
                   timeout=60).raise_for_status()
        yield live


def test_view_link_opens_rerun_web_viewer_on_the_skill_recording(viewer_service) -> None:  # type: ignore[no-untyped-def]
    url = viewer_service.url
    with httpx.Client(timeout=120) as client:
        first = client.get(f"{url}/skills/pour/view")
        assert first.status_code == 307
        page = client.get(f"{url}/skills/pour/view", follow_redirects=True)
        assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
        assert "re_viewer.js" in page.text and "Rerun" in page.text
        assert str(page.url).startswith(f"{url}/viewer/?url=")  # same origin as the service
        recording = parse_qs(urlsplit(str(page.url)).query)["url"][0]
        assert recording == f"{url}/skills/pour/recording.rrd"
        rrd = client.get(recording)
        assert rrd.status_code == 200 and rrd.content[:4] == b"RRF2" and len(rrd.content) > 1000
        js = client.get(f"{url}/viewer/re_viewer.js")
        assert js.status_code == 200 and "javascript" in js.headers["content-type"]
        wasm = client.get(f"{url}/viewer/re_viewer_bg.wasm")
        assert wasm.status_code == 200 and wasm.content[:4] == b"\0asm"
        assert wasm.headers["content-type"] == "application/wasm"
        # Only the viewer's own files, and only known skills.
        assert client.get(f"{url}/viewer/canal.sqlite3").status_code == 404
        assert client.get(f"{url}/viewer/..%2Fcanal.sqlite3").status_code == 422  # %2F: no path
        assert client.get(f"{url}/viewer/%2E%2E").status_code == 404
        missing = client.get(f"{url}/skills/nope/view")
        assert missing.status_code == 404 and missing.json()["error"]["type"] == "not_found"
        # The redirect was built from the Host header: a request naming another host (as a
        # proxy's cache may keep it) sent the browser there. It stays on the page's origin.
        forged = client.get(f"{url}/skills/pour/view", headers={"host": "elsewhere.example"})
        assert forged.status_code == 307
        assert forged.headers["location"].startswith("/viewer/?url="), forged.headers


def test_view_without_recordings_says_so(tmp_path: Path) -> None:
    settings = Settings(data_dir=tmp_path, zenoh_enabled=False, recordings_enabled=False)
    with LiveServer(create_app(settings)) as live:
        httpx.post(f"{live.url}/skills", json={"name": "s", "dim": 3}).raise_for_status()
        r = httpx.get(f"{live.url}/skills/s/view")
        assert r.status_code == 404 and r.json()["error"]["type"] == "disabled"
        result = CliRunner().invoke(cli_app, ["--url", live.url, "view", "s", "--web"])
        assert result.exit_code == 1
        assert "recordings are disabled" in result.stderr


def test_cli_view_web_prints_the_link(viewer_service) -> None:  # type: ignore[no-untyped-def]
    runner = CliRunner(env={"DISPLAY": "", "WAYLAND_DISPLAY": ""})
    result = runner.invoke(cli_app, ["--url", viewer_service.url, "view", "pour", "--web"])
    assert result.exit_code == 0, result.output
    assert f"{viewer_service.url}/skills/pour/view" in result.stdout
    result = runner.invoke(cli_app, ["--url", viewer_service.url, "--json", "view", "pour",
                                     "--web", "--no-open"])
    assert json.loads(result.stdout) == {"url": f"{viewer_service.url}/skills/pour/view",
                                         "opened": False}
    unknown = runner.invoke(cli_app, ["--url", viewer_service.url, "view", "nope", "--web"])
    assert unknown.exit_code == 1 and "nope" in unknown.stderr


# ---- canal sim --------------------------------------------------------------------------------


def test_live_endpoint_from_healthz() -> None:
    health = {"bridge": {"status": "ok", "prefix": "lab",
                         "listen": ["tcp/0.0.0.0:7447", "tcp/127.0.0.1:7448"]}}
    assert live_endpoint(health, "http://robot-pc:8000") == (
        ["tcp/robot-pc:7447", "tcp/127.0.0.1:7448"], "lab")
    from canal_client.errors import CanalClientError

    with pytest.raises(CanalClientError, match="no live bridge"):
        live_endpoint({"bridge": {"status": "disabled"}}, "http://127.0.0.1:8000")


def test_sim_finds_the_bridge_through_the_service(tmp_path: Path) -> None:
    zenoh = f"tcp/127.0.0.1:{free_port()}"
    settings = Settings(data_dir=tmp_path, recordings_enabled=False, zenoh_listen=[zenoh],
                        zenoh_prefix="lab")
    with LiveServer(create_app(settings)) as live:
        httpx.post(f"{live.url}/skills", json={"name": "s", "dim": 3}).raise_for_status()
        for d in datasets.task_one(n_points=30):
            httpx.post(f"{live.url}/skills/s/demonstrations",
                       json={"positions": d.tolist()}).raise_for_status()
        httpx.post(f"{live.url}/skills/s/fit", json={"n_samples": 40},
                   timeout=60).raise_for_status()
        runner = CliRunner()
        args = ["--url", live.url, "--json", "sim", "s", "--seed", "5", "--rate", "200",
                "--timeout", "20"]
        # No --endpoint, no --prefix: both come from /healthz (prefix 'lab', not 'canal').
        first = runner.invoke(cli_app, [*args, "--push", "999:0,0.01,0"])
        assert first.exit_code == 0, first.output
        doc = json.loads(first.stdout)
        assert doc["reached_end"] and doc["all_inside"] and doc["seed"] == 5
        assert doc["pushes_done"] == 0 and doc["pushes_pending"] == [[999.0, [0.0, 0.01, 0.0]]]
        assert "not applied" not in first.stdout + first.stderr  # --json: the fields say it
        again = json.loads(runner.invoke(cli_app, args).stdout)
        assert again["start"] == doc["start"]  # same seed, same start
        text = runner.invoke(cli_app, ["--url", live.url, "sim", "s", "--seed", "5", "--rate",
                                       "200", "--push", "999:0,0.01,0", "--push",
                                       "10%:0,0.001,0"])
        assert text.exit_code == 0, text.output
        # the normal output says what happened to each push
        assert "push 999 s:0,0.01,0 not applied: the run ended after" in text.stdout
        assert "push (0,0.001,0) applied at " in text.stdout  # the progress push happened
        # The wrong prefix given explicitly wins over the service's (and finds nobody).
        wrong = runner.invoke(cli_app, ["--url", live.url, "sim", "s", "--prefix", "canal",
                                        "--timeout", "1"])
        assert wrong.exit_code == 1


def test_sim_against_a_service_without_bridge_is_one_clear_error(tmp_path: Path) -> None:
    settings = Settings(data_dir=tmp_path, recordings_enabled=False, zenoh_enabled=False)
    with LiveServer(create_app(settings)) as live:
        result = CliRunner().invoke(cli_app, ["--url", live.url, "sim", "s"])
    assert result.exit_code == 1
    assert "runs no live bridge" in result.stderr and "Traceback" not in result.output
    unreachable = CliRunner().invoke(cli_app, ["--url", f"http://127.0.0.1:{free_port()}",
                                               "sim", "s"])
    assert unreachable.exit_code == 3


# ---- the CLI's wording for MCAP topics ----------------------------------------------------------


def test_cli_says_topic_flag_not_query_parameter(tmp_path: Path) -> None:
    assert cli_wording("pass ?topic= to choose the pose topic") == \
        "pass --topic to choose the pose topic"
    from mcap_ros2.writer import Writer as Ros2Writer

    sys.path.insert(0, str(DEMOS))
    from make_demos import POSE_STAMPED_MSGDEF

    buf = io.BytesIO()
    writer = Ros2Writer(buf)
    schema = writer.register_msgdef("geometry_msgs/msg/PoseStamped", POSE_STAMPED_MSGDEF)
    for i, p in enumerate(datasets.task_one(n_points=10)[0]):
        msg = {"header": {"stamp": {"sec": i, "nanosec": 0}, "frame_id": "b"},
               "pose": {"position": dict(zip("xyz", map(float, p), strict=True)),
                        "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}}
        for topic in ("/left", "/right"):
            writer.write_message(topic, schema, msg, log_time=i, publish_time=i)
    writer.finish()
    bag = tmp_path / "two.mcap"
    bag.write_bytes(buf.getvalue())
    with LiveServer(create_app(Settings(data_dir=tmp_path / "d", zenoh_enabled=False,
                                        recordings_enabled=False))) as live:
        httpx.post(f"{live.url}/skills", json={"name": "s", "dim": 3}).raise_for_status()
        result = CliRunner().invoke(cli_app, ["--url", live.url, "demo", "add", "s", str(bag)])
        assert result.exit_code == 1
        assert "--topic" in result.stderr and "?topic=" not in result.stderr
        ok = CliRunner().invoke(cli_app, ["--url", live.url, "demo", "add", "s", str(bag),
                                          "--topic", "/right"])
        assert ok.exit_code == 0, ok.output


# ---- start-up -----------------------------------------------------------------------------------


def test_endpoints_line_names_rest_and_zenoh() -> None:
    s = settings_from_args(["--port", "8123", "--zenoh-listen", "tcp/127.0.0.1:7500"])
    assert endpoints_line(s) == ("canal service: REST http://127.0.0.1:8123, "
                                 "Zenoh tcp/127.0.0.1:7500 (prefix canal)")
    assert endpoints_line(settings_from_args(["--no-zenoh"])).endswith("Zenoh off (--no-zenoh)")


def test_healthz_answers_while_the_app_loads_and_requests_wait(tmp_path: Path) -> None:
    release = threading.Event()

    def slow_build(settings: Settings):  # type: ignore[no-untyped-def]
        assert release.wait(30)
        return create_app(settings)

    settings = Settings(data_dir=tmp_path, zenoh_enabled=False, recordings_enabled=False)
    boot = Bootstrap(settings, build=slow_build)
    with LiveServer(boot) as live:
        boot.server = live.server
        starting = httpx.get(f"{live.url}/healthz", timeout=10)
        assert starting.status_code == 503 and starting.json()["status"] == "starting"
        answers: list[httpx.Response] = []
        waiting = threading.Thread(target=lambda: answers.append(
            httpx.get(f"{live.url}/skills", timeout=30)))
        waiting.start()
        time.sleep(0.3)
        assert not answers  # held until the app is there, not refused
        release.set()
        waiting.join(30)
        assert answers and answers[0].status_code == 200 and answers[0].json()["total"] == 0
        assert httpx.get(f"{live.url}/healthz", timeout=10).json()["status"] == "ok"


def test_a_service_that_cannot_start_exits_with_the_reason(tmp_path: Path) -> None:
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("CANAL_")}
    proc = subprocess.run(
        [sys.executable, "-m", "canal_service", "--port", str(port), "--no-zenoh",
         "--no-recordings", "--data-dir", str(tmp_path),
         "--database-url", "postgresql+psycopg://nobody@127.0.0.1:1/none"],
        capture_output=True, text=True, timeout=120, env=env)
    assert proc.returncode != 0
    assert f"canal service: REST http://127.0.0.1:{port}, Zenoh off" in proc.stderr
    assert "failed to start" in proc.stderr


def test_bootstrap_lifespan_runs_the_real_apps_lifespan(tmp_path: Path) -> None:
    """The recorder the real app opens is there after start and closed at shutdown."""
    settings = Settings(data_dir=tmp_path, zenoh_enabled=False, recordings_enabled=True)
    boot = Bootstrap(settings)
    before = {t for t in threading.enumerate() if t.name == "canal-recorder"}
    with LiveServer(boot) as live:
        boot.server = live.server
        deadline = time.monotonic() + 60
        while httpx.get(f"{live.url}/healthz", timeout=10).status_code != 200:
            assert time.monotonic() < deadline
            time.sleep(0.05)
        assert boot.app.state.service.recorder is not None
        ours = {t for t in threading.enumerate() if t.name == "canal-recorder"} - before
        assert len(ours) == 1 and all(t.is_alive() for t in ours)
    # closed by the real lifespan's exit: its writer thread has finished
    assert not any(t.is_alive() for t in ours)


# ---- license and citation ------------------------------------------------------------------


def test_license_and_citation_agree_with_the_package() -> None:
    import tomllib

    import yaml

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["license"] == "MIT"
    assert (ROOT / "LICENSE").read_text().startswith("MIT License\n")
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert cff["cff-version"] == "1.2.0" and cff["type"] == "software"
    assert cff["license"] == project["license"] and cff["version"] == project["version"]
    for entry in (cff, cff["preferred-citation"], *cff["references"]):
        assert entry["title"] and entry["authors"], entry
    paper = cff["preferred-citation"]
    assert paper["title"] == ("Encoding Demonstrations and Learning New Trajectories using "
                              "Canal Surfaces")
    assert [a["family-names"] for a in paper["authors"]] == ["Ahmadzadeh", "Chernova"]
