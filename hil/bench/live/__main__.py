"""``python -m hil.bench.live``: :func:`hil.bench.live.watch.main`."""

from hil.bench.live.watch import main

raise SystemExit(main())
