"""``hil lab up|down|status|exec``: a lab of hosts on this machine (hil.bench.lab, docs/lab.md)."""

from __future__ import annotations

import json
import subprocess
from typing import Annotated

import typer

from hil.commands import app
from hil.errors import BadInputError

LAB_NAME = "lab"


def _pairs(values: list[str], option: str) -> dict[str, float]:
    """``HOST=VALUE`` options as a dict; a malformed one is a BadInputError naming it."""
    out: dict[str, float] = {}
    for item in values:
        try:
            host, value = item.split("=", 1)  # ValueError without "="
            out[host] = float(value)
        except ValueError:
            raise BadInputError(f"{option} {item!r}: expected HOST=NUMBER, e.g. h2=0.02") from None
    return out


def _impairments(loss: list[str], rate: list[str]) -> dict[str, object]:
    from hil.bench.lab.net import LinkImpairment

    losses = _pairs(loss, "--loss")
    rates = _pairs(rate, "--rate-bps")
    for host, value in losses.items():
        if not 0.0 <= value < 1.0:
            raise BadInputError(f"--loss {host}={value}: a fraction in [0, 1)")
    for host, value in rates.items():
        if value < 8000:
            raise BadInputError(f"--rate-bps {host}={value}: at least 8000 bit/s")
    return {h: LinkImpairment(losses.get(h, 0.0), rates.get(h, 0.0)) for h in {*losses, *rates}}


NameOpt = Annotated[str, typer.Option(help="The lab's name (1-12 of [a-z0-9]).")]


lab = typer.Typer(
    help="A lab of hosts on this machine: network namespaces joined by veth links through "
    "a bridge, each with its own CLOCK_MONOTONIC offset and Zenoh router. Needs root.",
    no_args_is_help=True,
)
app.add_typer(lab, name="lab")


@lab.command("up")
def up_cmd(
    hosts: Annotated[int, typer.Option(help="Number of hosts (h1..hN).")] = 2,
    name: NameOpt = LAB_NAME,
    offset: Annotated[
        list[str], typer.Option(help="HOST=SECONDS: the host's CLOCK_MONOTONIC offset.")
    ] = [],  # noqa: B006 (typer reads the default, never mutates it)
    loss: Annotated[
        list[str], typer.Option(help="HOST=FRACTION of the packets the host receives dropped.")
    ] = [],  # noqa: B006
    rate_bps: Annotated[
        list[str], typer.Option(help="HOST=BITS_PER_SECOND: the host's sending rate cap.")
    ] = [],  # noqa: B006
) -> None:
    """Build the lab: h1..hN, a router on each (tcp/127.0.0.1:7447 from inside the host,
    tcp/10.231.0.i:7447 between hosts). Ctrl-C while it builds removes what was made; a
    lab left by a killed `up` is removed by the next `up` or `down`."""
    from hil.bench.lab.lab import up

    state = up(name, hosts, _pairs(offset, "--offset"), _impairments(loss, rate_bps))
    typer.echo(json.dumps({"lab": name, "hosts": state.hosts}, indent=2))


@lab.command("down")
def down_cmd(name: NameOpt = LAB_NAME) -> None:
    """Remove the lab: its processes (proven by PID, start time and the lab's mark), its
    namespaces and their links, its time namespaces and its folder."""
    from hil.bench.lab.lab import down

    typer.echo(json.dumps(down(name)))


@lab.command("status")
def status_cmd(
    name: Annotated[str | None, typer.Option(help="One lab (default: all).")] = None,
) -> None:
    """Each lab's hosts: offset, address, router, impairment and its kernel counters."""
    from hil.bench.lab.lab import status

    typer.echo(json.dumps(status(name), indent=2))


@lab.command("exec", context_settings={"allow_extra_args": True, "ignore_unknown_options": True})
def exec_cmd(
    ctx: typer.Context,
    host: Annotated[str, typer.Argument(help="The host (h1, h2, ...).")],
    name: NameOpt = LAB_NAME,
) -> None:
    """Run a command on a host: `hil lab exec h2 -- python -c '...'` (its network and its
    clock; its router is tcp/127.0.0.1:7447). Exits with the command's code."""
    from hil.bench.lab.lab import host_command, host_env, require_root
    from hil.bench.lab.state import load

    require_root("hil lab exec")
    state = load(name)
    if state is None or state.phase != "up":
        raise BadInputError(f"lab {name} is not up (hil lab up --name {name})")
    if not ctx.args:
        raise BadInputError("hil lab exec HOST -- COMMAND...: no command")
    code = subprocess.call(host_command(state, host, list(ctx.args)), env=host_env(state))
    raise typer.Exit(code)
