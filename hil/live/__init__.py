"""The live view: the running bench served over the Foxglove WebSocket protocol (docs/live.md).

:mod:`hil.live.view` publishes, :mod:`hil.live.timing` computes the once-a-second figures,
:mod:`hil.live.watch` is the process ``hil run --live`` and ``hil drives --live`` start, and
:mod:`hil.live.launch` starts it and checks the options.
"""
