"""``python -m hil.live``: :func:`hil.live.watch.main`."""

from hil.live.watch import main

raise SystemExit(main())
