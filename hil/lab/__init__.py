"""A lab of hosts on one machine (docs/lab.md): network namespaces joined by veth links through
a bridge in a private namespace, each host with its own ``CLOCK_MONOTONIC`` offset (a time
namespace) and its own Zenoh router, the routers linked to each other.

:mod:`hil.lab.state` keeps what the lab made (the owner marks that let a later ``up`` or
``down`` clean leftovers it can prove are its own), :mod:`hil.lab.net` makes and removes the
kernel's objects, :mod:`hil.lab.timens` a time namespace with a fractional offset,
:mod:`hil.lab.router` a host's router, :mod:`hil.lab.lab` ``up``/``down``/``status``.
"""
