"""The services' taps (protocol.tap, runtime.tap) and what observers make of them (hil.observe):
strict decoding, every entry delivered in order over real Zenoh, losses counted, log times on the
observer's clock, and observers that never subscribe to the loop's own keys."""

from __future__ import annotations

import json
import random
import subprocess
import sys
import threading
from pathlib import Path

import msgpack
import pytest
import zenoh

from hil.observe import InTimeOrder, Observed, TapReader
from protocol import keys
from protocol.messages import MAX_MESSAGE_BYTES, DecodeError, State, encode
from protocol.tap import (
    MAX_BATCH_BYTES,
    MAX_BATCH_ENTRIES,
    TAP_TAG,
    TAP_VERSION,
    TapEntry,
    decode_batch,
    encode_batch,
)
from runtime.tap import Tap
from runtime.zsession import open_session
from tests.procs import free_tcp_port, wait_until

ROOT = Path(__file__).resolve().parents[1]
KEY = keys.tap_key("robot0", "plant")
ENTRIES = [
    TapEntry(keys.STATE, 10, b"\x01\x02"),
    TapEntry(keys.TORQUE, 20, b"", "malformed"),
    TapEntry(keys.TELEMETRY, 2**62, bytes(MAX_MESSAGE_BYTES)),
]


def _batch(*fields: object) -> bytes:
    return msgpack.packb(list(fields), use_bin_type=True)


def test_a_batch_round_trips_every_entry_as_it_was() -> None:
    b = decode_batch(encode_batch("robot0", "plant", 7, 123, ENTRIES))
    assert (b.robot_id, b.role, b.seq, b.send_time_ns) == ("robot0", "plant", 7, 123)
    assert b.entries == tuple(ENTRIES)


GOOD = ["robot0", "plant", 1, 2, [["state", 3, b"x", ""]]]
REFUSED = [
    ("not bytes", "text", "not_bytes"),
    ("too large", bytes(MAX_BATCH_BYTES + 1), "too_large"),
    ("not msgpack", b"\xc1", "malformed"),
    ("trailing bytes", _batch(TAP_TAG, TAP_VERSION, *GOOD) + b"\x00", "trailing_bytes"),
    ("a map", msgpack.packb({"a": 1}), "not_array"),
    ("no header", _batch(TAP_TAG), "bad_header"),
    ("a message's tag", _batch(1, TAP_VERSION, *GOOD), "unknown_type"),
    ("a newer version", _batch(TAP_TAG, 2, *GOOD), "unknown_version"),
    ("a field short", _batch(TAP_TAG, TAP_VERSION, *GOOD[:-1]), "missing_field"),
    ("a field more", _batch(TAP_TAG, TAP_VERSION, *GOOD, 0), "extra_field"),
    ("robot id with a slash", _batch(TAP_TAG, TAP_VERSION, "a/b", *GOOD[1:]), "bad_identifier"),
    ("role not a word", _batch(TAP_TAG, TAP_VERSION, "r", "Plant!", *GOOD[2:]), "bad_identifier"),
    ("negative seq", _batch(TAP_TAG, TAP_VERSION, "r", "plant", -1, 2, []), "out_of_range"),
    ("bool as seq", _batch(TAP_TAG, TAP_VERSION, "r", "plant", True, 2, []), "wrong_type"),
    ("entries a map", _batch(TAP_TAG, TAP_VERSION, "r", "plant", 1, 2, {}), "wrong_type"),
    (
        "too many entries",
        _batch(TAP_TAG, TAP_VERSION, "r", "p", 1, 2, [["state", 1, b"", ""]] * 4097),
        "out_of_range",
    ),
    (
        "unknown stream",
        _batch(TAP_TAG, TAP_VERSION, "r", "p", 1, 2, [["x", 1, b"", ""]]),
        "bad_identifier",
    ),
    (
        "payload as str",
        _batch(TAP_TAG, TAP_VERSION, "r", "p", 1, 2, [["state", 1, "x", ""]]),
        "wrong_type",
    ),
    (
        "payload too long",
        _batch(TAP_TAG, TAP_VERSION, "r", "p", 1, 2, [["state", 1, bytes(4097), ""]]),
        "too_large",
    ),
    (
        "entry short",
        _batch(TAP_TAG, TAP_VERSION, "r", "p", 1, 2, [["state", 1, b""]]),
        "missing_field",
    ),
    (
        "reason not a word",
        _batch(TAP_TAG, TAP_VERSION, "r", "p", 1, 2, [["state", 1, b"", "X"]]),
        "bad_identifier",
    ),
    (
        "stamp a float",
        _batch(TAP_TAG, TAP_VERSION, "r", "p", 1, 2, [["state", 1.0, b"", ""]]),
        "wrong_type",
    ),
]


@pytest.mark.parametrize(("case", "data", "reason"), REFUSED, ids=[c for c, *_ in REFUSED])
def test_each_malformed_batch_is_refused_with_its_reason(case: str, data: object, reason: str):
    with pytest.raises(DecodeError) as got:
        decode_batch(data)
    assert got.value.reason == reason, (case, got.value)


def test_random_and_mutated_batches_raise_only_decode_errors() -> None:
    """20,000 seeded mutations of a valid batch: a DecodeError or a whole batch that encodes
    back to what was decoded, never another exception."""
    rng = random.Random(20261127)
    good = encode_batch("robot0", "plant", 3, 4, ENTRIES)
    accepted = refused = 0
    for _ in range(20_000):
        data = bytearray(good)
        for _ in range(rng.randint(1, 4)):
            op = rng.randrange(3)
            i = rng.randrange(len(data))
            if op == 0:
                data[i] = rng.randrange(256)
            elif op == 1:
                del data[i : i + rng.randint(1, 8)]
            else:
                data[i:i] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 4)))
        try:
            b = decode_batch(bytes(data))
        except DecodeError:
            refused += 1
            continue
        accepted += 1
        again = decode_batch(encode_batch(b.robot_id, b.role, b.seq, b.send_time_ns,
                                          list(b.entries)))  # fmt: skip
        assert again == b
    assert refused > 10_000 and accepted > 0


@pytest.fixture
def two_sessions():
    ep = f"tcp/127.0.0.1:{free_tcp_port()}"
    observer = open_session(ep, listen_endpoint=True, credentials=None)
    service = open_session(ep, credentials=None)
    try:
        yield service, observer
    finally:
        service.close()
        observer.close()


def test_a_tap_over_zenoh_delivers_every_entry_in_order_within_the_batch_limits(two_sessions):
    """9,000 entries (some refused payloads of the largest size) through a real Zenoh session:
    every one arrives, in order, in batches that each fit the decoder's limits, numbered
    without a gap."""
    service, observer = two_sessions
    got: list[bytes] = []
    sub = observer.declare_subscriber(KEY, lambda s: got.append(bytes(s.payload.to_bytes())))
    tap = Tap(service, "robot0", "plant")
    assert wait_until(lambda: tap._pub.matching_status.matching, 10)
    sent = []
    for i in range(9_000):
        if i % 500 == 7:
            tap.rejected(keys.TORQUE, i, bytes(MAX_MESSAGE_BYTES + 100), "too_large")
            sent.append((keys.TORQUE, i, MAX_MESSAGE_BYTES, "too_large"))
        else:
            tap.sent(keys.STATE, i, i.to_bytes(4, "little"))
            sent.append((keys.STATE, i, 4, ""))
        if i % 4500 == 4499:
            tap.flush()
    tap.close()
    assert wait_until(lambda: len(got) >= tap.batches, 10)
    sub.undeclare()
    batches = [decode_batch(p) for p in got]
    assert [b.seq for b in batches] == list(range(tap.batches))
    assert all(len(p) <= MAX_BATCH_BYTES and len(b.entries) <= MAX_BATCH_ENTRIES
               for p, b in zip(got, batches, strict=True))  # fmt: skip
    assert len(batches) == 4  # 4,500 entries do not fit one batch
    received = [(e.stream, e.stamp_ns, len(e.payload), e.rejected) for b in batches
                for e in b.entries]  # fmt: skip
    assert received == sent
    assert tap.counters() == {"tap_batches": len(got), "tap_entries": 9_000, "tap_put_errors": 0}


def test_a_refusal_after_the_close_is_put_at_once_and_numbered_on(two_sessions):
    """A callback still running while its service shuts down refuses a payload after the tap's
    last regular batch: it is put at once (never left in a tap nobody flushes), with the next
    batch number."""
    service, observer = two_sessions
    got: list[bytes] = []
    sub = observer.declare_subscriber(KEY, lambda s: got.append(bytes(s.payload.to_bytes())))
    tap = Tap(service, "robot0", "plant")
    assert wait_until(lambda: tap._pub.matching_status.matching, 10)
    tap.sent(keys.STATE, 1, b"a")
    tap.close()
    tap.rejected(keys.TORQUE, 2, b"\xc1", "malformed")
    tap.rejected(keys.TORQUE, 3, b"\xc1", "malformed")
    assert wait_until(lambda: len(got) >= 3, 10)
    sub.undeclare()
    batches = [decode_batch(p) for p in got]
    assert [b.seq for b in batches] == [0, 1, 2]
    assert [[e.stamp_ns for e in b.entries] for b in batches] == [[1], [2], [3]]
    assert tap.counters() == {"tap_batches": 3, "tap_entries": 3, "tap_put_errors": 0}


def test_the_reader_counts_a_lost_batch_and_a_restart_exactly() -> None:
    """Known answer: batches 0, 1, 3 (2 lost), then 0 again (the service restarted)."""
    reader = TapReader()
    for seq in (0, 1, 3, 0, 1):
        reader.read(KEY, 0, encode_batch("robot0", "plant", seq, 0, ENTRIES[:1]))
    c = reader.counts()
    assert (c["tap_batches"], c["tap_batches_lost"], c["tap_restarts"]) == (5, 1, 1)
    assert c["tap_entries"] == 5


def test_log_times_are_the_senders_stamps_or_carried_by_the_batch_transit() -> None:
    batch = encode_batch("robot0", "plant", 0, 5_000, [TapEntry(keys.STATE, 4_000, b"s")])
    same = TapReader(same_clock=True).read(KEY, 9_999_999, batch)
    assert same == [Observed("hil/robot0/state", 4_000, b"s", "", "plant")]
    # Another host's clock: received at 1_000_300 on ours, sent at 5_000 on its own.
    other = TapReader(same_clock=False).read(KEY, 1_000_300, batch)
    assert other[0].log_time_ns == 1_000_300 - (5_000 - 4_000)


def test_batches_on_the_wrong_key_or_malformed_are_refused_and_counted() -> None:
    reader = TapReader()
    assert reader.read(keys.tap_key("robot9", "plant"), 0,
                       encode_batch("robot0", "plant", 0, 0, ENTRIES)) == []  # fmt: skip
    assert reader.read(keys.tap_key("robot0", "controller"), 0,
                       encode_batch("robot0", "plant", 0, 0, ENTRIES)) == []  # fmt: skip
    assert reader.read(KEY, 0, b"\xc1") == []
    assert reader.counts()["tap_batches_refused"] == {"malformed": 1, "wrong_key": 2}
    # What is not a tap passes through, on its own key at its receive time.
    assert reader.read("hil/robot0/status", 42, b"p") == [Observed("hil/robot0/status", 42, b"p")]


def test_in_time_order_merges_two_senders_batches_after_the_hold() -> None:
    order = InTimeOrder(hold_ns=100)
    for t in (10, 30, 50):  # the plant's batch
        order.push(Observed("hil/r/state", t, b""))
    for t in (20, 40):  # the controller's, arriving after
        order.push(Observed("hil/r/cmd/torque", t, b""))
    assert [m.log_time_ns for m in order.ready(now_ns=135)] == [10, 20, 30]
    order.push(Observed("hil/r/state", 25, b""))  # older than what was given back: late
    assert [m.log_time_ns for m in order.ready(now_ns=None)] == [25, 40, 50]
    assert order.late == 1 and len(order) == 0


def test_observers_subscribe_to_status_and_taps_never_to_the_loops_keys() -> None:
    observed = [zenoh.KeyExpr(k) for k in keys.observed_keys("robot0")]
    hits = lambda k: any(o.intersects(zenoh.KeyExpr(k)) for o in observed)  # noqa: E731
    for loop_key in (keys.state_key("robot0"), keys.torque_key("robot0"),
                     keys.telemetry_key("robot0")):  # fmt: skip
        assert not hits(loop_key), loop_key
    for wanted in (keys.status_key("robot0"), keys.tap_key("robot0", "plant"),
                   keys.tap_key("robot0", "controller")):  # fmt: skip
        assert hits(wanted), wanted
    assert not hits(keys.tap_key("robot1", "plant"))  # another robot's


@pytest.mark.realtime
def test_a_run_records_what_each_service_sent_and_refused_through_its_tap(tmp_path: Path) -> None:
    """A real ``hil run`` while a stranger puts garbage and another robot's State on the state
    key: the recording holds every State the plant sent and every command the controller sent,
    each logged at its sender's own send stamp (the taps', not a receipt), and each refused
    payload as the controller refused it; no batch lost."""
    from hil.folder.recording import read_messages
    from tests.run_helpers import PASSES, check_clean_run, check_verdict, clean_scenario, load_log

    out = tmp_path / "run"
    # A clean run (CLEAN_50HZ): the stranger's puts are refused, its verdict stays PASS.
    argv = [sys.executable, "-m", "hil", "run", str(clean_scenario(tmp_path)), "--duration", "3",
            "--no-can", "--quiet", "--no-report", "--out", str(out)]  # fmt: skip
    run = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    stranger = None
    try:
        assert wait_until(lambda: (out / "controller.hoplog").is_file(), 120)
        endpoint = json.loads((out / "run_settings.json").read_text())["zenoh_endpoint"]
        stranger = open_session(endpoint, credentials=None)
        pub = stranger.declare_publisher(keys.state_key("robot0"))
        other = encode(State("robot7", 1, 1, 1, 0.0, 0.0, 0.0, 0.0, 0.0))
        stop = threading.Event()

        def pester() -> None:
            while not stop.wait(0.05):
                pub.put(b"\xc1")
                pub.put(other)

        t = threading.Thread(target=pester, daemon=True)
        t.start()
        code = run.wait(timeout=180)
        stop.set()
        t.join()
    finally:
        if run.poll() is None:
            run.kill()
        if stranger is not None:
            stranger.close()
    summary = json.loads((out / "summary.json").read_text())
    check_verdict(summary, PASSES, code, out, context=run.stderr.read()[-3000:].decode())
    check_clean_run(summary, "zenoh", out)  # the stranger's puts cost the loop nothing
    assert summary["recorder"]["tap_batches_lost"] == 0
    assert summary["recorder"]["tap_batches_refused"] == {}
    rec = out / "recording.mcap"
    states = [m for m in read_messages(rec, ["hil/robot0/state"])]
    samples = load_log(out / "plant.hoplog").columns("samples")
    assert [m.data["seq"] for m in states] == list(samples["seq"])
    assert all(m.log_time_ns == m.data["send_time_ns"] for m in states)
    ticks = load_log(out / "controller.hoplog").columns("ticks")
    sent_cmds = sorted(s for s in ticks["cmd_seq"] if s >= 0)
    cmds = [m.data["seq"] for m in read_messages(rec, ["hil/robot0/cmd/torque"])]
    assert sent_cmds and set(sent_cmds) <= set(cmds)  # and the final stop command
    refused = [m.data for m in read_messages(rec, ["recorder/rejected"])]
    by_reason = {(d["by"], d["topic"], d["reason"], d["raw"]) for d in refused}
    assert ("controller", "hil/robot0/state", "malformed", "c1") in by_reason
    assert ("controller", "hil/robot0/state", "wrong_robot", other.hex()) in by_reason
    counts = load_log(out / "controller.hoplog").final["rejections"]
    assert counts["malformed"] + counts["wrong_robot"] == len(refused)


@pytest.mark.parametrize("shared_memory", [None, True], ids=["bench config", "zenoh default"])
def test_a_tap_batch_over_3_kb_makes_no_shared_memory_pool(shared_memory: bool | None) -> None:
    """Zenoh's shared-memory transport copies a put over 3 KB into a /dev/shm pool it makes on
    first use (a 6-33 ms stall of the putting thread); the bench's sessions have it off. With
    it on (Zenoh's default, the control case) the same puts map the pool."""
    from protocol.zenoh_config import ZenohSettings, config_dict

    ep = f"tcp/127.0.0.1:{free_tcp_port()}"

    def session(settings: ZenohSettings) -> zenoh.Session:
        conf = zenoh.Config()
        inserts = config_dict(settings)
        if shared_memory is not None:
            inserts["transport/shared_memory/enabled"] = shared_memory
        for key, value in inserts.items():
            conf.insert_json5(key, json.dumps(value))
        return zenoh.open(conf)

    before = _shm_pools()  # a pool an earlier test mapped in this process is not this one's
    observer = session(ZenohSettings(mode="peer", listen=(ep,)))
    service = session(ZenohSettings(mode="peer", connect=(ep,)))
    try:
        got: list[int] = []
        observer.declare_subscriber(KEY, lambda s: got.append(1))
        tap = Tap(service, "robot0", "plant")
        assert wait_until(lambda: tap._pub.matching_status.matching, 10)
        for _ in range(3):
            for i in range(100):
                tap.sent(keys.STATE, i, bytes(80))  # 100 States: an 11 KB batch
            tap.flush()
        assert wait_until(lambda: len(got) == 3, 10)
        pools = _shm_pools() - before
        assert bool(pools) == bool(shared_memory), pools
    finally:
        service.close()
        observer.close()


def _shm_pools() -> set[str]:
    """This process' mappings of Zenoh shared-memory pools."""
    lines = Path("/proc/self/maps").read_text().splitlines()
    return {line for line in lines if "/dev/shm/" in line and line.endswith(".zenoh")}
