"""``hil report`` on a real run (controller and plant processes, Zenoh and the CAN path both
live): every section is produced, the report's certificate and timing figures are summary.json's
(one pipeline, hil.analysis.measure), its first lines answer the four questions with summary.json's
numbers, the HTML stays self-contained, and latency replay gives the same array from the run
folder and from its recording alone."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hil.analysis.measure.folder import measure_folder
from hil.analysis.replay import latencies_from_run
from hil.cli import main
from hil.sim.certificate import CONTRACT_KEYS
from tests.run_helpers import (
    PASSES,
    check_clean_run,
    check_verdict,
    clean_scenario,
    expected_exit,
)
from tests.test_report import RUN_SECTIONS, check_html, check_images


@pytest.mark.realtime
@pytest.mark.slow
def test_report_of_a_real_run_with_both_paths(tmp_path: Path, spawn) -> None:
    # A clean run (CLEAN_50HZ): its verdict is PASS, the report's too.
    scenario = clean_scenario(tmp_path)
    run_dir = tmp_path / "run"
    proc = spawn.python(
        ["-m", "hil", "run", str(scenario), "--duration", "3", "--out", str(run_dir), "--quiet"]
    )
    try:
        _, err = proc.communicate(timeout=180)
    except Exception:
        pytest.fail("hil run did not finish within 180 s")
    assert (run_dir / "summary.json").is_file(), err.decode()[-2000:]
    summary = json.loads((run_dir / "summary.json").read_text())
    check_verdict(summary, PASSES, proc.returncode, run_dir, context=err.decode()[-2000:])
    check_clean_run(summary, "zenoh", run_dir)  # and within a clean run's bounds
    assert list(run_dir.glob("*.mcap")), "the run left no recording"
    # hil run writes the report itself; hil report below rewrites it from the folder alone.
    written_by_run = json.loads((run_dir / "report.json").read_text())
    assert set(written_by_run["sections"]) == RUN_SECTIONS
    summary_before = (run_dir / "summary.json").read_bytes()

    code = main(["report", str(run_dir)])
    assert (run_dir / "summary.json").read_bytes() == summary_before
    data = json.loads((run_dir / "report.json").read_text())
    # The report judges the folder again with the same thresholds: the run's verdict.
    assert data["verdict"]["outcome"] == summary["verdict"]["outcome"] == "PASS"
    assert data["verdict"]["reasons"] == [] and data["verdict"]["ok"], data["verdict"]
    assert code == expected_exit("PASS", command="report")
    assert set(data["sections"]) == RUN_SECTIONS
    assert data["kind"] == "run"
    summary = json.loads(summary_before)
    # the certificate is summary.json's, field for field (docs/run-folder.md's certificate object)
    for key in CONTRACT_KEYS:
        assert data["certificate"][key] == summary["certificate"][key], key
        assert written_by_run["certificate"][key] == summary["certificate"][key], key
    assert data["certificate"]["path"] == "zenoh"
    assert data["timing"]["summary"] == summary["timing"]
    assert data["timing"]["messages"] == summary["messages"]
    assert data["metrics"]["bands"]["v_tilde"] is not None  # from the recorded telemetry
    c = check_html(run_dir / "report.html")
    assert set(c.section_ids) == RUN_SECTIONS
    check_images(c)

    # the first lines answer: limits of (2), D against D*, stalls, samples without a command
    head = "\n".join((run_dir / "report.md").read_text().splitlines()[:8])
    for key, limit in (("v", 1.6), ("omega", 5.1), ("tau1", 1.0), ("tau2", 8.0)):  # CLEAN_50HZ
        peak = summary[f"max_abs_{key}"]
        assert f"= {peak:.4g} " in head and f"{100 * peak / limit:.1f} %" in head, key
    cert = summary["certificate"]
    assert f"D = {cert['d_max_s'] * 1e3:.3f} ms" in head
    assert f"D* = {cert['d_star_s'] * 1e3:.3f} ms" in head
    assert f"margin {cert['margin_s'] * 1e3:.3f} ms" in head
    for st in cert["stalls"][:3]:
        assert f"t = {st['t_s']:.3f} s, age {st['age_s'] * 1e3:.3f} ms, cause {st['cause']}" in head
    if not cert["stalls"]:
        assert "Stalls: none" in head
    t = summary["timing"]
    assert (
        f"Samples without a command: {t['samples_without_command']} of {t['samples_judged']} "
        f"({100 * t['samples_without_command_rate']:.3f} %)"
    ) in head
    assert data["headline"]["command_age"]["d_max_s"] == cert["d_max_s"]

    # the latency plot draws hil.analysis.measure's samples: their exact percentiles are the
    # summary's
    lat = np.genfromtxt(run_dir / "report_latency.csv", delimiter=",", names=True)
    zen = lat["zenoh_sorted_us"][np.isfinite(lat["zenoh_sorted_us"])]
    s2a = summary["timing"]["sample_to_apply_zenoh"]
    assert s2a["count"] == zen.size
    for key, q in (("p50_us", 50.0), ("p99_us", 99.0), ("p999_us", 99.9)):
        assert np.percentile(zen, q, method="inverted_cdf") == s2a[key], key
    assert zen.max() == s2a["max_us"]

    # latency replay: the recording alone gives exactly the folder's latencies
    mcap = run_dir / "recording.mcap"
    assert np.array_equal(latencies_from_run(mcap), latencies_from_run(run_dir))
    for path in ("zenoh", "can"):
        from_mcap = latencies_from_run(f"{mcap}::{path}")
        assert np.array_equal(from_mcap, latencies_from_run(f"{run_dir}::{path}"))
        assert np.array_equal(from_mcap, measure_folder(run_dir).latency_us()[path] * 1e-6)
