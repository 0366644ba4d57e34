"""``python -m hil.live``: :func:`hil.live.watch.main`."""

import sys

from hil.live.watch import main

sys.exit(main())
