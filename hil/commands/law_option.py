"""``--law module:Class``: the same option and help on ``hil run``, ``sim`` and ``sweep``
(what it does: :func:`hil.law.option.with_law`)."""

from __future__ import annotations

from typing import Annotated

import typer

LAW_HELP = (
    "Control law instead of the scenario's: unified, unified_boundary, jiang1997, jiang2001 or "
    "your own 'module:Class' (a module next to the scenario or in the working directory is "
    "found without PYTHONPATH; hil new-law writes one). The scenario's [controller] "
    "parameters are kept only when they name the same law; otherwise the law's defaults."
)
LawOpt = Annotated[str | None, typer.Option("--law", help=LAW_HELP)]
