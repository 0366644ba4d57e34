"""``python -m plant_emulator --settings run_settings.json`` (what ``hil run`` starts), or
``python -m plant_emulator SCENARIO.toml [options]`` standalone (same as ``hil emulator``)."""

from __future__ import annotations

import sys


def main(argv: list[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if len(args) == 2 and args[0] == "--settings":
        from plant_emulator.service import main_from_settings

        return main_from_settings(args[1])
    from hil.cli import main as hil_main

    return hil_main(["emulator", *args])


if __name__ == "__main__":
    sys.exit(main())
