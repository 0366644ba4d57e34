"""``hil campaign``: how much worse may timing get before an outside device breaks a limit?

A hosted law can be replayed (``hil margin``); an outside device cannot, so it is measured: the
same scenario is run again and again with ``--controller external`` against the same endpoint
(the device keeps running between runs and reconnects), each run adding more to the feedback
path toward the device (``[faults] feedback_delay``, ``feedback_jitter`` or ``feedback_loss``:
States on Zenoh, encoder estimates on CAN), until a limit of (2) breaks (or the tracking
error exceeds ``--tracking-bound``). The answer is the largest value that held, with the run
folders behind it (campaign.json, campaign.md).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Annotated, Any

import typer

from hil import interrupts, ticker
from hil.commands import ForceOpt, app
from hil.errors import BadInputError, NegativeVerdictError

#: What a campaign varies: its [faults] key, its unit as printed, and a default step and end.
VARIED = {
    "delay": ("feedback_delay", "ms", 0.002, 0.04),
    "jitter": ("feedback_jitter", "ms", 0.002, 0.04),
    "loss": ("feedback_loss", "%", 0.05, 0.5),
}
CAMPAIGN_JSON = "campaign.json"
CAMPAIGN_MD = "campaign.md"
LATER_WAIT_S = 30.0  # after the first run, the device is waited for this long (it reconnects)


@dataclass
class Step:
    """One run of the campaign: the value added, where its folder is, and what it showed."""

    value: float
    run_dir: str
    outcome: str  # the run's verdict
    limits_held: bool
    broken: list[str]  # the limits of (2) that broke (and "tracking" beyond the bound)
    rms_position_error: float | None
    peaks: dict[str, float | None]
    response_p50_ms: float | None  # the device's response time (docs/realtime.md), if measured
    held: bool


@dataclass
class Campaign:
    """campaign.json."""

    varied: str  # "delay", "jitter" or "loss"
    key: str  # the [faults] key
    unit: str
    scenario: str
    cmd_path: str
    endpoint: str
    tracking_bound: float | None
    steps: list[Step] = field(default_factory=list)
    largest_held: float | None = None
    first_broken: float | None = None
    interrupted: bool = False

    def save(self, out: Path) -> None:
        (out / CAMPAIGN_JSON).write_text(json.dumps(asdict(self), indent=2) + "\n")
        (out / CAMPAIGN_MD).write_text(self.markdown())

    def shown(self, value: float | None) -> str:
        if value is None:
            return "none"
        return f"{value * 1e3:g} ms" if self.unit == "ms" else f"{value * 100:g} %"

    def answer(self) -> str:
        if not self.steps:
            return "no run finished"
        if self.largest_held is None:
            return (
                f"your device broke a limit with nothing added ({self.key} = 0): the campaign "
                "has no margin to measure"
            )
        tail = (
            f"; it broke at {self.shown(self.first_broken)}"
            if self.first_broken is not None
            else " (nothing broke up to the campaign's end)"
        )
        return f"largest {self.varied} added that held: {self.shown(self.largest_held)}{tail}"

    def markdown(self) -> str:
        lines = [
            f"# Campaign: added feedback {self.varied} toward your device",
            "",
            f"**{self.answer()}**",
            "",
            f"Scenario {self.scenario}, commands on {self.cmd_path}, device endpoint "
            f"{self.endpoint}; each run adds `[faults] {self.key}` to the path toward the device"
            + (
                f"; tracking bound {self.tracking_bound:g} m (RMS)." if self.tracking_bound else "."
            ),
            "",
            f"| {self.key} | held | verdict | broken | response p50 | RMS position error | run |",
            "|---|---|---|---|---|---|---|",
        ]
        for s in self.steps:
            resp = f"{s.response_p50_ms:.2f} ms" if s.response_p50_ms is not None else "-"
            rms = f"{s.rms_position_error:.4g} m" if s.rms_position_error is not None else "-"
            lines.append(
                f"| {self.shown(s.value)} | {'yes' if s.held else 'NO'} | {s.outcome} | "
                f"{', '.join(s.broken) or '-'} | {resp} | {rms} | {s.run_dir} |"
            )
        if self.interrupted:
            lines += ["", "Interrupted: the table holds the runs that finished."]
        return "\n".join(lines) + "\n"


def values(step: float, end: float) -> list[float]:
    """0, step, 2 step, ... up to end (inclusive, within rounding)."""
    n = math.floor(end / step + 1e-9)
    return [round(k * step, 12) for k in range(n + 1)]


def _response_p50_ms(summary: Any) -> float | None:
    """The device's median response time from summary.json (None when not measured)."""
    device = summary.get("device") or {}
    resp = device.get("response") or {}
    p50 = resp.get("p50_us") if isinstance(resp, dict) else None
    return float(p50) / 1e3 if isinstance(p50, int | float) else None


def judge_step(value: float, run_dir: Path, summary: Any, bound: float | None) -> Step:
    """Whether the run held: every limit of (2) held, and the tracking error within the bound."""
    from hil.verdict import run_started

    violations = summary.get("violations") or {}
    broken = [name for name, n in violations.items() if n]
    rms = summary.get("rms_position_error")
    if bound is not None and (rms is None or not rms <= bound):
        broken.append("tracking")
    outcome = str((summary.get("verdict") or {}).get("outcome") or "FAIL")
    peaks = {k: summary.get(k) for k in ("max_abs_v", "max_abs_omega")}
    return Step(
        value=value,
        run_dir=str(run_dir),
        outcome=outcome,
        limits_held=not [b for b in broken if b != "tracking"],
        broken=broken,
        rms_position_error=rms,
        peaks=peaks,
        response_p50_ms=_response_p50_ms(summary),
        held=not broken and run_started(summary),
    )


def _step_scenario(out: Path, base: str, key: str, value: float, k: int) -> Path:
    """The k-th run's scenario: the campaign's, with the value added (docs/scenario.md, base)."""
    path = out / "scenarios" / f"step-{k:03d}.toml"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f'base = "{base}"\n\n[faults]\n{key} = {value!r}\n')
    return path


def _run_steps(
    record: Campaign,
    folder: Path,
    base: str,
    tried: list[float],
    run_options: dict[str, Any],
    wait_device: float,
    keep_going: bool,
) -> None:
    """One ``hil run --controller external`` per value, until one breaks (or all ran)."""
    from hil.analysis.analyze import write_results
    from hil.bench.lifecycle import execute
    from hil.bench.prepare import RunOptions

    for k, value in enumerate(tried):
        ticker.say(
            f"hil campaign: run {k + 1} of {len(tried)}: {record.key} = {record.shown(value)}"
        )
        recorded = execute(
            RunOptions(
                scenario=_step_scenario(folder, base, record.key, value, k),
                out=folder / f"run-{k:03d}",
                quiet=True,
                controller="external",
                wait_device=wait_device if k == 0 else LATER_WAIT_S,
                **run_options,
            )
        )
        summary = write_results(recorded)
        if summary.get("interrupted") or interrupts.happened():
            record.interrupted = True
            return
        s = judge_step(value, recorded.run_dir, summary, record.tracking_bound)
        record.steps.append(s)
        ticker.say(
            f"hil campaign: {record.key} = {record.shown(value)}: "
            + ("held" if s.held else f"broke ({', '.join(s.broken) or summary.get('error')})")
        )
        if s.held and record.first_broken is None:
            record.largest_held = value
        elif record.first_broken is None:
            record.first_broken = value
            if not keep_going:
                return
        record.save(folder)


def _folder_and_base(
    scenario: str | None, out: Path | None, force: bool, vary: str
) -> tuple[Path, str]:
    """The campaign's folder (claimed), and the scenario each run starts from (its path)."""
    from hil.bench.defaults import PAPER_TRACKING_TOML
    from hil.bundled import resolve_scenario
    from hil.folder import claim, new_run_dir

    base = None if scenario is None else str(resolve_scenario(scenario).resolve())
    claim.check("--out", out, force, default="runs")
    folder = out or new_run_dir(prefix=f"campaign-{vary}")
    claim.take(folder, "campaign")
    folder.mkdir(parents=True, exist_ok=True)
    if base is None:  # hil run's default, written where each run's scenario can name it
        (folder / "scenario.toml").write_text(PAPER_TRACKING_TOML)
        base = str((folder / "scenario.toml").resolve())
    return folder, base


@app.command("campaign")
def campaign(
    scenario: Annotated[
        str | None,
        typer.Argument(help="Scenario TOML or bundled name (default: hil run's default)."),
    ] = None,
    vary: Annotated[
        str, typer.Option(help="What grows run after run: delay, jitter or loss.")
    ] = "delay",
    step: Annotated[
        float | None, typer.Option(help="Growth per run (s; loss: a probability).")
    ] = None,
    end: Annotated[float | None, typer.Option(help="Largest value tried (s; loss: <= 1).")] = None,
    duration: Annotated[float, typer.Option(help="Each run's length in s.")] = 5.0,
    cmd_path: Annotated[str, typer.Option(help="zenoh or can: the device's path.")] = "zenoh",
    can_interface: Annotated[str | None, typer.Option(help="python-can interface.")] = None,
    can_channel: Annotated[str | None, typer.Option(help="python-can channel.")] = None,
    zenoh_endpoint: Annotated[
        str | None, typer.Option(help="tcp/HOST:PORT for every run (default: one free port).")
    ] = None,
    can_endpoint: Annotated[
        str | None, typer.Option(help="zenoh_can's tcp/HOST:PORT for every run.")
    ] = None,
    wait_device: Annotated[float, typer.Option(help="s to wait for the device at first.")] = 60.0,
    tracking_bound: Annotated[
        float | None,
        typer.Option(help="Also broken when the RMS position error exceeds this (m)."),
    ] = None,
    out: Annotated[
        Path | None, typer.Option(help="Campaign folder (default runs/campaign-*).")
    ] = None,
    keep_going: Annotated[
        bool, typer.Option(help="Run every value, not only up to the first that broke.")
    ] = False,
    force: ForceOpt = False,
) -> None:
    """Measure how much added delay (or jitter, or loss) on the path toward YOUR device it
    holds before a limit of (2) breaks: runs `hil run --controller external` again and again
    on the same endpoint, the device kept running (docs/external.md, "Campaign")."""
    from hil.bench.prepare import free_port

    if vary not in VARIED:
        raise BadInputError(f"--vary {vary!r}: one of {', '.join(VARIED)}")
    key, unit, step0, end0 = VARIED[vary]
    step, end = step if step is not None else step0, end if end is not None else end0
    if not step > 0 or not end >= step or (vary == "loss" and end > 1):
        raise BadInputError(f"--step {step:g} and --end {end:g}: 0 < step <= end (loss: end <= 1)")
    folder, base = _folder_and_base(scenario, out, force, vary)
    zenoh_endpoint = zenoh_endpoint or f"tcp/127.0.0.1:{free_port()}"
    can_endpoint = can_endpoint or f"tcp/127.0.0.1:{free_port()}"
    endpoint = zenoh_endpoint if cmd_path == "zenoh" else can_endpoint
    name = scenario or "paper_tracking (default)"
    record = Campaign(vary, key, unit, name, cmd_path, endpoint, tracking_bound)
    tried = values(step, end)
    ticker.start_line(
        "campaign",
        f"{len(tried)} runs of {duration:g} s, [faults] {key} from 0 to {record.shown(end)}",
        f"about {len(tried) * (duration + 10):.0f} s",
        folder,
    )
    run_options = {
        "duration": duration,
        "cmd_path": cmd_path,
        "can_interface": can_interface,
        "can_channel": can_channel,
        "zenoh_endpoint": zenoh_endpoint,
        "can_endpoint": can_endpoint,
    }
    _run_steps(record, folder, base, tried, run_options, wait_device, keep_going)
    record.save(folder)
    typer.echo(f"campaign: {record.answer()}; {folder / CAMPAIGN_MD}")
    if record.interrupted:
        interrupts.note(f"campaign folder written to {folder}")
        return
    if record.steps and record.largest_held is None:
        raise NegativeVerdictError(record.answer(), "FAIL")
