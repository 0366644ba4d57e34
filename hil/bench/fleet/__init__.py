"""``hil fleet``: N closed loops at once, one run folder per robot and a fleet report
(docs/fleet.md)."""
