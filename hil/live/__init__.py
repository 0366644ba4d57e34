"""The live view: the running bench served over the Foxglove WebSocket protocol (docs/live.md);
:mod:`hil.live.watch` is its process, :mod:`hil.live.launch` starts it."""
