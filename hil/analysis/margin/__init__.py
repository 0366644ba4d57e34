"""``hil margin``: how much worse the timing may get before the controller breaks (2), for
every law the bench loads that runs on the batch path (numpy arrays), the user's own included."""
