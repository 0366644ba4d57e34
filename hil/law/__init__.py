"""A user's own control law on the bench: the ``--law`` option, the batch-path check of a law
that may only take floats, and the template ``hil new-law`` writes (docs/own-controller.md)."""
