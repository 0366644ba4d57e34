"""``hil run``: a closed loop of real processes, the controller and the emulated robot
(recorded by hil.bench, then analysed by hil.analysis)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, NotRequired, TypedDict

import typer

from hil import interrupts
from hil.commands import ForceOpt, app
from hil.commands.new_law import LawOpt
from hil.errors import NegativeVerdictError

if TYPE_CHECKING:
    from hil.folder.records import Summary

# ``--live [PORT]`` and ``--live-host``, one spelling for every command that serves a live view
# (run, drives, fleet; docs/live.md).
LiveHostOpt = Annotated[
    str,
    typer.Option(
        help="Address the live view binds to. Anything but loopback exposes the run's data "
        "to whoever reaches it (no login, no TLS): a warning says so."
    ),
]


def live_opt(serves: str) -> Any:
    """``--live [PORT]``: ``serves`` says what is served, the rest is the same everywhere."""
    return Annotated[
        int | None,
        typer.Option(
            metavar="[PORT]",
            help=f"Serve {serves} live over the Foxglove WebSocket protocol on this port "
            "(bare --live: 8765; 0: any free port), from a process of its own (docs/live.md).",
        ),
    ]


# The options of ``hil run`` longer than a line of its signature, one alias each.
ScenarioArg = Annotated[
    Path | None,
    typer.Argument(
        help="Scenario TOML or a bundled scenario's name (hil scenarios); default: the "
        "paper's tracking circle, 10 s."
    ),
]
LockstepOpt = Annotated[bool, typer.Option(help="Advance the plant one period per command.")]
TriggerOpt = Annotated[str | None, typer.Option(help="periodic (absolute deadlines) or on_state.")]
CanInterfaceOpt = Annotated[
    str | None, typer.Option(help="python-can interface (default zenoh_can).")
]
SecureOpt = Annotated[
    bool,
    typer.Option(
        help="Run every session through a router with user/password authentication and "
        "per-role access control (fresh passwords per run, outside the run folder; "
        "deploy/README.md)."
    ),
]
LabOpt = Annotated[
    str | None,
    typer.Option(
        help="Run on the hosts of this lab (hil lab up; root): the plant and the recorder on "
        "--plant-host, the controller on --controller-host, each through its host's router "
        "(docs/lab.md). Needs --no-can."
    ),
]
PlantHostOpt = Annotated[str | None, typer.Option(help="The plant's lab host (default h1).")]
ControllerHostOpt = Annotated[
    str | None, typer.Option(help="The controller's lab host (default h2).")
]
RobotIdOpt = Annotated[
    str | None, typer.Option(help="The robot's id (its keys hil/ID/...) instead of the scenario's.")
]
LiveOpt = live_opt("the run")
StrictOpt = Annotated[
    bool,
    typer.Option(
        help="Accepted so that older scripts run; changes nothing: every verdict has its own "
        'exit code (PASS 0, FAIL 1, INCONCLUSIVE 4; docs/reports.md, "Verdict and exit '
        'code"), so CI can act on each without it.'
    ),
]
ReportOpt = Annotated[
    bool,
    typer.Option(
        help="Write the sampling-effect report (report.html/.md/.json, as hil report "
        "does) into the run folder. Its verdict is printed; the exit code stays the "
        "run's own verdict's.",
    ),
]
JsonOpt = Annotated[
    bool,
    typer.Option(
        "--json",
        help="Print the run's brief (folder, figures, verdict, report) as JSON on stdout, for "
        "scripts; the plain result line then goes to stderr.",
    ),
]

ControllerOpt = Annotated[
    str,
    typer.Option(
        help="bench: the scenario's law in the bench's controller process. external: no "
        "controller of the bench's; your device connects (printed at the start, and in "
        "device.json) and is judged at the bus (docs/external.md)."
    ),
]
WaitDeviceOpt = Annotated[
    float,
    typer.Option(
        help="With --controller external: seconds to wait for the device before the run "
        "FAILs with 'no device connected'."
    ),
]
ZenohEndpointOpt = Annotated[
    str | None,
    typer.Option(
        help="The run's Zenoh endpoint, tcp/HOST:PORT (default: a free loopback port), so "
        "that an outside device connects to the same one run after run."
    ),
]


def run_options(given: dict[str, Any], cls: Any, **extra: Any) -> Any:
    """The bench's options record (hil.bench.prepare.RunOptions) from the command line's
    values by name: one spelling of each option, no list of them kept twice (its
    :meth:`~hil.bench.prepare.RunOptions.argv` is the way back)."""
    from hil.bench.prepare import FIELD_OF_OPTION

    fields = {f.name for f in dataclasses.fields(cls)}
    named = {FIELD_OF_OPTION.get(k, k): v for k, v in given.items()}
    return cls(**{k: v for k, v in named.items() if k in fields}, **extra)


CanEndpointOpt = Annotated[
    str | None,
    typer.Option(
        help="The zenoh_can bus's endpoint, tcp/HOST:PORT (default: a free loopback port): "
        "where a CAN device on interface zenoh_can connects, run after run."
    ),
]

UntilStoppedOpt = Annotated[
    bool,
    typer.Option(
        help="With --controller external: no duration; the run lasts until Ctrl-C (or "
        "SIGTERM; at most 10 million control samples, 5.5 h at 500 Hz), its planned end: the "
        "folder, the report and the verdict follow as for any run (a free-running session "
        "with your device, recorded and judged)."
    ),
]


class ReportBrief(TypedDict):
    """The run's report in ``hil run --json``: where it is and its verdict."""

    html: str
    ok: bool
    reasons: list[str]


class RunBrief(TypedDict):
    """What ``hil run --json`` prints: summary.json's headline figures (units as there)."""

    run_dir: str | None
    final_position_error: float | None
    max_abs_v: float | None
    max_abs_omega: float | None
    violations: dict[str, int] | None
    wakeup_lateness_p99_us: float | None
    sample_to_apply_p50_us: float | None  # on the applied command path
    deadline_misses: int | None
    interrupted: bool | None
    verdict: str | None  # PASS, FAIL or INCONCLUSIVE
    reasons: list[str] | None
    report: NotRequired[ReportBrief]


def _brief(summary: Summary, cmd_path: str) -> RunBrief:
    """The lines of summary.json that ``hil run`` prints."""
    t = summary.get("timing", {})
    v = summary.get("verdict") or {}
    return {
        "run_dir": summary.get("run_dir"),
        "final_position_error": summary.get("final_position_error"),
        "max_abs_v": summary.get("max_abs_v"),
        "max_abs_omega": summary.get("max_abs_omega"),
        "violations": summary.get("violations"),
        "wakeup_lateness_p99_us": (t.get("wakeup_lateness") or {}).get("p99_us"),
        "sample_to_apply_p50_us": (t.get(f"sample_to_apply_{cmd_path}") or {}).get("p50_us"),
        "deadline_misses": t.get("deadline_misses"),
        "interrupted": summary.get("interrupted"),
        "verdict": v.get("outcome"),
        "reasons": v.get("reasons"),
    }


def _raise_on_negative(summary: Summary) -> None:
    """Exit with the run's verdict's code (hil.verdict.EXIT_CODE, through hil.cli): nothing
    for PASS, NegativeVerdictError for FAIL (1) or INCONCLUSIVE (4); a run stopped by an
    error of its own is a FAIL (hil.verdict.run_outcome)."""
    from hil.verdict import PASS, run_outcome

    outcome = run_outcome(summary)
    if outcome == PASS:
        return
    v = summary.get("verdict") or {}
    why = [str(summary["error"])] if summary.get("error") else list(v.get("reasons") or [])
    raise NegativeVerdictError("; ".join(why) or "no reason recorded", outcome)


def verdict_line(summary: Summary, report: str | None = None) -> str:
    """One plain line: the outcome, why, D against D* where there is a certificate, notes,
    and where to read more (the report, else the run folder)."""
    from hil.verdict import run_outcome, short_reason

    v = summary.get("verdict") or {}
    cert = summary.get("certificate") or {}
    d, ds = cert.get("d_max_s"), cert.get("d_star_s")
    age = f"D {d * 1e3:.2f} ms of D* {ds * 1e3:.2f} ms" if d is not None and ds else ""
    # The outcome the run exits with: a run stopped by its own error is a FAIL, said first.
    reasons = [str(summary["error"])] if summary.get("error") else []
    reasons += [r for r in v.get("reasons") or [] if r not in reasons]  # the verdict has it too
    # The first reason's first clause, whole: a law's fault (hil.verdict.LawEnd) names the law,
    # the time, the state and the exception in one sentence, which must not lose its end.
    why = short_reason(reasons[0]) if reasons else f"limits {v.get('limits', '?')}"
    if len(reasons) > 1:
        why += f" (and {len(reasons) - 1} more reason{'s' if len(reasons) > 2 else ''})"
    if "D* =" in why:
        age = ""  # the reason already says D against D*
    notes = "; ".join(v.get("notes") or [])
    line = f"{run_outcome(summary)}: " + ", ".join(x for x in (why, age) if x)
    if notes:
        line += f" ({notes})"
    if report:
        return f"{line}; report: {report}"
    run_dir = summary.get("run_dir")
    return f"{line}; run folder: {run_dir}" if run_dir else line


def _write_report(recorded: Any, summary: Summary, quiet: bool) -> ReportBrief:
    """The report of the finished run, as ``hil report RUN_DIR`` writes it, from the run's
    scenario and verdict as this process holds them (neither parsed nor judged again)."""
    from hil.analysis.report.build import build_report, write_report
    from hil.analysis.report.ideal import ideal_from_simulator
    from hil.folder import load_folder
    from hil.folder.scenario_view import as_resolved
    from hil.verdict import Verdict

    if not quiet:
        typer.echo("writing the report (and the ideal-trajectory simulation) ...", err=True)
    run_dir = recorded.run_dir
    folder = load_folder(run_dir, lazy=True)
    folder.typed = as_resolved(recorded.scenario, folder.scenario)
    judged = Verdict.from_dict(summary["verdict"]) if summary.get("verdict") else None
    rep = build_report(folder, ideal=ideal_from_simulator, verdict=judged)
    paths = write_report(rep, run_dir)
    verdict = rep.data["verdict"]
    return {"html": str(paths["html"]), "ok": verdict["ok"], "reasons": verdict["reasons"]}


@app.command("run")
def run(
    scenario: ScenarioArg = None,
    duration: Annotated[float | None, typer.Option(help="Run length in s.")] = None,
    rate: Annotated[float | None, typer.Option(help="Control rate in Hz.")] = None,
    cmd_path: Annotated[str, typer.Option(help="Applied command path: zenoh or can.")] = "zenoh",
    lockstep: LockstepOpt = False,
    trigger: TriggerOpt = None,
    can: Annotated[bool, typer.Option(help="Keep the CAN path live (as shadow).")] = True,
    can_interface: CanInterfaceOpt = None,
    can_channel: Annotated[str | None, typer.Option(help="python-can channel.")] = None,
    spin_us: Annotated[float, typer.Option(help="Spin this long before each deadline.")] = 0.0,
    out: Annotated[Path | None, typer.Option(help="Run folder (default runs/run-*).")] = None,
    quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
    secure: SecureOpt = False,
    report: ReportOpt = True,
    strict: StrictOpt = False,
    law: LawOpt = None,
    as_json: JsonOpt = False,
    lab: LabOpt = None,
    plant_host: PlantHostOpt = None,
    controller_host: ControllerHostOpt = None,
    robot_id: RobotIdOpt = None,
    live: LiveOpt = None,
    live_host: LiveHostOpt = "127.0.0.1",
    force: ForceOpt = False,
    controller: ControllerOpt = "bench",
    wait_device: WaitDeviceOpt = 60.0,
    zenoh_endpoint: ZenohEndpointOpt = None,
    can_endpoint: CanEndpointOpt = None,
    until_stopped: UntilStoppedOpt = False,
) -> None:
    """Run the controller against the emulated robot over Zenoh and CAN and record it.

    With --controller external the controller is yours: any process, in any language, that
    speaks the documented Zenoh messages or CANSimple to the virtual ODrives (docs/external.md).
    The run says how to connect, waits for it, and judges it at the bus."""
    given = dict(locals())  # the command line, by option name (first: nothing else bound yet)
    from hil.analysis.analyze import write_results
    from hil.analysis.replay import latencies_from_run
    from hil.bench.lifecycle import execute
    from hil.bench.prepare import RunOptions
    from hil.verdict import run_started

    # The bench records the run into its folder; the analysis then writes the figures, the
    # trace and the verdict into it (summary.json); the report follows.
    recorded = execute(run_options(given, RunOptions, run_latencies=latencies_from_run))
    summary: Summary = write_results(recorded).copy()
    summary["run_dir"] = str(recorded.run_dir)
    brief = _brief(summary, cmd_path)
    run_dir = summary.get("run_dir")
    stopped = summary.get("interrupted") or interrupts.happened()
    if report and run_dir and not stopped and run_started(summary):
        brief["report"] = _write_report(recorded, summary, quiet)
    report_html = brief["report"]["html"] if "report" in brief else None
    line = f"result: {verdict_line(summary, report_html)}"
    # One plain line ends the run (a negative exit prints its own reason, hil.cli, after
    # it); --json puts the brief on stdout for scripts and the line on stderr.
    if as_json:
        typer.echo(json.dumps(brief, indent=2))
    typer.echo(line, err=as_json)
    if stopped:
        # hil.cli exits 130: hil.bench.lifecycle recorded the signal in hil.interrupts.
        interrupts.note(f"run folder written to {run_dir}")
        return
    del strict  # accepted, changes nothing (StrictOpt)
    _raise_on_negative(summary)
