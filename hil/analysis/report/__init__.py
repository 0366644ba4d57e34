"""Reports of run and simulation folders: ``hil report`` and ``hil compare``."""
