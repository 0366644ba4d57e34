"""The live view: the running bench served over the Foxglove WebSocket protocol (docs/live.md);
:mod:`hil.bench.live.watch` is its process, :mod:`hil.bench.live.launch` starts it."""
