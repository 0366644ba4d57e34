"""``hil can-load``: the worst-case bus load of the CAN drive profile at a control rate."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from hil.commands import ForceOpt, app
from hil.errors import BadInputError, NegativeVerdictError
from hil.options import integer, number, optional_number

RATE_MAX = 1e6  # Hz: frames per second of one kind
BITRATE_MAX = 1e9  # bit/s
DRIVES_MAX = 64  # CANSimple node ids are 0..63


@app.command("can-load")
def can_load(
    rate: Annotated[float, typer.Option(help="Control rate in Hz.")],
    bitrate: Annotated[float, typer.Option(help="CAN bitrate in bit/s.")],
    drives: Annotated[int, typer.Option(help="Drives on the bus.")] = 2,
    heartbeat_rate: Annotated[
        float, typer.Option(help="Heartbeats/s per drive (firmware: 10).")
    ] = 10.0,
    encoder_rate: Annotated[
        float | None,
        typer.Option(help="Encoder estimates per second per drive (default: the control rate)."),
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON, not a table.")] = False,
    out: Annotated[
        Path | None, typer.Option(help="Also write can_load.json in this folder.")
    ] = None,
    force: ForceOpt = False,
) -> None:
    """Bit length of every periodic frame (classical CAN, 11-bit id, worst-case stuffing:
    47 + 8 DLC + floor((34 + 8 DLC - 1)/4) bits, 3-bit interframe space included; Davis
    et al. 2007) and the bus load in percent. Exit code 1 (with a warning) when the load
    exceeds 100%, 2 on bad input."""
    from hil.folder import claim
    from protocol.can.bus_load import bus_load_percent, profile_frames

    rate = number("--rate", rate, 0.0, RATE_MAX, positive=True)
    bitrate = number("--bitrate", bitrate, 0.0, BITRATE_MAX, positive=True)
    drives = integer("--drives", drives, 1, DRIVES_MAX)
    heartbeat_rate = number("--heartbeat-rate", heartbeat_rate, 0.0, RATE_MAX)
    encoder_rate = optional_number("--encoder-rate", encoder_rate, 0.0, RATE_MAX)
    claim.check("--out", out, force)
    try:
        frames = profile_frames(rate, drives, heartbeat_rate, encoder_rate)
        load = bus_load_percent(frames, bitrate)
    except ValueError as exc:
        raise BadInputError(str(exc)) from exc
    report = {
        "rate_hz": rate,
        "bitrate_bps": bitrate,
        "drives": drives,
        "frames": [
            {
                "name": f.name,
                "dlc": f.dlc,
                "bits": f.bits,
                "frames_per_second": f.per_second,
                "bits_per_second": f.bits_per_second,
            }
            for f in frames
        ],
        "bits_per_second": sum(f.bits_per_second for f in frames),
        "load_percent": load,
    }
    if out is not None:
        claim.take(out, "can-load")
        (out / "can_load.json").write_text(json.dumps(report, indent=2) + "\n")
    if as_json:
        typer.echo(json.dumps(report, indent=2))
    else:
        typer.echo(f"{'frame':<24}{'DLC':>4}{'bits':>6}{'frames/s':>11}{'bit/s':>12}")
        for f in frames:
            typer.echo(
                f"{f.name:<24}{f.dlc:>4}{f.bits:>6}{f.per_second:>11.1f}{f.bits_per_second:>12.0f}"
            )
        typer.echo(
            f"total {report['bits_per_second']:.0f} bit/s of {bitrate:.0f}: bus load {load:.2f}%"
        )
    if load > 100.0:
        typer.echo(f"warning: bus load {load:.1f}% > 100%: frames queue without bound", err=True)
        raise NegativeVerdictError(f"CAN bus overloaded ({load:.1f}%)")
