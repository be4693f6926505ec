"""Pictures of the benchmark results: what `python -m bench` collects, drawn as PNGs.

Input: the summary rows every bench script appends (see :mod:`bench.common`: ``source``,
``name``, ``value``, ``unit``, ``peer_name``, ``peer_value``, ``better``). Each plot takes the
rows it recognises by source and name and ignores the rest, so a missing script, a renamed
row or a partial run gives a smaller picture (or none), never an error:

``quality.png``
    ``quality`` rows whose name holds ``dtw``, ``rmse`` or ``contain``: ours beside each
    same-run peer named in the row, one panel per data set (the text after the name's last
    comma, e.g. ``LASA leave-one-out``) and measure: the measure the table states.
``fit_time.png``
    ``fit, circle, ... N=<N>`` rows (``core``, ``scale``): fit time against the number of
    sections N, beside the peer the row names (measured in the same run);
    ``fit, circle, <n> demos x ...`` rows against the number of demos; ``fit, circle, <set>,
    <d> x <n> rows, N=<N>`` rows (raw logs) as bars beside their peer (the reference
    implementation): each panel is titled by what its rows hold.
``live_latency.png``
    ``live round trip p<q>, <k> stream(s)`` or ``live <k> robot(s)|<k>x1kHz <format> p<q>`` rows:
    the measured quantiles as bars beside the bare Zenoh echo of the same run, per stream
    count. A row may carry ``samples`` and ``peer_samples`` (latencies, the row's unit): then
    the full empirical CDF is drawn instead.

``python -m bench.plots --from-markdown BENCHMARKS.md --out docs/img/bench`` draws the same
pictures from the summary table already in BENCHMARKS.md (no benchmark is re-run).
"""

from __future__ import annotations

import argparse
import math
import re
import sys
from collections import defaultdict
from collections.abc import Iterable
from pathlib import Path
from typing import Any

Row = dict[str, Any]

OURS = "tab:blue"
PEERS = ["tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:gray"]
FIT_N = re.compile(r"^fit, circle, (?P<demos>\d+) x (?P<points>\d+) pts, N=(?P<n>\d+)$")
FIT_DEMOS = re.compile(r"^fit, circle, (?P<demos>\d+) demos x (?P<points>\d+) pts$")
FIT_RAW = re.compile(r"^fit, circle, (?P<set>[^,]+), (?P<demos>\d+) x (?P<points>\d+) rows, "
                     r"N=(?P<n>\d+)$")
LIVE = re.compile(r"^live round trip p(?P<q>\d+(?:\.\d+)?), (?P<k>\d+) streams?(?:\(s\))?$")
LIVE_BENCH = re.compile(r"^live (?P<k>\d+)(?: robots?|x1kHz) (?P<fmt>\w+) p(?P<q>\d+(?:\.\d+)?)$")


def _finite(x: Any) -> bool:
    return isinstance(x, int | float) and math.isfinite(x)


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig: Any, path: Path, dpi: int) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi, metadata={"Software": None})
    _pyplot().close(fig)
    return path


# ---- quality ---------------------------------------------------------------------------------


def quality_panels(rows: Iterable[Row]) -> dict[tuple[str, str], dict[str, Any]]:
    """{(data set, measure): {"unit", "better", "ours", "peers": {name: value}}} from the
    quality rows."""
    panels: dict[tuple[str, str], dict[str, Any]] = {}
    for r in rows:
        name = str(r.get("name", ""))
        if r.get("source") != "quality" or not _finite(r.get("value")):
            continue
        measure = ("dtw" if "dtw" in name else "rmse" if "rmse" in name
                   else "contain" if "contain" in name else None)
        if measure is None:
            continue
        dataset = name.rsplit(",", 1)[1].strip() if "," in name else "all"
        panel = panels.setdefault((dataset, measure), {
            "unit": r.get("unit", ""), "better": r.get("better", "lower"),
            "ours": float(r["value"]), "ours_name": name.split(",")[0].strip(), "peers": {}})
        if r.get("peer_name") and _finite(r.get("peer_value")):
            panel["peers"][str(r["peer_name"])] = float(r["peer_value"])
    return panels


def plot_quality(rows: Iterable[Row], out: Path, dpi: int = 90) -> Path | None:
    panels = quality_panels(rows)
    if not panels:
        return None
    plt = _pyplot()
    order = {"dtw": 0, "rmse": 1, "contain": 2}
    keys = sorted(panels, key=lambda k: (order[k[1]], k[0]))
    fig, axes = plt.subplots(1, len(keys), figsize=(3.6 * len(keys), 3.4), squeeze=False,
                             layout="constrained")
    for ax, key in zip(axes[0], keys, strict=True):
        p = panels[key]
        labels = ["canal (ours)", *p["peers"]]
        values = [p["ours"], *p["peers"].values()]
        colors = [OURS, *PEERS[: len(p["peers"])]]
        bars = ax.bar(range(len(values)), values, color=colors)
        ax.bar_label(bars, labels=[f"{v:.3g}" for v in values], fontsize=7)
        ax.set_xticks(range(len(values)), labels, rotation=30, ha="right", fontsize=7)
        unit = f" ({p['unit']})" if p["unit"] else ""
        ax.set_title(f"{key[0]}: {key[1]}{unit}\n{p['better']} is better", fontsize=9)
        ax.tick_params(axis="y", labelsize=7)
        ax.margins(y=0.15)
    fig.suptitle("Quality: canal beside the best peer of the same run, per data set "
                 "(bench/quality.py)", fontsize=10)
    return _save(fig, out, dpi)


# ---- fit time -------------------------------------------------------------------------------


def fit_series(rows: Iterable[Row]) -> dict[str, dict[str, list[tuple[float, float]]]]:
    """{"N": {series: [(x, ms)]}, "demos": {...}}: fit time against sections and demos."""
    series: dict[str, dict[str, list[tuple[float, float]]]] = {"N": defaultdict(list),
                                                               "demos": defaultdict(list)}
    for r in rows:
        name = str(r.get("name", ""))
        if r.get("unit") != "ms" or not _finite(r.get("value")):
            continue
        if m := FIT_N.match(name):
            n = float(m["n"])
            label = f"canal_core.fit, {m['demos']} demos x {m['points']} pts"
            series["N"][label].append((n, float(r["value"])))
            if r.get("peer_name") and _finite(r.get("peer_value")):
                series["N"][f"{r['peer_name']}, {m['demos']} x {m['points']}"].append(
                    (n, float(r["peer_value"])))
        elif m := FIT_DEMOS.match(name):
            label = f"canal_core.fit, {m['points']} pts per demo"
            series["demos"][label].append((float(m["demos"]), float(r["value"])))
            if r.get("peer_name") and _finite(r.get("peer_value")):
                series["demos"][str(r["peer_name"])].append(
                    (float(m["demos"]), float(r["peer_value"])))
    return {k: {s: sorted(set(v)) for s, v in d.items()} for k, d in series.items() if d}


def fit_on_raw_logs(rows: Iterable[Row]) -> list[tuple[str, float, str, float]]:
    """[(set, ours ms, peer, peer ms)]: fits of raw logs beside the peer of the same run."""
    out = []
    for r in rows:
        m = FIT_RAW.match(str(r.get("name", "")))
        if (m and r.get("unit") == "ms" and _finite(r.get("value")) and r.get("peer_name")
                and _finite(r.get("peer_value"))):
            out.append((f"{m['set']}\n{m['demos']} x {m['points']}, N={m['n']}",
                        float(r["value"]), str(r["peer_name"]), float(r["peer_value"])))
    return out


def plot_fit_time(rows: Iterable[Row], out: Path, dpi: int = 90) -> Path | None:
    rows = list(rows)
    series = fit_series(rows)
    raw = fit_on_raw_logs(rows)
    if not series and not raw:
        return None
    plt = _pyplot()
    kinds = [k for k in ("N", "demos") if k in series] + (["raw"] if raw else [])
    fig, axes = plt.subplots(1, len(kinds), figsize=(5.0 * len(kinds), 3.6), squeeze=False,
                             layout="constrained")
    for ax, kind in zip(axes[0], kinds, strict=True):
        if kind == "raw":
            xs = range(len(raw))
            peers = sorted({p for _, _, p, _ in raw})
            ax.bar([x - 0.2 for x in xs], [o for _, o, _, _ in raw], width=0.4, color=OURS,
                   label="canal_core.fit")
            for j, peer in enumerate(peers):
                ax.bar([x + 0.2 for x, row in zip(xs, raw, strict=True) if row[2] == peer],
                       [v for _, _, p, v in raw if p == peer], width=0.4,
                       color=PEERS[j % len(PEERS)], label=peer)
            ax.set_xticks(list(xs), [label for label, _, _, _ in raw], fontsize=7)
            ax.set_yscale("log")
            ax.set_ylabel("fit time (ms, log scale)", fontsize=8)
            ax.set_title("raw robot logs, beside " + ", ".join(peers), fontsize=9)
        else:
            for j, (label, points) in enumerate(sorted(series[kind].items(),
                                                       key=lambda kv: "canal" not in kv[0])):
                px, py = zip(*points, strict=True)
                ours = label.startswith("canal_core")
                ax.plot(px, py, marker="o", ms=4, lw=1.5 if ours else 1.2,
                        ls="-" if ours else "--", color=OURS if j == 0 and ours else
                        PEERS[j % len(PEERS)], label=label)
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_xlabel("sections N" if kind == "N" else "demonstrations", fontsize=8)
            ax.set_ylabel("fit time (ms)", fontsize=8)
            ax.grid(True, which="both", alpha=0.3)
        ax.tick_params(which="both", labelsize=7)
        ax.legend(fontsize=7, frameon=False)
    fig.suptitle("Fit time (circle sections), each beside the peer measured in the same run",
                 fontsize=10)
    return _save(fig, out, dpi)


# ---- live latency ---------------------------------------------------------------------------


def live_quantiles(rows: Iterable[Row]) -> dict[int, dict[str, Any]]:
    """{streams: {"unit", "ours": {q: v}, "peer": {q: v}, "peer_name", "samples"...}}."""
    out: dict[int, dict[str, Any]] = {}
    for r in rows:
        m = LIVE.match(str(r.get("name", ""))) or LIVE_BENCH.match(str(r.get("name", "")))
        if not m or not _finite(r.get("value")) or r.get("unit") not in ("ms", "us", "s"):
            continue
        entry = out.setdefault(int(m["k"]), {"unit": r.get("unit", ""), "ours": {}, "peer": {},
                                             "peer_name": r.get("peer_name") or "peer"})
        q = float(m["q"]) / 100.0
        entry["ours"][q] = float(r["value"])
        if _finite(r.get("peer_value")):
            entry["peer"][q] = float(r["peer_value"])
        for key in ("samples", "peer_samples"):
            if isinstance(r.get(key), list) and r[key]:
                entry[key] = [float(v) for v in r[key] if _finite(v)]
    return out


def plot_live_latency(rows: Iterable[Row], out: Path, dpi: int = 90) -> Path | None:
    """A CDF where the rows carry their samples; else the measured quantiles as bars (a
    curve through two quantiles would invent the distribution between them)."""
    data = live_quantiles(rows)
    if not data:
        return None
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 4.0), layout="constrained")
    unit = next(iter(data.values()))["unit"]
    with_samples = all("samples" in e for e in data.values())
    if with_samples:
        for j, (k, entry) in enumerate(sorted(data.items())):
            color = PEERS[j % len(PEERS)] if j else OURS
            for who, style in (("samples", "-"), ("peer_samples", ":")):
                if not entry.get(who):
                    continue
                xs = sorted(entry[who])
                ys = [(i + 1) / len(xs) for i in range(len(xs))]
                name = "Canal bridge" if who == "samples" else entry["peer_name"]
                ax.plot(xs, ys, ls=style, color=color, drawstyle="steps-post",
                        label=f"{name}, {k} stream{'s' if k > 1 else ''}")
        ax.set_xscale("log")
        ax.set_xlabel(f"pose -> target round trip ({unit}, log scale)", fontsize=8)
        ax.set_ylabel("fraction of poses answered within", fontsize=8)
        ax.set_ylim(0, 1.02)
        ax.legend(fontsize=7, frameon=False, loc="lower right")
    else:
        labels, ours, peer = [], [], []
        for k, entry in sorted(data.items()):
            for q in sorted(entry["ours"]):
                labels.append(f"{k} stream{'s' if k > 1 else ''}\np{100 * q:g}")
                ours.append(entry["ours"][q])
                peer.append(entry["peer"].get(q, math.nan))
        xs = range(len(labels))
        peer_name = next(iter(data.values()))["peer_name"]
        bars = ax.bar([x - 0.2 for x in xs], ours, width=0.4, color=OURS, label="Canal bridge")
        ax.bar_label(bars, labels=[f"{v:.3g}" for v in ours], fontsize=7)
        bars = ax.bar([x + 0.2 for x in xs], peer, width=0.4, color=PEERS[0], label=peer_name)
        ax.bar_label(bars, labels=["" if math.isnan(v) else f"{v:.3g}" for v in peer],
                     fontsize=7)
        ax.set_xticks(list(xs), labels, fontsize=7)
        ax.set_yscale("log")
        ax.set_ylabel(f"pose -> target round trip ({unit}, log scale)", fontsize=8)
        ax.legend(fontsize=7, frameon=False, loc="upper left")
    ax.grid(True, which="both", alpha=0.3)
    ax.tick_params(which="both", labelsize=7)
    ax.set_title("Live round trip beside the bare Zenoh echo, same run (bench/live.py)",
                 fontsize=9)
    return _save(fig, out, dpi)


# ---- all of them ----------------------------------------------------------------------------

PLOTS = (("quality.png", plot_quality, "Quality against the peers per data set"),
         ("fit_time.png", plot_fit_time, "Fit time, beside the peers of the same run"),
         ("live_latency.png", plot_live_latency, "Live round trip against the bare Zenoh echo"))


def write_plots(rows: list[Row], out_dir: Path, dpi: int = 90) -> list[tuple[Path, str]]:
    """Every plot the rows allow, as (path, caption) (matplotlib: the dev extra)."""
    written = []
    for filename, plot, caption in PLOTS:
        path = plot(rows, out_dir / filename, dpi)
        if path is not None:
            written.append((path, caption))
    return written


def markdown_images(written: list[tuple[Path, str]], relative_to: Path) -> str:
    """Markdown image lines for BENCHMARKS.md (paths relative to its folder)."""
    lines = []
    for path, caption in written:
        try:
            rel = path.resolve().relative_to(relative_to.resolve())
        except ValueError:
            rel = path
        lines.append(f"![{caption}]({rel.as_posix()})")
    return "\n\n".join(lines)


def rows_from_markdown(text: str) -> list[Row]:
    """The rows of the summary table ``summary_markdown`` wrote (bench/common.py)."""
    rows = []
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) != 8 or cells[0] in ("source", "") or set(cells[0]) <= {"-", ":"}:
            continue
        source, name, ours, unit, peer_name, peer, _ratio, better = cells

        def number(text: str) -> float | None:
            try:
                return float(text)
            except ValueError:
                return None

        if number(ours) is None:
            continue
        rows.append({"source": source, "name": name, "value": number(ours), "unit": unit,
                     "peer_name": None if peer_name == "-" else peer_name,
                     "peer_value": number(peer), "better": better})
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.plots",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--from-markdown", type=Path, required=True,
                        help="a markdown file holding the summary table (BENCHMARKS.md)")
    parser.add_argument("--out", type=Path, default=Path("docs/img/bench"))
    parser.add_argument("--dpi", type=int, default=90)
    args = parser.parse_args(argv)
    rows = rows_from_markdown(args.from_markdown.read_text(encoding="utf-8"))
    written = write_plots(rows, args.out, args.dpi)
    for path, _ in written:
        print(f"wrote {path}")
    print(markdown_images(written, args.from_markdown.parent))
    return 0 if written else 1


if __name__ == "__main__":
    sys.exit(main())
