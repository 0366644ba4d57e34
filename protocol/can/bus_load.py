"""Bit length of classical CAN frames and the bus load of the drive profile.

Worst-case length of a classical CAN frame with ``n`` data bytes, in bits, following
Davis, Burns, Bril, Lukkien, "Controller Area Network (CAN) schedulability analysis: Refuted,
revisited and revised", Real-Time Systems 35 (2007), eq. (3):

    C(n) = g + 8 n + 13 + floor((g + 8 n - 1) / 4)

with g = 34 for an 11-bit identifier (g = 54 for a 29-bit one). The g + 8 n bits from the start
of frame to the end of the CRC are subject to bit stuffing (worst case one stuff bit per four
after the first); the 13 unstuffed bits are the CRC delimiter (1), ACK slot and delimiter (2),
end of frame (7) and the 3-bit interframe space. So for an 11-bit id: 47 + 8 n bits plus the
stuffing floor((34 + 8 n - 1) / 4), the interframe space included: 135 bits at n = 8, 55 at
n = 0. A remote (RTR) frame carries no data field whatever its DLC.
"""

from __future__ import annotations

from dataclasses import dataclass

from protocol.can import codec
from protocol.can.codec import Cmd


def frame_bits(
    dlc: int, extended: bool = False, remote: bool = False, stuffing: bool = True
) -> int:
    """Worst-case bits a classical CAN frame occupies on the bus, interframe space included."""
    if not 0 <= dlc <= 8:
        raise ValueError(f"classical CAN DLC is 0..8, got {dlc}")
    n = 0 if remote else dlc
    g = 54 if extended else 34
    stuff = (g + 8 * n - 1) // 4 if stuffing else 0
    return g + 8 * n + 13 + stuff


def frame_time(dlc: int, bitrate: float, extended: bool = False, remote: bool = False) -> float:
    """Seconds a frame occupies the bus at ``bitrate`` bit/s (worst-case stuffing)."""
    if not bitrate > 0:
        raise ValueError(f"bitrate must be positive, got {bitrate}")
    return frame_bits(dlc, extended, remote) / bitrate


@dataclass(frozen=True)
class PeriodicFrame:
    """One periodic frame of the profile: its name, payload length, count per period, rate."""

    name: str
    dlc: int
    per_second: float

    @property
    def bits(self) -> int:
        return frame_bits(self.dlc)

    @property
    def bits_per_second(self) -> float:
        return self.bits * self.per_second


def profile_frames(
    rate: float, drives: int = 2, heartbeat_rate: float = 10.0, encoder_rate: float | None = None
) -> list[PeriodicFrame]:
    """The periodic traffic of the profile: per control cycle one Set_Input_Torque per drive;
    per drive a Heartbeat at ``heartbeat_rate`` and Encoder_Estimates at ``encoder_rate``
    (default: the control rate, since the loop needs a fresh estimate each cycle)."""
    if not rate > 0 or drives < 1 or heartbeat_rate < 0:
        raise ValueError("rate must be > 0, drives >= 1, heartbeat_rate >= 0")
    enc = rate if encoder_rate is None else encoder_rate
    if enc < 0:
        raise ValueError("encoder_rate must be >= 0")
    db = codec.database()

    def dlc(cmd: Cmd) -> int:
        return db.get_message_by_frame_id(int(cmd)).length

    return [
        PeriodicFrame("Set_Input_Torque", dlc(Cmd.SET_INPUT_TORQUE), drives * rate),
        PeriodicFrame("Get_Encoder_Estimates", dlc(Cmd.GET_ENCODER_ESTIMATES), drives * enc),
        PeriodicFrame("Heartbeat", dlc(Cmd.HEARTBEAT), drives * heartbeat_rate),
    ]


def bus_load_percent(frames: list[PeriodicFrame], bitrate: float) -> float:
    """Share of the bus time the frames occupy, in percent (above 100: the bus cannot carry
    them and queues grow without bound)."""
    if not bitrate > 0:
        raise ValueError(f"bitrate must be positive, got {bitrate}")
    return 100.0 * sum(f.bits_per_second for f in frames) / bitrate
