"""State and TorqueCommand over real Zenoh sessions in two processes on loopback.

The child process plays the plant: it answers every TorqueCommand with a State carrying the
command's sequence number and torques, and publishes a Status with its rejection counts when it
refuses a payload. The test process plays the controller with the project's session config
and publisher QoS.
"""

from __future__ import annotations

import contextlib
import queue
import select
import subprocess
import textwrap
import time

import zenoh

from protocol import keys
from protocol import messages as m
from protocol.rejections import RejectionCounter
from protocol.sequence import SequenceTracker
from protocol.zenoh_config import (
    COMMAND_QOS,
    ZenohSettings,
    declare_publisher,
    session_config,
)
from tests.procs import free_tcp_port

ROBOT = "bench_1"

PLANT = textwrap.dedent(
    """
    import sys, time
    import zenoh
    from protocol import keys, messages as m
    from protocol.rejections import RejectionCounter
    from protocol.zenoh_config import (STATE_QOS, STATUS_QOS, ZenohSettings,
                                       declare_publisher, session_config)

    robot, port = sys.argv[1], sys.argv[2]
    settings = ZenohSettings(mode="peer", listen=(f"tcp/127.0.0.1:{port}",), robot_id=robot)
    session = zenoh.open(session_config(settings))
    state_pub = declare_publisher(session, keys.state_key(robot), STATE_QOS)
    status_pub = declare_publisher(session, keys.status_key(robot), STATUS_QOS)
    rejections = RejectionCounter()
    status_seq = 0

    def on_command(sample):
        global status_seq
        cmd = m.decode_counted(sample.payload.to_bytes(), rejections, m.TorqueCommand)
        now = time.monotonic_ns()
        if cmd is None:
            status_seq += 1
            status_pub.put(m.encode(m.Status(robot, status_seq, now, "plant", "running", 0,
                                             rejections.snapshot())))
            return
        state_pub.put(m.encode(m.State(robot, cmd.seq, now, time.monotonic_ns(),
                                       cmd.tau1, cmd.tau2, 0.0, 0.0, 0.0)))

    sub = session.declare_subscriber(keys.torque_key(robot), on_command)
    print("ready", flush=True)
    sys.stdin.read()
    session.close()
    """
)


def wait_for_line(proc: subprocess.Popen, timeout: float) -> str:
    """The child's next stdout line, waiting at most ``timeout`` seconds."""
    ready, _, _ = select.select([proc.stdout], [], [], timeout)
    if not ready:
        raise AssertionError(f"no output from pid {proc.pid} within {timeout} s")
    return proc.stdout.readline().decode().strip()


def test_zenoh_state_and_torque_between_two_processes(spawn) -> None:
    port = free_tcp_port()
    plant = spawn.python(["-c", PLANT, ROBOT, str(port)], stdin=subprocess.PIPE)
    assert wait_for_line(plant, 30.0) == "ready", plant.stderr.read().decode()

    settings = ZenohSettings(mode="peer", connect=(f"tcp/127.0.0.1:{port}",), robot_id=ROBOT)
    session = zenoh.open(session_config(settings))
    try:
        states: queue.Queue[m.State | None] = queue.Queue()
        statuses: queue.Queue[m.Status | None] = queue.Queue()
        rejections = RejectionCounter()
        session.declare_subscriber(
            keys.state_key(ROBOT),
            lambda s: states.put(m.decode_counted(s.payload.to_bytes(), rejections, m.State)),
        )
        session.declare_subscriber(
            keys.status_key(ROBOT),
            lambda s: statuses.put(m.decode_counted(s.payload.to_bytes(), rejections, m.Status)),
        )
        cmd_pub = declare_publisher(session, keys.torque_key(ROBOT), COMMAND_QOS)

        def command(seq: int) -> m.TorqueCommand:
            t = time.monotonic_ns()
            tau1, tau2 = 3.3 * (-1) ** seq, -51.0 + seq * 1e-3
            return m.TorqueCommand(ROBOT, seq, seq, t, t, t, tau1, tau2, "unified", 0)

        # Until the routes are up a put may reach no one: resend seq 0 until it is answered.
        deadline = time.monotonic() + 20.0
        first = None
        while first is None and time.monotonic() < deadline:
            cmd_pub.put(m.encode(command(0)))
            with contextlib.suppress(queue.Empty):
                first = states.get(timeout=0.2)
        assert first is not None and first.seq == 0
        while not states.empty():
            states.get_nowait()

        tracker = SequenceTracker()
        for seq in range(1, 201):
            sent = command(seq)
            cmd_pub.put(m.encode(sent))
            state = states.get(timeout=10.0)
            assert state is not None
            assert tracker.observe(state.seq).fresh
            assert (state.robot_id, state.seq, state.x, state.y) == (
                ROBOT, seq, sent.tau1, sent.tau2
            )  # fmt: skip
        assert tracker.counts.as_dict()["lost"] == 0
        assert tracker.counts.accepted == 200

        # Bad payloads are refused and counted by reason on the other side.
        cmd_pub.put(b"\xc1")
        cmd_pub.put(m.encode(m.State(ROBOT, 1, 1, 1, 0.0, 0.0, 0.0, 0.0, 0.0)))
        last = None
        for _ in range(2):
            last = statuses.get(timeout=10.0)
        assert last is not None
        assert last.role == "plant"
        assert last.counters == {"malformed": 1, "unexpected_type": 1}
        assert rejections.total == 0
    finally:
        session.close()
        # Closing stdin is the child's signal to close its session and exit on its own.
        plant.stdin.close()
        plant.wait(timeout=20.0)
    assert plant.returncode == 0, plant.stderr.read().decode()
