"""The analysis wing: reads a run folder and writes what it derives into it (the figures,
trace.csv, summary.json with the verdict, the reports; docs/architecture.md). It never imports
:mod:`hil.bench`."""
