"""The bench wing: starts the processes of a run, records them and writes the raw run folder
(docs/architecture.md). It never imports :mod:`hil.analysis`: the commands run the analysis on
the folder the bench wrote."""
