"""``hil paper``: the paper's Section 4 reproduced offline (Figures 2-20 and a table).

The runs are the bundled scenarios ``hil/scenarios/paper_NAME.toml`` (NAME in :data:`RUNS`;
initial conditions stated there), each on the single-run float simulator at Ts = 1 ms,
h = 0.1 ms for its file's duration (150 s, 300 s, 100 s), spread over ``jobs`` processes
(default 2: the machine's cores); ``quick`` divides every duration by 5 for smoke tests (then
the convergence checks are not judged). ``paper.html`` opens with the checks of the paper's
claims, then the measured figures and every figure (drawn as the run report draws them: a
switching torque as its envelope and duty); ``table.md`` and ``table.json`` hold the same table
and checks; each figure group's docstring names its figures.
"""

from __future__ import annotations

import base64
import contextlib
import multiprocessing
import signal
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TypedDict, cast

import numpy as np

from hil import interrupts
from hil.analysis.report import content as ct
from hil.analysis.report import figures as report_figures
from hil.analysis.report.content import NORMALIZED, WHAT_2
from hil.bundled import bundled_dir
from hil.folder import layout, write_summary
from hil.folder.jsonio import write_json
from hil.limits import LIMIT_NAMES, PEAK_KEYS, SIGNALS, UNITS
from hil.paper import figures as fg
from hil.provenance import dumps_toml
from hil.scenario import load_scenario
from hil.sim import SimResult, simulate
from hil.sim.folder import write_run_folder

PAPER_HTML = "paper.html"
QUICK_FACTOR = 5.0
JOLT_WINDOW = 0.5
JOLT_SPAN = 5.0
# [19] must jolt clearly, not by rounding: its jolt at least this many times the unified law's.
JOLT_RATIO = 1.5


# The paper's runs in table order; the run NAME is the bundled scenario paper_NAME.toml.
RUNS = (
    "tracking",
    "stabilization",
    "chattering",
    "compare_jiang1997",
    "compare_jiang2001",
    "circle_then_stop_unified",
)


def velocity_jolt(
    t: np.ndarray,
    v: np.ndarray,
    stop_time: float,
    window: float = JOLT_WINDOW,
    span: float = JOLT_SPAN,
) -> float:
    """Largest change of v smoothed over ``window`` within ``span`` after ``stop_time``.

    v is averaged over the trailing ``window`` (this removes the +-varpi1 chattering of a sign
    law), then the change |v_s(t) - v_s(t - window)| is maximised over
    stop_time <= t <= stop_time + span.
    """
    if len(t) < 2:
        return float("nan")
    ts = float(t[1] - t[0])
    w = max(1, round(window / ts))
    csum = np.concatenate([[0.0], np.cumsum(v)])
    vs = np.full(len(v), np.nan)
    vs[w - 1 :] = (csum[w:] - csum[:-w]) / w
    change = np.full(len(v), np.nan)
    change[w:] = np.abs(vs[w:] - vs[:-w])
    mask = (t >= stop_time) & (t <= stop_time + span) & np.isfinite(change)
    return float(np.max(change[mask])) if mask.any() else float("nan")


# The summary's figures in each row of the table, after the run, its law and its scenario.
_ROW_KEYS = (
    *("duration", "ts", "plant_step", "final_position_error", "final_heading_error"),
    *("rms_position_error", *PEAK_KEYS.values()),
    "violations",
)


class PaperCheck(TypedDict):
    """One check of the paper's claims (table.md's and table.json's ``checks``)."""

    check: str
    passed: bool | None  # None: not judged (--quick)
    measured: str


class PaperRun(TypedDict):
    """One run of table.json's ``runs`` (a row of table.md): its name, law and scenario, then
    the simulation summary's figures named in ``_ROW_KEYS`` (units as summary.json's)."""

    run: str
    law: str
    scenario: str
    duration: float
    ts: float
    plant_step: float
    final_position_error: float
    final_heading_error: float
    rms_position_error: float
    max_abs_v: float
    max_abs_omega: float
    max_abs_tau1: float
    max_abs_tau2: float
    violations: dict[str, int]  # plant steps beyond each limit of (2)


class PaperTable(TypedDict):
    """table.json, as ``hil paper`` writes it."""

    note: str
    runs: list[PaperRun]
    checks: list[PaperCheck]  # none when interrupted
    quick: bool
    interrupted: bool
    runs_not_done: list[str]


def checks(results: dict[str, SimResult], quick: bool) -> list[PaperCheck]:
    """The checks of the paper's claims on its runs (convergence checks skipped when quick)."""
    out: list[PaperCheck] = []

    def add(name: str, ok: bool | None, measured: str) -> None:
        out.append({"check": name, "passed": ok, "measured": measured})

    tr = results["tracking"]
    if quick:
        add("tracking: position error < 0.02 m by t = 150 s", None, "not judged (--quick)")
    else:
        t, err = tr.column("t"), tr.column("position_error")  # at the sample t = 150 s - Ts
        i = int(np.searchsorted(t, 150.0 - tr.scenario.timing.ts - 1e-9))
        e = float(err[min(i, len(err) - 1)])
        add("tracking: position error < 0.02 m by t = 150 s", e < 0.02, f"{e:.4g} m")
    for name in ("tracking", "stabilization", "chattering", "circle_then_stop_unified"):
        v = results[name].summary["violations"]
        beyond = ", ".join(f"{SIGNALS[k]} {v[k]}" for k in PEAK_KEYS)
        add(f"{name}: limits (2) hold at every plant step", not any(v.values()),
            f"plant steps beyond (2): {beyond}")  # fmt: skip
    st = results["stabilization"]
    if quick:
        add("stabilization: position error at 300 s < 0.6 m", None, "not judged (--quick)")
    else:
        e = st.summary["final_position_error"]
        add("stabilization: position error at 300 s < 0.6 m", e < 0.6, f"{e:.4g} m")
    j7 = results["compare_jiang1997"].summary
    u = tr.summary
    add(
        "[7] breaks |v| ≤ φ1 on the tracking run, the unified law does not",
        j7["violations"]["v"] > 0 and u["violations"]["v"] == 0,
        f"max |v|: [7] {j7['max_abs_v']:.4g} m/s, unified {u['max_abs_v']:.4g} m/s, "
        f"φ1 = {tr.scenario.limits.phi1:.4g} m/s",
    )
    j19 = results["compare_jiang2001"]
    un = results["circle_then_stop_unified"]
    stop = float(un.scenario.reference.get("stop_time", 70.0))
    if j19.column("t")[-1] < stop + JOLT_SPAN or un.column("t")[-1] < stop + JOLT_SPAN:
        add("[19] jolts at the switch, the unified law does not", None, "run too short")
    else:
        jolt19 = velocity_jolt(j19.column("t"), j19.column("v"), stop)
        jolt_u = velocity_jolt(un.column("t"), un.column("v"), stop)
        add(
            "[19] jolts at the switch, the unified law does not",
            jolt19 >= JOLT_RATIO * jolt_u,
            f"needs [19] >= {JOLT_RATIO:g} x unified; largest change of v smoothed over "
            f"{JOLT_WINDOW} s within {JOLT_SPAN} s of the stop: [19] {jolt19:.4g} m/s, "
            f"unified {jolt_u:.4g} m/s",
        )
    return out


TITLE = "Li et al. 2024, Section 4, reproduced offline"
#: The table's columns (table.md and paper.html), each with its unit; the limits' symbols and
#: units are hil.limits.LIMITS'.
RUN_HEADER = ["run", "law", "final position error [m]", "final heading error [rad]"]
RUN_HEADER += ["RMS position error, last 10 % [m]"]
RUN_HEADER += [f"max |{SIGNALS[k]}| [{UNITS[k]}]" for k in PEAK_KEYS]
RUN_HEADER += ["plant steps beyond (2): " + "/".join(SIGNALS[k] for k in PEAK_KEYS)]
CHECK_HEADER = ["check of the paper's claim", "result", "measured"]


def _run_cells(r: PaperRun) -> list[str]:
    v = r["violations"]
    cells = [r["run"], r["law"]]
    cells += [f"{r[k]:.4g}" for k in ("final_position_error", "final_heading_error")]
    cells += [f"{r['rms_position_error']:.4g}", *(f"{r[k]:.4g}" for k in PEAK_KEYS.values())]
    return [*cells, "/".join(str(v[k]) for k in PEAK_KEYS)]


def _check_cells(c: PaperCheck) -> list[str]:
    return [
        c["check"],
        {True: "pass", False: "FAIL", None: "not judged"}[c["passed"]],
        c["measured"],
    ]


def answer(check_rows: list[PaperCheck], interrupted: bool) -> tuple[str, str]:
    """The page's first line, and its class (ok, bad, unsure): how many of the paper's claims
    held."""
    judged = [c for c in check_rows if c["passed"] is not None]
    failed = [c["check"] for c in judged if c["passed"] is False]
    if interrupted:
        return "INTERRUPTED: the paper's claims were not checked (see the note).", "unsure"
    if failed:
        return f"{len(failed)} of {len(judged)} claims judged FAIL: {'; '.join(failed)}.", "bad"
    if not judged:
        return "No claim judged (--quick: the runs are too short to judge them).", "unsure"
    rest = len(check_rows) - len(judged)
    more = f" ({rest} not judged: --quick)" if rest else ""
    return f"Every claim judged holds: {len(judged)} of {len(judged)}{more}.", "ok"


def _md_row(cells: list[str]) -> str:
    return "| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |"


def _markdown(
    rows: list[PaperRun], check_rows: list[PaperCheck], note: str, interrupted: bool
) -> str:
    """table.md: the claims checked first (the answer), then the measured figures."""
    lines = [f"# {TITLE}", "", answer(check_rows, interrupted)[0], "", note, ""]
    lines += ["## Checks of the paper's claims", ""]
    lines += [_md_row(CHECK_HEADER), "|" + "---|" * len(CHECK_HEADER)]
    lines += [_md_row(_check_cells(c)) for c in check_rows]
    lines += ["", "## Measured figures", "", NORMALIZED, ""]
    lines += [_md_row(RUN_HEADER), "|" + "---|" * len(RUN_HEADER)]
    lines += [_md_row(_run_cells(r)) for r in rows]
    return "\n".join(lines) + "\n"


def _html(
    out: Path,
    rows: list[PaperRun],
    check_rows: list[PaperCheck],
    note: str,
    interrupted: bool,
) -> str:
    """paper.html: self-contained as the run report (inline CSS, figures as data URIs); the
    claims checked first, then the measured figures, then every figure written."""
    text, cls = answer(check_rows, interrupted)
    figures = []
    for png in sorted(out.glob("fig*.png")):
        b64 = base64.b64encode(png.read_bytes()).decode("ascii")
        figures.append(
            f'<figure><img alt="{ct.esc(png.stem)}" src="data:image/png;base64,{b64}">'
            f"<figcaption>{ct.esc(png.stem)} (data: <code>{ct.esc(png.stem)}.csv</code>)"
            "</figcaption></figure>"
        )
    return "\n".join(
        [
            "<!DOCTYPE html>",
            '<html lang="en"><head><meta charset="utf-8">',
            f"<title>{ct.esc(TITLE)}</title><style>{ct.CSS}</style></head><body>",
            f"<h1>{ct.esc(TITLE)}</h1>",
            f'<section id="headline"><div class="verdict {cls}"><strong>{ct.esc(text)}</strong>',
            ct.table(CHECK_HEADER, [_check_cells(c) for c in check_rows]),
            "</div>",
            f"<p>{ct.esc(note)}</p></section>",
            '<section id="runs"><h2>Measured figures</h2>',
            f"<p>{ct.esc(NORMALIZED)} {ct.esc(WHAT_2)}</p>",
            ct.table(RUN_HEADER, [_run_cells(r) for r in rows]),
            "</section>",
            '<section id="figures"><h2>The paper\'s figures</h2>',
            f"<p>{ct.esc(FIGURES_NOTE)}</p>",
            '<div class="figs">',
            *figures,
            "</div></section></body></html>",
        ]
    )


FIGURES_NOTE = (
    "Each figure as the paper numbers it (fig02 is its Figure 2), with its data as CSV beside "
    "it; the limits of (2) are the red dashed lines. A switching torque τ1, τ2 is drawn as "
    "the run report draws it: per time bin its min-max range (the envelope) and its mean (the "
    "duty), not a solid block of lines."
)


def axis_label(col: str) -> str:
    """A signal's axis as every page labels it, from hil.limits.LIMITS: "τ1 [m/s²]"."""
    return f"{SIGNALS[col]} [{UNITS[col]}]"


def _signals(out: Path, first: int, stem: str, title: str, runs: fg.Runs, cols: str) -> list[Path]:
    """Figures ``first``, ``first + 1``, ...: each signal of ``cols`` (space-separated) over time
    against its limit of (2) (the last run's), titled ``title.format(symbol)``, its axis in the
    signal's unit (hil.limits: τ1 in m/s², τ2 in rad/s², the normalized inputs of model (1)).
    A torque switches faster than a plot shows: drawn as the run report draws it, its envelope
    and duty per time bin (hil.analysis.report.figures.switching_band)."""
    limits = runs[-1][1].scenario.limits
    paths = []
    for i, col in enumerate(cols.split()):
        path = out / f"fig{first + i:02d}_{stem}_{col}.png"
        label, limit = axis_label(col), getattr(limits, LIMIT_NAMES[col])
        if col.startswith("tau"):
            t = runs[0][1].column("t")
            series = [(name, run.column(col)[: len(t)]) for name, run in runs]
            band = report_figures.switching_band(
                path.stem, title.format(SIGNALS[col]), label, t, series, limit
            )
            band.write(out, "")
        else:
            fg.over_time(path, title.format(SIGNALS[col]), label, [col], runs, limit)
        paths.append(path)
    return paths


def _xy_and_signals(
    out: Path, first: int, stem: str, titles: tuple[str, str], runs: fg.Runs, cols: str
) -> list[Path]:
    """Figure ``first``, the trajectories against the last run's reference, then the signals
    of ``cols`` (:func:`_signals`); ``titles``: the trajectory's, the signals' template."""
    xy = fg.trajectory(out / f"fig{first:02d}_{stem}_xy.png", titles[0], runs, runs[-1][1])
    return [xy, *_signals(out, first + 1, stem, titles[1], runs, cols)]


def _task_figures(results: dict[str, SimResult], out: Path, name: str) -> list[Path]:
    """Figures 2-6 (tracking) or 7-11 (stabilization): trajectory, v, omega, tau1, tau2."""
    first, task = {"tracking": (2, "Tracking"), "stabilization": (7, "Stabilization")}[name]
    titles = (f"{task} task: robot position", f"{task} task: {{}} and its constraints")
    return _xy_and_signals(
        out, first, name, titles, [("robot", results[name])], "v omega tau1 tau2"
    )


def _chattering_figures(results: dict[str, SimResult], out: Path) -> list[Path]:
    """Figures 12-14: errors, tau1 and tau2 of the chattering reduction (19)."""
    runs = [("robot", results["chattering"])]
    errors = fg.over_time(
        out / "fig12_chattering_errors.png",
        "Chattering reduction (19): position and heading errors",
        "error (m, rad)",
        ["position_error", "heading_error"],
        runs,
    )
    return [errors, *_signals(out, 13, "chattering", "Chattering reduction: {}", runs, "tau1 tau2")]


def _jiang1997_figures(results: dict[str, SimResult], out: Path) -> list[Path]:
    """Figures 15-17: [7] on the tracking task."""
    titles = ("Tracking with [7]", "Tracking with [7]: {}")
    return _xy_and_signals(
        out, 15, "jiang1997", titles, [("[7]", results["compare_jiang1997"])], "v omega"
    )


def _compare_figures(results: dict[str, SimResult], out: Path) -> list[Path]:
    """Figures 18-20: [19] and the unified law on circle_then_stop."""
    runs = [
        ("[19]", results["compare_jiang2001"]),
        ("unified", results["circle_then_stop_unified"]),
    ]
    titles = ("Circle then stop: [19] and the unified law", "Circle then stop: {}")
    return _xy_and_signals(out, 18, "compare", titles, runs, "v omega")


FigureWriter = Callable[[dict[str, SimResult], Path], list[Path]]

# Each group of figures with the runs it needs, in figure order: a group is written as soon as
# its runs are done, so an interrupted ``hil paper`` keeps every figure it could draw.
FIGURE_GROUPS: tuple[tuple[tuple[str, ...], FigureWriter], ...] = (
    (("tracking",), lambda res, out: _task_figures(res, out, "tracking")),
    (("stabilization",), lambda res, out: _task_figures(res, out, "stabilization")),
    (("chattering",), _chattering_figures),
    (("compare_jiang1997",), _jiang1997_figures),
    (("compare_jiang2001", "circle_then_stop_unified"), _compare_figures),
)


def _ignore_sigint() -> None:
    """Pool workers leave Ctrl-C to the parent, which stops them (a terminal sends SIGINT to
    the whole process group)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _run_task(task: tuple[str, str, float]) -> tuple[str, SimResult]:
    """(name, result) of the run of ``task`` = (name, scenario file, divisor of its duration)."""
    name, path, scale = task
    sc = load_scenario(path)
    if scale != 1.0:
        sc = sc.with_overrides(duration=sc.run.duration / scale)
    return name, simulate(sc)


@contextlib.contextmanager
def _simulations(
    tasks: list[tuple[str, str, float]], jobs: int
) -> Iterator[Iterator[tuple[str, SimResult]]]:
    """(name, result) of every task as each finishes; the workers are stopped on leaving."""
    if jobs <= 1 or len(tasks) <= 1:
        yield (_run_task(t) for t in tasks)
        return
    pool = multiprocessing.get_context().Pool(min(jobs, len(tasks)), initializer=_ignore_sigint)
    try:
        yield pool.imap_unordered(_run_task, tasks)
    finally:
        with interrupts.shielded():  # at once on Ctrl-C: a run still going is not waited for
            pool.terminate()
            pool.join()


def _write_run(out: Path, res: SimResult, name: str, traces: bool) -> None:
    run_dir = out / "runs" / name
    if traces:
        write_run_folder(res, run_dir)
    else:
        run_dir.mkdir(parents=True, exist_ok=True)
        (run_dir / layout.SCENARIO_RESOLVED).write_text(dumps_toml(res.resolved))
        write_summary(run_dir, res.summary)


def run_paper(
    out: Path,
    quick: bool = False,
    jobs: int = 2,
    traces: bool = False,
    log: Callable[[str], None] = lambda _msg: None,
) -> PaperTable:
    """Run every bundled paper scenario, write figures, table.md, table.json; return the table.

    Each run's folder and each group of figures is written as soon as its runs are done.
    Ctrl-C stops the runs still going and keeps what was written; the table then holds the
    runs done, ``interrupted: true`` and no checks.
    """
    out.mkdir(parents=True, exist_ok=True)
    scale = QUICK_FACTOR if quick else 1.0
    tasks = [(r, str(bundled_dir() / f"paper_{r}.toml"), scale) for r in RUNS]
    for _, path, _ in tasks:
        load_scenario(path)  # bad files fail before any work starts
    results: dict[str, SimResult] = {}
    pending = list(FIGURE_GROUPS)
    interrupted = False
    try:
        with _simulations(tasks, jobs) as done:
            for name, res in done:
                if res.interrupted:  # Ctrl-C inside the loop (runs in this process)
                    interrupted = True
                    break
                # A Ctrl-C while files are written is recorded and acted on after them.
                with interrupts.shielded():
                    results[name] = res
                    _write_run(out, res, name, traces)
                    log(f"{name}: done")
                    for group in [g for g in pending if all(n in results for n in g[0])]:
                        pending.remove(group)
                        figs = group[1](results, out)
                        log(f"{name}: wrote {', '.join(f.name for f in figs)}")
                if interrupts.happened():
                    interrupted = True
                    break
    except KeyboardInterrupt:
        interrupted = True
    with interrupts.shielded():
        return _write_table(out, results, quick, interrupted)


def _write_table(
    out: Path, results: dict[str, SimResult], quick: bool, interrupted: bool
) -> PaperTable:
    done = [r for r in RUNS if r in results]
    rows = [
        cast(
            PaperRun,
            {"run": r, "law": results[r].summary["law"], "scenario": f"paper_{r}.toml"}
            | {k: results[r].summary[k] for k in _ROW_KEYS},
        )
        for r in done
    ]
    check_rows = [] if interrupted else checks(results, quick)
    note = "Single-run float simulator"
    if done:
        sc = results[done[0]].scenario
        note += f", Ts = {sc.timing.ts * 1e3:g} ms, RK4 plant step h = {sc.plant_step * 1e3:g} ms"
    note += f"; durations divided by {QUICK_FACTOR:g} (--quick)." if quick else "."
    note += " Initial conditions: see the scenario files."
    if interrupted:
        missing = ", ".join(r for r in RUNS if r not in results) or "none"
        note += (
            f" INTERRUPTED: {len(done)} of {len(RUNS)} runs done; not done: {missing} (no claim "
            "about them); the checks of the paper's claims not judged."
        )
    table: PaperTable = {
        "note": note,
        "runs": rows,
        "checks": check_rows,
        "quick": quick,
        "interrupted": interrupted,
        "runs_not_done": [r for r in RUNS if r not in results],
    }
    write_json(out / "table.json", table)
    (out / "table.md").write_text(_markdown(rows, check_rows, note, interrupted))
    (out / PAPER_HTML).write_text(_html(out, rows, check_rows, note, interrupted))
    return table
