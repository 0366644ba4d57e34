"""``hil report`` and ``hil compare`` on synthetic folders of the contract's format: sections,
self-contained HTML, figures as data, verdict and exit codes."""

from __future__ import annotations

import base64
import io
import json
import re
import shutil
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

from hil.analysis.report.build import SOURCE
from hil.cli import main
from hil.sim.certificate import CONTRACT_KEYS
from hil.verdict import Verdict
from tests.page_tables import numbers_without_unit, tables, unglossed
from tests.run_helpers import PASSES, expected_exit
from tests.synthetic_folder import write_synthetic_folder

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
VOID = {"meta", "img", "br", "hr", "link", "input", "col", "source", "area", "base", "wbr"}
SIM_SECTIONS = {
    "headline",
    "terms",
    "verdict",
    "certificate",
    "trajectory",
    "velocities",
    "torques",
    "tracking_error",
    "bands",
}
# A simulation ran no CAN drives: no section for them (the synthetic run has its drives' counters).
RUN_SECTIONS = SIM_SECTIONS | {"drives", "latency", "lateness", "messages", "timing_summary"}


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


@pytest.fixture(scope="module")
def stall_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A run that lost 30 ms of Zenoh commands at t = 2 s: D > D*."""
    return write_synthetic_folder(
        tmp_path_factory.mktemp("stall") / "run", run=True, stall=(2.0, 0.03)
    )


def test_report_of_a_run_folder_has_every_section(run_folder: Path) -> None:
    before = (run_folder / "summary.json").read_bytes()
    assert main(["report", str(run_folder), "--no-ideal"]) == 0
    assert (run_folder / "summary.json").read_bytes() == before, "summary.json was rewritten"
    c = check_html(run_folder / "report.html")
    assert c.section_ids == [
        "headline",
        "terms",
        "verdict",
        "certificate",
        "trajectory",
        "velocities",
        "torques",
        "drives",
        "tracking_error",
        "bands",
        "latency",
        "lateness",
        "messages",
        "timing_summary",
    ]
    check_images(c)
    data = json.loads((run_folder / "report.json").read_text())
    assert set(data["sections"]) == RUN_SECTIONS
    assert data["kind"] == "run" and data["verdict"]["ok"] is True
    assert data["timing"]["source"] == SOURCE
    summary = json.loads((run_folder / "summary.json").read_text())
    assert data["timing"]["summary"] == summary["timing"]  # read, never measured again
    names = {f["name"] for f in data["figures"]}
    assert {"latency", "lateness", "command_age", "bands", "motor_torques"} <= names


def test_the_certificate_is_summary_jsons_not_the_worst_of_both_paths(run_folder: Path) -> None:
    """The CAN shadow lands later than the applied Zenoh commands: a report that took the
    worst delay of any path would disagree with summary.json. It must not."""
    assert main(["report", str(run_folder), "--no-ideal"]) == 0
    summary = json.loads((run_folder / "summary.json").read_text())
    data = json.loads((run_folder / "report.json").read_text())
    for key in CONTRACT_KEYS:
        assert data["certificate"][key] == summary["certificate"][key], key
    assert data["certificate"]["path"] == "zenoh"
    t = summary["timing"]
    assert t["command_age_can"]["max_us"] > t["command_age_zenoh"]["max_us"]
    assert data["certificate"]["d_max_s"] == t["command_age_zenoh"]["max_us"] / 1e6
    # every timing figure the report shows is summary.json's
    assert data["timing"]["summary"] == t
    assert data["timing"]["messages"] == summary["messages"]


def test_the_shadow_path_never_enters_the_verdict(tmp_path: Path, run_folder: Path) -> None:
    folder = tmp_path / "run"
    shutil.copytree(run_folder, folder)
    summary = json.loads((folder / "summary.json").read_text())
    can = summary["messages"]["torque_can"]
    can["lost"], can["received"] = can["sent"], 0  # every shadow command lost
    (folder / "summary.json").write_text(json.dumps(summary))
    assert main(["report", str(folder), "--no-ideal"]) == 0
    v = json.loads((folder / "report.json").read_text())["verdict"]
    assert v["ok"] and v["lost_messages"] == 0
    assert v["timing"]["lost_messages"]["streams"] == ["state", "torque_zenoh"]


def _first_lines(folder: Path, n: int = 8) -> str:
    return "\n".join((folder / "report.md").read_text().splitlines()[:n])


def test_the_report_answers_first(run_folder: Path) -> None:
    assert main(["report", str(run_folder), "--no-ideal"]) == 0
    summary = json.loads((run_folder / "summary.json").read_text())
    head = _first_lines(run_folder)
    # 1. the limits of (2), each peak as a share of its limit
    assert "Limits of (2) held" in head
    for key, limit in (("v", 1.6), ("omega", 5.1), ("tau1", 3.3), ("tau2", 51.0)):
        peak = summary[f"max_abs_{key}"]
        assert f"= {peak:.4g} " in head, key
        assert f"{100 * peak / limit:.1f} %" in head, key
    # 2. D against D* and the margin
    cert = summary["certificate"]
    assert f"D = {cert['d_max_s'] * 1e3:.3f} ms" in head
    assert f"D* = {cert['d_star_s'] * 1e3:.3f} ms" in head
    assert f"margin {cert['margin_s'] * 1e3:.3f} ms" in head
    assert "certificate held" in head
    # 3. the stalls (none here) and 4. the share of samples without a command
    assert "Stalls: none" in head and f"{cert['stall_threshold_s'] * 1e3:.3f} ms" in head
    t = summary["timing"]
    n, judged = t["samples_without_command"], t["samples_judged"]
    assert f"Samples without a command: {n} of {judged} " in head
    assert f"({100 * t['samples_without_command_rate']:.3f} %)" in head
    data = json.loads((run_folder / "report.json").read_text())
    h = data["headline"]
    assert h["verdict"] == "PASS"
    assert h["command_age"]["d_max_s"] == cert["d_max_s"]
    assert h["limits"]["v"]["max"] == summary["max_abs_v"]
    assert h["samples_without_command"]["rate"] == t["samples_without_command_rate"]
    # the HTML says the same first
    html = (run_folder / "report.html").read_text()
    assert html.index('id="headline"') < html.index('id="verdict"') < html.index('id="trajectory"')
    assert f"D = {cert['d_max_s'] * 1e3:.3f} ms" in html[: html.index('id="terms"')]


def test_the_report_says_what_its_words_mean(run_folder: Path) -> None:
    assert main(["report", str(run_folder), "--no-ideal"]) == 0
    md = (run_folder / "report.md").read_text()
    assert md.count("Model (1) is normalized: v' = τ1 + d1 and ω' = τ2 + d2") == 1
    assert "although the paper labels τ1, τ2 in N·m" in md
    assert "The constraints (2) are" in md
    assert "The tracking errors (4) are" in md
    assert "The certificate is" in md


def test_a_stall_beyond_d_star_is_negative_and_named(stall_folder: Path) -> None:
    assert main(["report", str(stall_folder), "--no-ideal"]) == 1
    summary = json.loads((stall_folder / "summary.json").read_text())
    cert = summary["certificate"]
    data = json.loads((stall_folder / "report.json").read_text())
    for key in CONTRACT_KEYS:
        assert data["certificate"][key] == cert[key], key
    v = data["verdict"]
    assert v["limits"] == "held" and v["certificate"] == "not held"
    # at D the sampled |w| bound passes phi2: the condition that fails is named
    assert data["certificate"]["failed_conditions"] == ["sampled |w| bound <= phi2"]
    assert v["reasons"] == [
        f"certificate not held: command age D = {cert['d_max_s'] * 1e3:.3f} ms > "
        f"D* = {cert['d_star_s'] * 1e3:.3f} ms on the zenoh path "
        f"(margin {cert['margin_s'] * 1e3:.3f} ms; failing: sampled |ω| bound <= φ2) "
        f"by the system's own timing; worst: t = {cert['stalls'][0]['t_s']:.3f} s, "
        f"{cert['stalls'][0]['age_s'] * 1e3:.3f} ms, {cert['stalls'][0]['cause']}"
    ]
    assert v["outcome"] == "FAIL" and cert["stalls"][0]["owner"] == "system"
    assert cert["omega_bound"] > 5.1
    assert cert["d_max_s"] > cert["d_star_s"] > 0
    stall = cert["stalls"][0]
    assert stall["cause"] == "command_lost" and 2.0 <= stall["t_s"] <= 2.05
    head = _first_lines(stall_folder)
    assert "certificate NOT held (D > D*)" in head
    assert (
        f"t = {stall['t_s']:.3f} s, age {stall['age_s'] * 1e3:.3f} ms, cause command_lost" in head
    )
    assert "Verdict: FAIL" in head
    check_html(stall_folder / "report.html")


def test_timing_thresholds_name_their_numbers(tmp_path: Path, stall_folder: Path) -> None:
    folder = tmp_path / "run"
    shutil.copytree(stall_folder, folder)
    t = json.loads((folder / "summary.json").read_text())["timing"]
    args = ["report", str(folder), "--no-ideal", "--max-samples-without-command-ratio", "0.001"]
    assert main([*args, "--max-lost-ratio", "0.5"]) == 1
    reasons = json.loads((folder / "report.json").read_text())["verdict"]["reasons"]
    n, judged, rate = (
        t["samples_without_command"],
        t["samples_judged"],
        t["samples_without_command_rate"],
    )
    assert f"samples without a command: {n} of {judged} ({100 * rate:.3f} %) > 0.100 %" in reasons
    assert main(["report", str(folder), "--no-ideal", "--max-lost-ratio", "0.001"]) == 1
    reasons = json.loads((folder / "report.json").read_text())["verdict"]["reasons"]
    lost = [r for r in reasons if r.startswith("lost messages")]
    m = json.loads((folder / "summary.json").read_text())["messages"]
    st, z = m["state"], m["torque_zenoh"]
    sent, gone = st["sent"] + z["sent"], st["lost"] + z["lost"]
    assert z["lost"] == 30  # the injected losses, all inside the window
    assert lost == [
        f"lost messages: {gone} of {sent} ({100 * gone / sent:.3f} %) > 0.100 % "
        f"(state {st['lost']} of {st['sent']}, torque_zenoh {z['lost']} of {z['sent']})"
    ]


def test_every_figure_is_written_as_data_beside_its_picture(run_folder: Path) -> None:
    assert main(["report", str(run_folder), "--no-ideal"]) == 0
    data = json.loads((run_folder / "report.json").read_text())
    md = (run_folder / "report.md").read_text()
    assert len(data["figures"]) >= 11
    for f in data["figures"]:
        png, csv_file = run_folder / f["png"], run_folder / f["data"]
        assert png.read_bytes().startswith(PNG_SIGNATURE)
        lines = csv_file.read_text().splitlines()
        assert len(lines) >= 2 and lines[0].strip(), f["data"]
        assert f"]({f['png']})" in md
    trace_rows = len((run_folder / "trace.csv").read_text().splitlines())
    v_rows = len((run_folder / "report_v.csv").read_text().splitlines())
    assert v_rows == trace_rows, "the v data file must hold every sample, not the decimated plot"


def test_report_figures_match_the_trace_and_the_measurement(run_folder: Path) -> None:
    from hil.analysis.measure.folder import measure_folder
    from protocol.can.wheel_mapping import RobotGeometry, motor_torques

    main(["report", str(run_folder), "--no-ideal"])
    data = json.loads((run_folder / "report.json").read_text())
    trace = np.genfromtxt(run_folder / "trace.csv", delimiter=",", names=True)
    assert data["metrics"]["constraints"]["v"]["peak"] == pytest.approx(np.abs(trace["v"]).max())
    band = data["metrics"]["bands"]["v_tilde"]
    assert band["band_max"] == pytest.approx(3.3 * 1.5e-3 / 2)
    assert data["metrics"]["saturation_share"] == {"tau1": 1.0, "tau2": 1.0}
    # the latency plot draws hil.analysis.measure's samples; their exact percentiles are the
    # summary's
    lat = np.genfromtxt(run_folder / "report_latency.csv", delimiter=",", names=True)
    zen = lat["zenoh_sorted_us"][np.isfinite(lat["zenoh_sorted_us"])]
    m = measure_folder(run_folder)
    assert np.array_equal(zen, np.sort(m.latency_us()["zenoh"]))
    s = json.loads((run_folder / "summary.json").read_text())["timing"]["sample_to_apply_zenoh"]
    assert s["count"] == zen.size
    for key, q in (("p50_us", 50.0), ("p99_us", 99.0), ("p999_us", 99.9)):
        assert np.percentile(zen, q, method="inverted_cdf") == s[key]
    assert zen.max() == s["max_us"]
    # the drives get the wheel mapping of the applied torques
    q = np.genfromtxt(run_folder / "report_motor_torques.csv", delimiter=",", names=True)
    qr, ql = motor_torques(RobotGeometry(), trace["tau1"], trace["tau2"])
    assert np.allclose(q["right"], qr) and np.allclose(q["left"], ql)
    assert data["drives"]["max_abs_q_right_nm"] == pytest.approx(np.abs(qr).max())
    assert data["drives"]["rejection_counts"] == {"controller": 0, "plant": 0, "drives": 0}
    # v~ and w~ on separate axes
    bands = np.genfromtxt(run_folder / "report_bands.csv", delimiter=",", names=True)
    assert {"v_tilde", "w_tilde", "v_tilde_t", "w_tilde_t"} <= set(bands.dtype.names)


def test_simulation_folder_report_and_limit_broken_exit_1(tmp_path: Path) -> None:
    good = write_synthetic_folder(tmp_path / "good")
    assert main(["report", str(good), "--no-ideal"]) == 0
    c = check_html(good / "report.html")
    assert set(c.section_ids) == SIM_SECTIONS
    data = json.loads((good / "report.json").read_text())
    cert = data["certificate"]
    assert cert["d_max_s"] == pytest.approx(1e-3)  # Ts + worst delay of the scenario
    assert cert["d_star_s"] > cert["d_max_s"] and cert["held"] is True
    assert "Samples without a command: none in a simulation" in _first_lines(good)
    bad = write_synthetic_folder(tmp_path / "bad", overshoot=1.5)
    assert main(["report", str(bad), "--no-ideal"]) == 1
    data = json.loads((bad / "report.json").read_text())
    v = data["verdict"]
    assert v["limits"] == "broken" and "v" in v["limits_broken"]
    n = json.loads((bad / "summary.json").read_text())["violations"]["v"]
    peak = data["metrics"]["constraints"]["v"]["peak"]
    assert (
        f"limits of (2) broken: |v| beyond φ1 = 1.6 m/s at {n} plant steps "
        f"(max |v| = {peak:.4g} m/s, {100 * peak / 1.6:.1f} % of φ1)"
    ) in v["reasons"]
    assert "Limits of (2) BROKEN" in _first_lines(bad)
    assert "FAIL" in (bad / "report.html").read_text()


def test_beyond_the_certified_bound_is_negative_though_within_limits(tmp_path: Path) -> None:
    folder = write_synthetic_folder(tmp_path / "f", overshoot=0.5)  # |v| 1.2 < phi1, > bound
    assert main(["report", str(folder), "--no-ideal"]) == 1
    data = json.loads((folder / "report.json").read_text())
    v = data["verdict"]
    assert v["limits"] == "held" and v["certificate"] == "broken"
    peak, bound = data["metrics"]["constraints"]["v"]["peak"], data["certificate"]["v_bound"]
    assert v["reasons"] == [
        f"measured beyond the sampled-data bound: max |v| = {peak:.4g} m/s > {bound:.4g} m/s"
    ]


def test_a_design_that_breaks_the_papers_conditions_names_them(tmp_path: Path) -> None:
    folder = write_synthetic_folder(tmp_path / "f", duration=0.5)
    toml = folder / "scenario.resolved.toml"
    toml.write_text(toml.read_text().replace("m1 = 0.5", "m1 = 1.3"))  # (9): m1 < phi1 - mu1
    assert main(["report", str(folder), "--no-ideal"]) == 1
    data = json.loads((folder / "report.json").read_text())
    cert = data["certificate"]
    assert cert["d_star_s"] == 0.0 and cert["held"] is False
    assert "(9) m1 < phi1 - mu1" in cert["failed_conditions"]
    (reason,) = data["verdict"]["reasons"]
    assert reason.startswith("certificate not held: command age D = 1.000 ms > D* = 0.000 ms")
    assert "(9) m1 < φ1 - mu1" in reason  # the page's symbols (hil.limits.in_symbols)


def test_lost_messages_over_threshold_are_negative(tmp_path: Path, run_folder: Path) -> None:
    folder = tmp_path / "run"
    shutil.copytree(run_folder, folder)
    summary = json.loads((folder / "summary.json").read_text())
    summary["messages"]["torque_zenoh"]["lost"] = summary["messages"]["torque_zenoh"]["sent"] // 10
    (folder / "summary.json").write_text(json.dumps(summary))
    assert main(["report", str(folder), "--no-ideal"]) == 1
    data = json.loads((folder / "report.json").read_text())
    # summary.json's figures are the run's one measurement: the report reads, never re-measures
    assert data["timing"]["messages"] == summary["messages"]
    assert main(["report", str(folder), "--no-ideal", "--max-lost-ratio", "0.2"]) == 0


def test_ideal_trajectory_of_a_trace_that_starts_late(tmp_path: Path) -> None:
    """The ideal simulation starts from the trace's first state and time, wherever that is."""
    from hil.analysis.report.ideal import ideal_from_simulator
    from hil.folder import load_folder

    folder = write_synthetic_folder(tmp_path / "late", start=0.5, duration=1.0, rate=200.0)
    loaded = load_folder(folder)
    ideal = ideal_from_simulator(loaded)
    assert ideal is not None
    tr = loaded.trace
    assert tr["t"][0] == 0.5 and ideal["t"][0] == 0.5
    assert ideal["t"][-1] == pytest.approx(tr["t"][-1], abs=5e-4)  # Ts/10 = 0.5 ms
    for k in ("x", "y", "theta"):
        assert ideal[k][0] == tr[k][0]
    assert main(["report", str(folder)]) == 0
    data = json.loads((folder / "report.json").read_text())
    m = data["metrics"]
    assert m["deviation_from_ideal_note"].startswith("simulated at Ts/10 from the trace's first")
    assert "t = 0.5 s" in m["deviation_from_ideal_note"]
    assert m["deviation_from_ideal"] is not None
    dev = np.genfromtxt(folder / "report_tracking_error.csv", delimiter=",", names=True)
    assert dev["deviation_from_ideal_m"][0] == 0.0
    check_html(folder / "report.html")


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


def test_compare_two_folders(tmp_path: Path, run_folder: Path, stall_folder: Path) -> None:
    from hil.analysis.measure.folder import measure_folder

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
    assert "saturation_share.tau1" in rows
    assert "certificate.d_max_s" not in rows or rows["certificate.d_max_s"]["b"] is None
    for f in data["figures"]:
        assert (out / f["png"]).is_file() and (out / f["data"]).is_file()
    # two runs: their measured figures, as hil.analysis.measure gives them
    out2 = tmp_path / "cmp2"
    assert main(["compare", str(run_folder), str(stall_folder), "--out", str(out2)]) == 0
    rows = {r["figure"]: r for r in json.loads((out2 / "compare.json").read_text())["rows"]}
    ma, mb = measure_folder(run_folder), measure_folder(stall_folder)
    assert rows["certificate.d_max_s"]["a"] == ma.certificate["d_max_s"]
    assert rows["certificate.d_max_s"]["b"] == mb.certificate["d_max_s"]
    assert rows["certificate.held"]["b"] == 0.0
    assert rows["timing.samples_without_command"]["b"] == mb.timing["samples_without_command"]
    # the page answers first: verdicts, D against D*, the limits, then what moved most
    head = json.loads((out2 / "compare.json").read_text())["headline"]
    assert head["lines"][0].startswith("Verdict: A ")
    d_a, d_b = ma.certificate["d_max_s"] * 1e3, mb.certificate["d_max_s"] * 1e3
    assert head["lines"][1].startswith("Why B: certificate not held")  # B's one reason
    age = head["lines"][2]
    assert f"A D = {d_a:.3f} ms of D* = " in age and f"B D = {d_b:.3f} ms" in age
    assert "D: the longest a command stayed in force" in age  # each symbol said in words
    assert head["lines"][3].startswith("Limits of (2), the bounds φ1, φ2 on the velocities")
    moved = {r[0]: r for r in head["most_moved"]}
    # the stall moved D, which the verdict's reason names: listed with its unit, its name in
    # words, and what it is measured against (tests/test_compare_pages.py: the ranking)
    assert moved["certificate.d_max_s"][4:7] == [
        "s",
        "D, the longest a command stayed in force",
        f"D* = {mb.certificate['d_star_s'] * 1e3:.3f} ms",
    ]
    text = (out2 / "compare.html").read_text()
    assert text.index("Verdict: A") < text.index("Every figure")
    assert (
        rows["timing.sample_to_apply_zenoh.p99_us"]["a"]
        == (ma.timing["sample_to_apply_zenoh"]["p99_us"])
    )
    assert rows["messages.torque_zenoh.lost"]["b"] == 30
    assert (out2 / "compare_latency.png").is_file()
    # A verdict that is not PASS says why, in its first reason's words, right after it.
    judged = tmp_path / "judged"
    shutil.copytree(stall_folder, judged)
    summary = json.loads((judged / "summary.json").read_text())
    reason = "samples without a command: 30 of 100 (30.000 %; all at 2 s) > 1.000 %; and more"
    summary["verdict"] = Verdict(outcome="FAIL", fail_reasons=[reason]).as_dict()
    (judged / "summary.json").write_text(json.dumps(summary))
    assert main(["compare", str(run_folder), str(judged), "--out", str(tmp_path / "c3")]) == 0
    lines = json.loads((tmp_path / "c3" / "compare.json").read_text())["headline"]["lines"]
    assert lines[0].endswith(", B FAIL.")
    assert (
        lines[1] == "Why B: samples without a command: 30 of 100 (30.000 %; all at 2 s) > 1.000 %."
    )
    assert main(["compare", str(run_folder), str(tmp_path / "none"), "--out", str(out)]) == 2


def test_a_switching_torque_is_drawn_as_its_envelope_and_duty() -> None:
    """A torque that switches between +limit and -limit with an 80 % duty: each bin (10
    samples) has a band of [-1, 1] and a mean of 0.6, which a solid block of lines would hide."""
    from hil.analysis.report import figures as fg

    t = np.arange(4000) * 1e-3
    tau = np.where(np.arange(4000) % 5 == 0, -1.0, 1.0)
    f = fg.switching_band("tau1", "τ1", "τ1 [m/s²]", t, [("tau1", tau)], 1.0)
    assert np.all(f.columns["tau1_min"] == -1.0) and np.all(f.columns["tau1_max"] == 1.0)
    assert np.allclose(f.columns["tau1_mean"], 0.6)
    assert np.array_equal(f.columns["tau1"], tau)  # the samples stay in the data file


def test_a_far_latency_outlier_is_left_off_the_axis_and_listed() -> None:
    from hil.analysis.report import figures as fg

    values = np.concatenate([np.full(2000, 1000.0) + np.arange(2000) % 50, [170_000.0]])
    f = fg.histogram_and_cdf("latency", "latency", {"zenoh": values})
    assert "1 samples beyond the axis" in f.caption and "largest 170000 µs" in f.caption
    assert f.columns["zenoh_sorted_us"].max() == 170_000.0  # left off the drawing, not the data
    plain = fg.histogram_and_cdf("latency", "latency", {"zenoh": values[:-1]})
    assert "beyond the axis" not in plain.caption


def test_the_report_page_has_contents_and_folds_long_tables(run_folder: Path) -> None:
    assert main(["report", str(run_folder), "--no-ideal"]) == 0
    text = (run_folder / "report.html").read_text()
    assert '<nav class="toc">' in text and 'href="#certificate"' in text
    assert "<details><summary>" in text  # every timing figure: folded below the answers
    assert text.index('<nav class="toc">') < text.index('id="verdict"')


def test_a_report_needs_no_user_law_after_the_run(tmp_path: Path) -> None:
    """Everything a report shows was measured or simulated already: a folder whose user law
    cannot be imported any more is reported in full, the ideal trajectory left out with why."""
    folder = write_synthetic_folder(tmp_path / "f", duration=0.5)
    toml = folder / "scenario.resolved.toml"
    text = toml.read_text()
    start = text.index("[controller]")
    end = text.index("\n[", start + 1)
    toml.write_text(
        text[:start] + '[controller]\nlaw = "no_such_user_module:MyLaw"\ngain = 2.0\n' + text[end:]
    )
    # The verdict's own exit code, never 2: the synthetic folder's timing is clean, PASS.
    assert main(["report", str(folder)]) == expected_exit("PASS", command="report")
    data = json.loads((folder / "report.json").read_text())
    assert PASSES.check(data["verdict"]) is None, data["verdict"]
    assert data["scenario"]["law"] == "no_such_user_module:MyLaw"
    note = data["metrics"]["deviation_from_ideal_note"]
    assert note.startswith("not computed") and "no_such_user_module:MyLaw" in note


def _page_text(page: str) -> str:
    import html

    return html.unescape(re.sub(r"<[^>]+>", " ", page))


def test_every_table_gives_units_and_every_symbol_its_sentence(
    tmp_path: Path, run_folder: Path, stall_folder: Path
) -> None:
    """The run report and the compare page: every number of every table has its unit in its
    table (header, row label or unit column), and each symbol of the paper a sentence."""
    assert main(["report", str(stall_folder), "--no-ideal"]) == 1  # stalls, drives, messages
    assert main(["compare", str(run_folder), str(stall_folder), "--out", str(tmp_path)]) == 0
    for page in (stall_folder / "report.html", tmp_path / "compare.html"):
        text = page.read_text()
        assert len(tables(text)) >= 2, page.name  # the check reads the real tables
        assert not numbers_without_unit(text), (page.name, numbers_without_unit(text)[:10])
        words = _page_text(text)
        assert "D*" in words and "(2)" in words, page.name
        assert not unglossed(words), (page.name, unglossed(words))


def test_the_headline_names_no_d_star_for_a_law_without_one() -> None:
    """A user's law with no certificate still has stalls (above 3 Ts); the headline lists them
    as the longest and never speaks of a D* it does not have. The paper's law keeps its rule."""
    from hil.analysis.report.content import _stalls

    stall = {"t_s": 1.5, "age_s": 0.012, "cause": "controller_late", "owner": "bench"}
    cert = {"path": "zenoh", "stall_threshold_s": 0.003, "stalls": [stall], "stall_count": 1,
            "stalled_time_s": 0.009, "d_star_s": None}  # fmt: skip
    _, own = _stalls({"kind": "run", "certificate": cert})
    assert "D*" not in own.replace("no D* for this law", ""), own
    assert own.startswith("Stalls longest (no D* for this law) (top 1 of 1 above 3.000 ms"), own
    _, none = _stalls({"kind": "run", "certificate": {**cert, "stalls": [], "stall_count": 0}})
    assert "threshold 3 Ts = 3.000 ms" in none and "D*" not in none, none
    _, paper = _stalls({"kind": "run", "certificate": {**cert, "d_star_s": 0.02}})
    assert paper.startswith("Stalls closest to D* (top 1 of 1 above 3.000 ms"), paper
