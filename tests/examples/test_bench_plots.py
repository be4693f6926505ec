"""bench/plots.py draws what the benchmark rows allow and never fails on a partial run."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from bench.common import summary_markdown, summary_row  # noqa: E402
from bench.plots import (  # noqa: E402
    fit_series,
    live_quantiles,
    markdown_images,
    quality_panels,
    rows_from_markdown,
    write_plots,
)


def rows() -> list[dict]:
    out = []
    for peer, v in (("ProMP", 2.0), ("DMP", 3.3)):
        out.append({"source": "quality", **summary_row("canal circle rmse, LASA leave-one-out",
                                                       3.5, "mm", peer, v)})
    out.append({"source": "quality", **summary_row("canal circle RMF contain, 3-D sets", 99.7,
                                                   "%", "ProMP", 60.9, better="higher")})
    out.append({"source": "quality", **summary_row("canal circle fit time, LASA", 7.8, "ms",
                                                   "GMR", 99.0)})  # not a quality measure
    for n, ours, naive in ((200, 10.2, 7.2), (1000, 19.9, 26.7)):
        out.append({"source": "core", **summary_row(f"fit, circle, 10 x 1000 pts, N={n}", ours,
                                                    "ms", "naive Python loop", naive)})
    out.append({"source": "scale", **summary_row("fit, circle, 10 x 5000 pts, N=5000", 384.0,
                                                 "ms")})
    out.append({"source": "scale", **summary_row("fit, circle, 200 demos x 200 pts", 87.0,
                                                 "ms")})
    for k in (1, 16):
        for q, ours, echo in ((50, 0.33 * k, 0.23), (99, 1.2 * k, 2.4)):
            out.append({"source": "live", **summary_row(f"live round trip p{q}, {k} stream(s)",
                                                        ours, "ms", "bare Zenoh echo", echo)})
    return out


def png_ok(path: Path) -> None:
    from matplotlib.image import imread

    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    image = imread(str(path))
    assert image.shape[0] >= 150 and image.shape[1] >= 300
    assert image[..., :3].std() > 0.05


def test_rows_become_the_three_pictures(tmp_path: Path) -> None:
    written = write_plots(rows(), tmp_path, dpi=60)
    assert [p.name for p, _ in written] == ["quality.png", "fit_time.png", "live_latency.png"]
    for path, _ in written:
        png_ok(path)
    md = markdown_images(written, tmp_path)
    assert "![Quality against the peers per data set](quality.png)" in md


def test_what_each_picture_reads() -> None:
    panels = quality_panels(rows())
    assert set(panels) == {("LASA leave-one-out", "rmse"), ("3-D sets", "contain")}
    assert panels[("LASA leave-one-out", "rmse")]["peers"] == {"ProMP": 2.0, "DMP": 3.3}
    series = fit_series(rows())
    assert series["N"]["canal_core.fit, 10 demos x 1000 pts"] == [(200.0, 10.2), (1000.0, 19.9)]
    assert series["N"]["naive Python loop, 10 x 1000"] == [(200.0, 7.2), (1000.0, 26.7)]
    assert series["N"]["canal_core.fit, 10 demos x 5000 pts"] == [(5000.0, 384.0)]
    assert series["demos"]["canal_core.fit, 200 pts per demo"] == [(200.0, 87.0)]
    live = live_quantiles(rows())
    assert sorted(live) == [1, 16]
    assert live[16]["ours"] == {0.5: pytest.approx(5.28), 0.99: pytest.approx(19.2)}
    assert live[1]["peer"] == {0.5: 0.23, 0.99: 2.4}


def test_partial_and_odd_rows_give_fewer_pictures_not_errors(tmp_path: Path) -> None:
    assert write_plots([], tmp_path / "none") == []
    assert not (tmp_path / "none").exists()
    only_live = [r for r in rows() if r["source"] == "live"]
    written = write_plots(only_live, tmp_path / "live", dpi=50)
    assert [p.name for p, _ in written] == ["live_latency.png"]
    odd = [{"source": "quality", "name": "canal circle rmse, LASA", "value": math.nan},
           {"source": "live", "name": "live round trip p50, 4 stream(s)", "value": None},
           {"name": "fit, circle, 10 x 1000 pts, N=200", "value": "fast", "unit": "ms"},
           {"source": "core"}, {}]
    assert write_plots(odd, tmp_path / "odd") == []


def test_live_samples_draw_the_full_cdf(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    row = {"source": "live", **summary_row("live round trip p50, 1 stream(s)", 0.3, "ms",
                                           "bare Zenoh echo", 0.2)}
    row["samples"] = list(rng.gamma(4.0, 0.08, 500))
    row["peer_samples"] = list(rng.gamma(4.0, 0.05, 500))
    assert len(live_quantiles([row])[1]["samples"]) == 500
    (path, _), = write_plots([row], tmp_path, dpi=50)
    png_ok(path)


def test_summary_table_round_trip_and_cli(tmp_path: Path) -> None:
    table = summary_markdown(rows())
    back = rows_from_markdown("text before\n\n" + table + "\n\nafter")
    assert len(back) == len(rows())
    assert back[0]["name"] == "canal circle rmse, LASA leave-one-out"
    assert back[0]["peer_name"] == "ProMP" and back[0]["peer_value"] == 2.0
    md = tmp_path / "B.md"
    md.write_text(table + "\n")
    out = tmp_path / "img"
    proc = subprocess.run([sys.executable, "-m", "bench.plots", "--from-markdown", str(md),
                           "--out", str(out), "--dpi", "50"], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert sorted(p.name for p in out.iterdir()) == ["fit_time.png", "live_latency.png",
                                                     "quality.png"]
    assert "![Live round trip against the bare Zenoh echo](img/live_latency.png)" in proc.stdout


def test_every_benchmark_picture_linked_is_there_and_small() -> None:
    import re

    links = re.findall(r"!\[[^\]]*\]\(([^)]+\.png)\)", (ROOT / "BENCHMARKS.md").read_text())
    assert links
    for link in links:
        path = ROOT / link
        png_ok(path)
        assert path.stat().st_size < 200 * 1024
