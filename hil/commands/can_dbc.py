"""``hil can-dbc``: the CANSimple DBC for the node ids in use."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from hil.commands import ForceOpt, app
from hil.errors import BadInputError


@app.command("can-dbc")
def can_dbc(
    nodes: Annotated[
        str, typer.Option(help="Node ids: a range and/or a list, e.g. 0-7 or 0,1,12 (0..63).")
    ] = "0-7",
    out: Annotated[
        Path | None, typer.Option(help="Write odrive_cansimple.dbc in this folder (else: stdout).")
    ] = None,
    force: ForceOpt = False,
) -> None:
    """Write the ODrive CANSimple (firmware 0.6) DBC with one message set per node id, so
    that `cantools decode` names every frame of those nodes. The file shipped in the
    package (protocol/can/odrive_cansimple.dbc) is the one for 0-7, as ODrive's own."""
    from hil.folder import claim
    from protocol.can.dbc import parse_nodes, render

    claim.check("--out", out, force)
    try:
        text = render(parse_nodes(nodes))
    except ValueError as exc:
        raise BadInputError(str(exc)) from exc
    if out is None:
        typer.echo(text, nl=False)
        return
    claim.take(out, "can-dbc")
    (out / "odrive_cansimple.dbc").write_text(text, encoding="utf-8")
    typer.echo(f"wrote {out / 'odrive_cansimple.dbc'} for nodes {nodes}")
