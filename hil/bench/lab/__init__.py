"""A lab of hosts on one machine (docs/lab.md). ``hil lab`` is :mod:`hil.bench.lab.lab`; what it
made, and how leftovers are proven its own, :mod:`hil.bench.lab.state`."""
