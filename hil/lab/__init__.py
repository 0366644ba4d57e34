"""A lab of hosts on one machine (docs/lab.md): network namespaces joined by veth links through
a bridge in a private namespace, each host with its own ``CLOCK_MONOTONIC`` offset (a time
namespace) and its own Zenoh router, the routers linked to each other. ``hil lab`` is
:mod:`hil.lab.lab`; what it made, and how leftovers are proven its own, :mod:`hil.lab.state`."""
