"""``hil margin``: how much worse the timing may get before the controller breaks (2).

:mod:`hil.margin.timing` (the replayed timing, scaled by k), :mod:`hil.margin.search` (the
bisection for k*), :mod:`hil.margin.record` (margin.json). Works for every law the bench loads
that runs on the batch path (numpy arrays), the user's own included.
"""
