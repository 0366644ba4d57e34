"""``hil sweep``: the closed loop over grids of Ts, delay, jitter and seeds, on the batch path."""
