"""The controller announces itself ready only once its commands have a route to the plant
(runtime/startgate.py, ZenohCommandPath.matched): through routers a route forms some time after
both ends declared, and commands sent before it would be lost. Real Zenoh sessions on
loopback."""

from __future__ import annotations

import threading
import time

from controller_service.command_paths import ZenohCommandPath
from protocol import keys
from protocol.messages import Status, decode_as
from runtime.startgate import READY_WITHIN_S, StartGate
from runtime.zsession import open_session, payload_bytes
from tests.procs import free_tcp_port, wait_until


class _Stop:
    """The services' stop flag: truthy once set."""

    def __init__(self) -> None:
        self.set_ = False

    def __bool__(self) -> bool:
        return self.set_


def test_the_controller_is_ready_only_once_the_plants_subscription_reaches_it():
    ep = f"tcp/127.0.0.1:{free_tcp_port()}"
    controller = open_session(ep, listen_endpoint=True, credentials=None)
    plant = open_session(ep, credentials=None)
    try:
        path = ZenohCommandPath(controller, "robot3")
        assert not path.matched()  # nobody subscribes to the command key yet
        readies: list[float] = []

        def on_status(sample) -> None:
            msg = decode_as(Status, payload_bytes(sample))
            if msg.role == "controller" and msg.state == "ready":
                readies.append(time.monotonic())

        watch = plant.declare_subscriber(keys.status_key("robot3"), on_status)
        gate = StartGate(controller, "robot3", "controller")
        stop = _Stop()
        waiter = threading.Thread(target=gate.wait, args=(stop,), kwargs={"ready": path.matched})
        started = time.monotonic()  # the gate's own start is later: its fallback too
        waiter.start()
        time.sleep(0.5)
        assert readies == [] and not path.matched()  # no route for commands: not ready
        subscribed = time.monotonic()
        sub = plant.declare_subscriber(keys.torque_key("robot3"), lambda s: None)
        assert wait_until(lambda: bool(readies), 10), "never ready after the plant subscribed"
        assert path.matched() and readies[0] >= subscribed
        # The route, not the fallback: that fires READY_WITHIN_S after the gate's start, never
        # sooner.
        assert readies[0] < started + READY_WITHIN_S, (readies[0] - started, READY_WITHIN_S)
        stop.set_ = True
        waiter.join(timeout=5)
        sub.undeclare()
        watch.undeclare()
    finally:
        plant.close()
        controller.close()
