"""`haptic-teleop report`: one self-contained HTML file and a Markdown twin from sweeps, runs, bags.

One real sweep (4 runs of 0.4 s, bags kept: today's sweep.csv) and small synthetic tables (the
Parquet/CSV results table's columns) feed every check; the browser check renders the HTML with
headless Chromium (skipped where no chromium binary is on PATH) and reads back which images it drew.
"""

from __future__ import annotations

import base64
import csv
import math
import os
import re
import shutil
import statistics
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import pytest

from haptic_teleop.cli.main import main

DELAY = "network.backward.effects.delay.delay_s"
POLICY = "network.backward.buffer.policy"
SWEEP = [
    "sweep", "wall_contact", "--param", f"{DELAY}=0.01,0.1", "--param", f"{POLICY}=none,adaptive",
    "--seeds", "1", "--keep-bags", "--quiet",
    "--set", "scene.duration_s=0.4", "--set", "operator.start_s=0.0", "--set", "slave.wall.position_m=0.004",
    "--set", "operator.speed_m_per_s=0.05", "--set", "network.backward.effects.delay.jitter_s=0.01",
]  # fmt: skip
PAIR = re.compile(r"^(.+)_predicted(_.+)?$")


class Page(HTMLParser):
    """Every tag with its attributes, the ids, and the text of each table row's cells."""

    def __init__(self, text: str) -> None:
        super().__init__()
        self.text = text
        self.tags: list[tuple[str, dict[str, str]]] = []
        self.rows: list[list[str]] = []
        self._cell: list[str] | None = None
        self.feed(text)

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, {k: v or "" for k, v in attrs}))
        if tag == "tr":
            self.rows.append([])
        elif tag in ("td", "th"):
            self._cell = []

    def handle_endtag(self, tag):
        if tag in ("td", "th") and self._cell is not None:
            self.rows[-1].append("".join(self._cell).strip())
            self._cell = None

    def handle_data(self, data):
        if self._cell is not None:
            self._cell.append(data)

    def ids(self) -> set[str]:
        return {a["id"] for _, a in self.tags if "id" in a}

    def images(self) -> list[dict[str, str]]:
        return [a for t, a in self.tags if t == "img"]

    def row(self, *first: str) -> list[str]:
        got = [r for r in self.rows if r[: len(first)] == list(first)]
        assert len(got) == 1, (first, got)
        return got[0]


def _report(args: list[str], out: Path, capsys) -> tuple[Page, str]:
    assert main(["report", *args, "--out", str(out), "--quiet"]) == 0, capsys.readouterr().err
    html = (out / "report.html").read_text()
    return Page(html), (out / "report.md").read_text()


@pytest.fixture(scope="module")
def sweep_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("report") / "sweep"
    assert main([*SWEEP, "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def sweep_report(sweep_dir, tmp_path_factory):
    out = tmp_path_factory.mktemp("report") / "sweep-report"
    assert main(["report", str(sweep_dir), "--max-runs", "1", "--out", str(out), "--quiet"]) == 0
    return out


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


def _synthetic(path: Path, bag: Path | None) -> None:
    """The results table's columns (scene keys by key path, seed, run_hash, metrics, bag_path):
    two delays set in both directions together, two policies, three seeds. Known by construction:
    measured slope = predicted + 0.05; transparency's RMS error = none's + 0.25 for every seed,
    while the seeds themselves spread it by 1 N."""
    rows = []
    for d in (0.0, 0.2):
        for policy in ("none", "transparency"):
            for seed in (1, 2, 3):
                predicted = 2.0 + d
                rows.append({
                    DELAY: d, "network.forward.effects.delay.delay_s": d, POLICY: policy, "scene.name": "wall_contact",
                    "seed": seed, "run_hash": f"{int(d * 10)}{policy[0]}{seed}" + "0" * 13,
                    "force_slope_predicted_n_per_s": predicted, "force_slope_measured_n_per_s": predicted + 0.05,
                    "force_drop_predicted_n": 0.1,  # no measured twin: not a pair
                    "force_rms_error_n": float(seed) + (0.25 if policy == "transparency" else 0.0) + d,
                    "buffering_delay_backward_mean_s": 0.01 * seed, "engine_loop": "compiled",
                    # the first row's bag relative to the table; the second's as the sweep ran it
                    # elsewhere: found in runs/<run_hash>/ beside the table
                    "bag_path": os.path.relpath(bag, path.parent) if bag is not None and not rows
                    else "elsewhere/runs/x/bag" if bag is not None and len(rows) == 1 else "",
                })  # fmt: skip
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def _sections(page: Page) -> set[str]:
    return {a["id"] for t, a in page.tags if t == "section" and "id" in a}


TOP = {"overview", "predicted-against-measured", "metrics-against-parameters", "comparisons-per-category",
       "per-run-drill-down"}  # fmt: skip


def _self_contained(page: Page) -> None:
    """No src or href leaves the page: images are data: PNGs, links are to the page's own ids."""
    assert not [t for t, _ in page.tags if t in ("link", "iframe", "object", "embed", "base")]
    ids = page.ids()
    for tag, attrs in page.tags:
        for name in ("src", "href", "srcset", "data", "poster", "action"):
            if name not in attrs:
                continue
            v = attrs[name]
            if tag == "img" and name == "src":
                assert v.startswith("data:image/png;base64,"), v[:60]
                assert base64.b64decode(v.split(",", 1)[1]).startswith(b"\x89PNG\r\n\x1a\n")
            elif name == "href":
                assert v.startswith("#") and v[1:] in ids, v
            else:
                raise AssertionError(f"<{tag} {name}={v[:60]!r}>")
    assert not [a for t, a in page.tags if t == "script" and "src" in a]
    assert "url(" not in page.text and "@import" not in page.text  # nothing fetched by the style sheet


def _markdown_twin(md: str, out: Path, page: Page) -> None:
    """Every PNG the Markdown links exists beside it, one per image of the HTML, same sections."""
    links = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", md)
    assert len(links) == len(page.images()) > 0
    for link in links:
        assert not link.startswith(("http:", "https:", "/"))
        assert (out / link).read_bytes().startswith(b"\x89PNG")
    anchors = set(re.findall(r'<a id="([^"]+)"></a>', md))
    assert anchors == _sections(page)


def test_sweep_csv_report_is_one_self_contained_file_with_its_markdown_twin(sweep_dir, sweep_report, capsys):
    page = Page((sweep_report / "report.html").read_text())
    md = (sweep_report / "report.md").read_text()
    _self_contained(page)
    _markdown_twin(md, sweep_report, page)
    header = next(csv.reader((sweep_dir / "sweep.csv").open()))
    pairs = any(PAIR.match(c) and PAIR.sub(r"\1_measured\2", c) in header for c in header)
    # a number and a name swept, bags kept: every section but the one whose data may be missing
    expected = TOP if pairs else TOP - {"predicted-against-measured"}
    assert _sections(page) & TOP == expected
    # swept keys read from the sweep's column naming: the key paths, seed, run_hash
    # (tables name them by their shortest distinct ending, the overview's legend by the whole path)
    assert page.row("delay_s", DELAY, "number", "0.01, 0.1")
    assert page.row("policy", POLICY, "category", "none, adaptive")
    assert page.rows[[r[:1] for r in page.rows].index(["run"])][1:3] == ["delay_s", "policy"]
    # drill-down capped at one run (the table's first, named by its hash): forces, positions, network
    rows = _rows(sweep_dir / "sweep.csv")
    first = rows[0]["run_hash"][:12]
    drill = [a for a in page.images() if a["alt"].startswith(f"{first}:")]
    assert [a["alt"] for a in drill] == [f"{first}: forces", f"{first}: positions", f"{first}: network"]
    assert "the first 1 of 4" in md
    # the overview's numbers are the table's
    row = rows[1]
    cells = page.row(row["run_hash"][:12])
    assert f"{float(row['force_rms_error_n']):.4g}" in cells


def test_synthetic_table_predictions_and_pairs_by_seed(sweep_dir, tmp_path, capsys):
    from haptic_teleop.studies.document.inputs import read_inputs

    table = tmp_path / "tables" / "results.csv"
    table.parent.mkdir()
    bag = sweep_dir / "runs" / _rows(sweep_dir / "sweep.csv")[2]["run_hash"] / "bag"
    _synthetic(table, bag)
    page, md = _report([str(table), "--baseline", "none", "--max-runs", "0"], tmp_path / "out", capsys)
    _self_contained(page)
    _markdown_twin(md, tmp_path / "out", page)
    assert _sections(page) & TOP == TOP - {"per-run-drill-down"}  # --max-runs 0
    # keys swept together are one key
    assert page.row("delay_s", f"{DELAY}+network.forward.effects.delay.delay_s", "number", "0, 0.2")
    # predicted against measured: one pair; measured - predicted = 0.05 in every run
    slope = page.row("force_slope (N/s)", "12")
    assert slope[1:3] == ["12", "2.1"] and slope[4:7] == ["0.05", "0.05", "0.05"]
    assert not [r for r in page.rows if r and r[0].startswith("force_drop")]
    # paired by seed: exactly +0.25 with no spread, although the seeds spread each policy by 1 N
    diff = page.row("transparency", "force_rms_error_n (N)")
    assert diff[2:4] == ["6", "0.25 ± 0"]
    unpaired = statistics.stdev(s + 0.25 + d for d in (0.0, 0.2) for s in (1, 2, 3))
    assert f"± {unpaired:.4g} " in page.row("transparency", "6")[2]  # unpaired: the seeds' spread
    # bag_path is taken relative to the table's directory, else found in runs/<run_hash>/
    second = table.parent / "runs" / "0n20000000000000" / "bag"
    shutil.copytree(bag, second)
    runs = read_inputs([table]).runs
    assert [r.bag for r in runs] == [bag.resolve(), second, *[None] * 10]


def test_sections_absent_without_their_data(tmp_path, capsys):
    table = tmp_path / "plain.csv"
    table.write_text(
        f"{POLICY},seed,run_hash,force_rms_error_n\nnone,1,a1,1.0\nnone,2,a2,2.0\nfixed,1,b1,1.5\nfixed,2,b2,2.5\n"
    )
    page, md = _report([str(table), "--max-runs", "3"], tmp_path / "out", capsys)
    _self_contained(page)
    _markdown_twin(md, tmp_path / "out", page)
    assert _sections(page) & TOP == {"overview", "comparisons-per-category"}
    assert page.row("fixed", "force_rms_error_n (N)")[2:4] == ["2", "0.5 ± 0"]


def test_run_directory_and_bare_bag_read_like_the_sweep(sweep_dir, tmp_path, capsys):
    from haptic_teleop.studies.document.inputs import read_inputs

    rows = _rows(sweep_dir / "sweep.csv")
    names = (rows[0]["run_hash"], rows[3]["run_hash"])
    bag = tmp_path / "elsewhere" / "bag"
    shutil.copytree(sweep_dir / "runs" / names[1] / "bag", bag)  # no summary.json beside it
    inputs = read_inputs([sweep_dir / "runs" / names[0], bag])
    table = {r["run_hash"]: r for r in rows}
    for run, name in zip(inputs.runs, names, strict=True):
        assert run.seed == int(table[name]["seed"])
        assert run.params[DELAY] == float(table[name][DELAY])
        assert run.params[POLICY] == table[name][POLICY]
        for m in ("force_rms_error_n", "late_loss_rate_backward", "buffering_delay_backward_mean_s"):
            assert math.isclose(run.metrics[m], float(table[name][m]), rel_tol=1e-12, abs_tol=1e-15), m
    page, _ = _report([str(sweep_dir / "runs" / names[0]), str(bag), "--max-runs", "0"], tmp_path / "o", capsys)
    assert _sections(page) & TOP == {"overview", "metrics-against-parameters", "comparisons-per-category"}


def test_parquet_table_reads_like_its_csv(sweep_dir, tmp_path, capsys):
    from haptic_teleop.studies.document.inputs import read_inputs

    table = tmp_path / "results.csv"
    _synthetic(table, None)
    try:
        import pyarrow.csv as pacsv
        import pyarrow.parquet as pq
    except ImportError:
        (tmp_path / "results.parquet").write_bytes(b"PAR1")
        assert main(["report", str(tmp_path / "results.parquet"), "--out", str(tmp_path / "o"), "--quiet"]) == 2
        err = capsys.readouterr().err
        assert "pip install haptic_teleop[sweep]" in err and len(err.strip().splitlines()) == 1
        return
    pq.write_table(pacsv.read_csv(table), tmp_path / "results.parquet")
    a = read_inputs([table]).runs
    b = read_inputs([tmp_path / "results.parquet"]).runs
    assert [(r.params, r.seed, r.metrics) for r in a] == [(r.params, r.seed, r.metrics) for r in b]


@pytest.mark.parametrize(
    ("make", "extra", "says"),
    [
        (None, [], "no such file or directory"),
        ("notes.txt", [], "neither a results table nor a bag"),
        ("strings.csv", [], "no metric columns"),
        ("emptydir", [], "neither a results table"),
        ("plain.csv", ["--metrics", "force_rms_eror_n"], "--metrics force_rms_eror_n: not a metric"),
        ("plain.csv", ["--baseline", "fixd"], "--baseline fixd: not a value of a categorical swept key"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, make, extra, says):
    path = tmp_path / (make or "missing.csv")
    if make == "notes.txt":
        path.write_text("hello\n")
    elif make == "strings.csv":
        path.write_text(f"{POLICY},run_hash,engine_loop\nnone,a1,compiled\n")
    elif make == "emptydir":
        path.mkdir()
    elif make == "plain.csv":
        path.write_text(f"{POLICY},seed,force_rms_error_n\nnone,1,1.0\nfixed,1,2.0\n")
    out = tmp_path / "out"
    assert main(["report", str(path), *extra, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert says in err and err.startswith("haptic-teleop: ") and len(err.strip().splitlines()) == 1, err
    assert not out.exists()


def _chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


def _drawn(html: Path, profile: Path) -> Page:
    """The DOM after headless Chromium loaded the page and its script marked the drawn images."""
    got = subprocess.run(
        [_chromium(), "--headless", "--disable-gpu", "--no-sandbox", "--no-first-run", f"--user-data-dir={profile}",
         "--dump-dom", html.as_uri()],
        capture_output=True, text=True, timeout=60, check=True,
    )  # fmt: skip
    return Page(got.stdout)


@pytest.mark.skipif(_chromium() is None, reason="no chromium or chromium-browser on PATH (Debian package chromium)")
def test_every_plot_is_drawn_in_a_browser(sweep_report, tmp_path):
    html = sweep_report / "report.html"
    page = _drawn(html, tmp_path / "profile")
    images = page.images()
    check = next(a for t, a in page.tags if a.get("id") == "plot-check")
    assert len(images) == len(Page(html.read_text()).images()) > 0
    assert [a.get("data-drawn") for a in images] == ["yes"] * len(images)
    assert check["data-drawn"] == check["data-total"] == str(len(images))
    # the check sees a plot that is not drawn: one image's PNG cut short
    text = html.read_text()
    start = text.index("data:image/png;base64,") + len("data:image/png;base64,")
    broken = tmp_path / "broken.html"
    broken.write_text(text[:start] + "iVBORw0KGgo" + text[text.index('"', start) :])
    page = _drawn(broken, tmp_path / "profile")
    assert [a.get("data-drawn") for a in page.images()] == ["no"] + ["yes"] * (len(images) - 1)


def test_the_report_takes_the_metrics_the_sweep_file_lists(sweep_dir, tmp_path, capsys):
    """A sweep writes the metrics it was asked for (the sweep file's `metrics:`, --metrics, or its
    defaults) to sweep.json beside its table, and a report on the sweep takes those, in their order,
    unless --metrics says otherwise."""
    import json
    import shutil

    meta = json.loads((sweep_dir / "sweep.json").read_text())
    assert meta["metrics"] and all(isinstance(m, str) for m in meta["metrics"])
    mine = tmp_path / "sweep"
    shutil.copytree(sweep_dir, mine)
    chosen = ["packets_sent_backward", "contact_force_max_n"]
    (mine / "sweep.json").write_text(json.dumps({"metrics": chosen}))
    _, md = _report([str(mine), "--max-runs", "0"], tmp_path / "r1", capsys)
    assert "Metrics shown: `packets_sent_backward`, `contact_force_max_n`: the metrics the sweep file lists" in md
    _, md = _report([str(mine), "--max-runs", "0", "--metrics", "force_rms_error_n"], tmp_path / "r2", capsys)
    assert "the metrics given by --metrics" in md and "the metrics the sweep file lists" not in md


def test_short_names_are_the_shortest_distinct_endings():
    from haptic_teleop.studies.document.compose import short_names

    names = ["network.forward.effects.delay.delay_s", "network.backward.effects.delay.delay_s",
             "network.backward.buffer.policy", "seed_like", "a.b"]  # fmt: skip
    assert short_names(names) == {
        "network.forward.effects.delay.delay_s": "forward.effects.delay.delay_s",
        "network.backward.effects.delay.delay_s": "backward.effects.delay.delay_s",
        "network.backward.buffer.policy": "policy",
        "seed_like": "seed_like",
        "a.b": "b",
    }
