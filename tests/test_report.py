"""``hil report`` and ``hil compare`` on synthetic folders of the contract's format: sections,
self-contained HTML, figures as data, verdict and exit codes."""

from __future__ import annotations

import base64
import io
import json
import re
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.image as mpimg
import matplotlib.pyplot as plt
import numpy as np
import pytest

from hil.cli import main
from hil.report.synthetic import write_synthetic_folder

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
VOID = {"meta", "img", "br", "hr", "link", "input", "col", "source", "area", "base", "wbr"}
RUN_SECTIONS = {
    "trajectory",
    "velocities",
    "torques",
    "tracking_error",
    "bands",
    "latency",
    "lateness",
    "timing_summary",
    "verdict",
}


class Checker(HTMLParser):
    """Records well-formedness problems, network references and embedded images."""

    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.stack: list[str] = []
        self.errors: list[str] = []
        self.remote: list[str] = []
        self.images: list[str] = []
        self.scripts = 0
        self.section_ids: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = dict(attrs)
        for key in ("src", "href", "data", "action", "poster"):
            value = a.get(key) or ""
            if re.match(r"\s*(https?:)?//", value, re.I):
                self.remote.append(f"{tag} {key}={value}")
        if tag == "script":
            self.scripts += 1
        if tag == "link":
            self.remote.append(f"link {a}")
        if tag == "img":
            self.images.append(a.get("src") or "")
        if tag == "section":
            self.section_ids.append(a.get("id") or "")
        if tag not in VOID:
            self.stack.append(tag)

    def handle_endtag(self, tag: str) -> None:
        if tag in VOID:
            return
        if not self.stack or self.stack[-1] != tag:
            self.errors.append(f"unbalanced </{tag}> with open {self.stack[-3:]}")
            return
        self.stack.pop()

    def handle_data(self, data: str) -> None:
        if re.search(r"url\(\s*['\"]?(https?:)?//", data) or "@import" in data:
            self.remote.append(data[:80])


def check_html(path: Path) -> Checker:
    c = Checker()
    c.feed(path.read_text())
    c.close()
    assert not c.errors, c.errors
    assert not c.stack, f"unclosed tags {c.stack}"
    assert c.remote == [], c.remote
    assert c.scripts == 0
    return c


def blank_png_size(width: int, height: int) -> int:
    fig = plt.figure(figsize=(width / 90, height / 90), dpi=90)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    return len(buf.getvalue())


def check_images(c: Checker) -> None:
    assert c.images
    for src in c.images:
        assert src.startswith("data:image/png;base64,"), src[:40]
        raw = base64.b64decode(src.split(",", 1)[1], validate=True)
        assert raw.startswith(PNG_SIGNATURE)
        pixels = mpimg.imread(io.BytesIO(raw), format="png")
        h, w = pixels.shape[:2]
        assert len(raw) > blank_png_size(w, h), "figure no bigger than a blank image"
        assert float(np.std(pixels[..., :3])) > 0.01


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_synthetic_folder(tmp_path_factory.mktemp("run") / "run", run=True, delay=0.0005)


def test_report_of_a_run_folder_has_every_section(run_folder: Path) -> None:
    before = (run_folder / "summary.json").read_bytes()
    assert main(["report", str(run_folder), "--no-ideal"]) == 0
    assert (run_folder / "summary.json").read_bytes() == before, "summary.json was rewritten"
    c = check_html(run_folder / "report.html")
    assert set(c.section_ids) == RUN_SECTIONS
    check_images(c)
    data = json.loads((run_folder / "report.json").read_text())
    assert set(data["sections"]) == RUN_SECTIONS
    assert data["verdict"]["ok"] is True
    assert data["certificate"]["timing_source"] == "measured"
    # the certificate is evaluated at the measured worst gap and delay, not the nominal ones
    assert data["certificate"]["ts"] > 1e-3 and data["certificate"]["delay"] >= 5e-4
    assert set(data["timing"]["latency_percentiles_us"]) == {"zenoh", "can"}


def test_every_figure_is_written_as_data_beside_its_picture(run_folder: Path) -> None:
    assert main(["report", str(run_folder), "--no-ideal"]) == 0
    data = json.loads((run_folder / "report.json").read_text())
    md = (run_folder / "report.md").read_text()
    assert len(data["figures"]) >= 9
    for f in data["figures"]:
        png, csv_file = run_folder / f["png"], run_folder / f["data"]
        assert png.read_bytes().startswith(PNG_SIGNATURE)
        lines = csv_file.read_text().splitlines()
        assert len(lines) >= 2 and lines[0].strip(), f["data"]
        assert f"]({f['png']})" in md
    trace_rows = len((run_folder / "trace.csv").read_text().splitlines())
    v_rows = len((run_folder / "report_v.csv").read_text().splitlines())
    assert v_rows == trace_rows, "the v data file must hold every sample, not the decimated plot"


def test_report_figures_match_the_trace(run_folder: Path) -> None:
    main(["report", str(run_folder), "--no-ideal"])
    data = json.loads((run_folder / "report.json").read_text())
    trace = np.genfromtxt(run_folder / "trace.csv", delimiter=",", names=True)
    assert data["metrics"]["constraints"]["v"]["peak"] == pytest.approx(np.abs(trace["v"]).max())
    lat = trace["zenoh_latency_us"]
    assert data["timing"]["latency_percentiles_us"]["zenoh"]["p99"] == np.percentile(lat, 99)
    band = data["metrics"]["bands"]["v_tilde"]
    assert band["band_max"] == pytest.approx(3.3 * 1.5e-3 / 2)


def test_simulation_folder_report_and_limit_broken_exit_1(tmp_path: Path) -> None:
    good = write_synthetic_folder(tmp_path / "good")
    assert main(["report", str(good), "--no-ideal"]) == 0
    c = check_html(good / "report.html")
    assert "latency" not in c.section_ids and "verdict" in c.section_ids
    bad = write_synthetic_folder(tmp_path / "bad", overshoot=1.5)
    assert main(["report", str(bad), "--no-ideal"]) == 1
    v = json.loads((bad / "report.json").read_text())["verdict"]
    assert v["limits"] == "broken" and "v" in v["limits_broken"]
    assert "FAIL" in (bad / "report.html").read_text()


def test_beyond_the_certified_bound_is_negative_though_within_limits(tmp_path: Path) -> None:
    folder = write_synthetic_folder(tmp_path / "f", overshoot=0.5)  # |v| 1.2 < phi1, > bound
    assert main(["report", str(folder), "--no-ideal"]) == 1
    v = json.loads((folder / "report.json").read_text())["verdict"]
    assert v["limits"] == "held" and v["certificate"] == "broken"


def test_lost_messages_over_threshold_are_negative(tmp_path: Path) -> None:
    folder = write_synthetic_folder(tmp_path / "f", run=True)
    summary = json.loads((folder / "summary.json").read_text())
    summary["messages"]["lost"] = summary["messages"]["sent"] // 10
    (folder / "summary.json").write_text(json.dumps(summary))
    assert main(["report", str(folder), "--no-ideal"]) == 1
    assert main(["report", str(folder), "--no-ideal", "--max-lost-ratio", "0.2"]) == 0


@pytest.mark.parametrize("damage", ["missing", "no_trace", "bad_cell", "bad_json", "no_column"])
def test_not_a_run_folder_exits_2(tmp_path: Path, damage: str) -> None:
    folder = write_synthetic_folder(tmp_path / "f", duration=0.5)
    if damage == "missing":
        folder = tmp_path / "nothing"
    elif damage == "no_trace":
        (folder / "trace.csv").unlink()
    elif damage == "bad_cell":
        with open(folder / "trace.csv", "a") as f:
            f.write("oops" + ",1" * 14 + "\n")
    elif damage == "bad_json":
        (folder / "summary.json").write_text("{not json")
    elif damage == "no_column":
        text = (folder / "trace.csv").read_text().replace("tau2,", "tauX,", 1)
        (folder / "trace.csv").write_text(text)
    assert main(["report", str(folder), "--no-ideal"]) == 2
    assert not (folder / "report.html").exists()


def test_exit_codes_through_the_installed_command(tmp_path: Path) -> None:
    bad = write_synthetic_folder(tmp_path / "bad", duration=0.5, overshoot=1.5)
    cmd = [sys.executable, "-m", "hil", "report", "--no-ideal"]
    assert subprocess.run([*cmd, str(bad)], capture_output=True).returncode == 1
    assert subprocess.run([*cmd, str(tmp_path / "none")], capture_output=True).returncode == 2


def test_compare_two_folders(tmp_path: Path, run_folder: Path) -> None:
    other = write_synthetic_folder(tmp_path / "slow", rate=200.0, delay=0.002)
    out = tmp_path / "cmp"
    assert main(["compare", str(run_folder), str(other), "--out", str(out)]) == 0
    c = check_html(out / "compare.html")
    check_images(c)
    data = json.loads((out / "compare.json").read_text())
    rows = {r["figure"]: r for r in data["rows"]}
    assert rows["ts"]["a"] == pytest.approx(1e-3) and rows["ts"]["b"] == pytest.approx(5e-3)
    assert rows["ts"]["b_minus_a"] == pytest.approx(4e-3)
    assert rows["band_p99.v_tilde"]["b"] > rows["band_p99.v_tilde"]["a"]
    for f in data["figures"]:
        assert (out / f["png"]).is_file() and (out / f["data"]).is_file()
    assert main(["compare", str(run_folder), str(tmp_path / "none"), "--out", str(out)]) == 2
