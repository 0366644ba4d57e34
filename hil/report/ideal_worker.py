"""One part of a long trace's windowed ideal in a process of its own
(:func:`hil.report.ideal_sim._spread`): the part pickled on stdin, its rows pickled on stdout."""

from __future__ import annotations

import pickle
import sys

from hil.report.ideal_sim import _batch


def main() -> None:
    part = pickle.load(sys.stdin.buffer)
    pickle.dump(_batch(part), sys.stdout.buffer, protocol=pickle.HIGHEST_PROTOCOL)


if __name__ == "__main__":
    main()
