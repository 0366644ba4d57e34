"""Which send each received CAN torque frame is: a matching that a lost frame cannot shift.

CANSimple frames carry no sequence number. The controller logs every Set_Input_Torque frame it
put on the bus (``can_tx``: node, send time, command, the float32 torque); the plant logs every
one its drives received (``cmd_rx`` path 1: node, receive time, the torque). Per node, a CAN bus
delivers frames in the order they were sent and never invents one, so the arrivals are a
subsequence of the sends with the same bytes, each received after it was sent. Two cases:

- **Named frames** (the ``zenoh_can`` bus names each frame by its modelled end of transmission,
  which sender and receiver both log): each arrival is the send of that name. Duplicates (a name
  seen again) and reorders (a name older than one already seen) are counted.
- **Unnamed frames** (SocketCAN, a PCAN adapter, ``udp_multicast``): of every way to embed the
  arrivals in the sends (same node, same bytes, order kept, received after sent), the match used
  is the **latest** one: each arrival is the newest unmatched send of its bytes before it
  (:func:`_embed_latest`, computed from the end), the smallest latencies the logs allow. A
  frame lost on the wire is a send no arrival takes. It cannot shift later matches: an arrival
  can only take a send with its own bytes sent before it arrived, and the newest such send is
  its own whenever the transport's delay is shorter than the spacing of identical payloads.
  Where it is not, the logs cannot decide, and this is found, not assumed: with H the largest
  hop the latest matching needs anywhere in the run, the **earliest** embedding whose every hop
  is at most H (:func:`_embed_earliest`) bounds every match from below. An arrival whose two
  matches differ (a loss among identical payloads spaced closer than H, e.g. after a receiver
  stall made H long, or a duplicate on such a bus) is counted ``ambiguous``; every CAN figure
  it feeds carries that count (``not_relatable``), and the command age is also computed with the
  earliest embedding, an upper bound on it, so the certificate is held only if it holds for both
  (hil.measure.figures). An arrival that no send can explain (no earlier send of its bytes left)
  is ``unmatched``; if its bytes are the previous arrival's, it is counted a duplicate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

UNMATCHED = -2  # cmd of an arrival no send explains (-1 is a lifecycle zero)
NAME_TOLERANCE_NS = 2_000  # a name (modelled end of transmission) is logged to the ns on both sides
_BLOCK = 1024  # arrivals compared at once on the fast path (a mismatch costs at most this)


@dataclass(frozen=True)
class NodeMatch:
    """One node's arrivals (in arrival order) matched to its sends (indices into the node's sends
    in bus order; -1 none). ``latest`` is the match the figures use, ``earliest`` the bound."""

    latest: np.ndarray
    earliest: np.ndarray
    duplicated: np.ndarray  # bool per arrival: a copy of a frame already received
    reordered: int  # arrivals older than one received before them (named buses only)
    named: bool

    @property
    def ambiguous(self) -> np.ndarray:
        return (self.latest != self.earliest) & (self.latest >= 0)


def match_node(
    send_ns: np.ndarray,
    send_value: np.ndarray,
    send_name: np.ndarray,
    recv_ns: np.ndarray,
    recv_value: np.ndarray,
    recv_name: np.ndarray,
) -> NodeMatch:
    """Match one node's arrivals to its sends (module docstring)."""
    m = recv_ns.size
    if m and (recv_name > 0).all() and send_name.size and (send_name > 0).all():
        at = _nearest(send_name, recv_name, NAME_TOLERANCE_NS)
        seen = np.zeros(send_ns.size, bool)
        dup = np.zeros(m, bool)
        for j, i in enumerate(at.tolist()):  # duplicates: a name seen before
            if i >= 0:
                dup[j] = seen[i]
                seen[i] = True
        first = at[(at >= 0) & ~dup]
        reordered = int((first[1:] < np.maximum.accumulate(first)[:-1]).sum()) if first.size else 0
        return NodeMatch(at, at, dup, reordered, True)
    sv = np.asarray(send_value, np.float32).view(np.int32)  # compare the frame's bytes exactly
    rv = np.asarray(recv_value, np.float32).view(np.int32)
    feasible = _embed_earliest(sv, send_ns, rv, recv_ns) >= 0
    late = np.full(m, -1, np.int64)
    late[feasible] = _embed_latest(sv, send_ns, rv[feasible], recv_ns[feasible])
    early = np.full(m, -1, np.int64)
    if feasible.any():
        max_hop = int((recv_ns[feasible] - send_ns[late[feasible]]).max())
        early[feasible] = _embed_earliest(
            sv, send_ns, rv[feasible], recv_ns[feasible], max_hop=max_hop
        )
    dup = np.zeros(m, bool)
    if m > 1:
        # An arrival no send explains, with the bytes of the arrival before it: a copy.
        dup[1:] = ~feasible[1:] & (rv[1:] == rv[:-1])
    return NodeMatch(late, early, dup, 0, False)


def _by_value(values: np.ndarray) -> dict[int, np.ndarray]:
    """value -> the sorted indices where it occurs."""
    order = np.argsort(values, kind="stable")
    keys, starts = np.unique(values[order], return_index=True)
    bounds = [*starts.tolist(), order.size]
    return {int(k): order[bounds[n] : bounds[n + 1]] for n, k in enumerate(keys.tolist())}


def _embed_earliest(
    sv: np.ndarray, ss: np.ndarray, rv: np.ndarray, rr: np.ndarray, max_hop: int | None = None
) -> np.ndarray:
    """For each arrival in order, the earliest send after the previous match with its bytes,
    sent before it arrived (and no more than ``max_hop`` before); -1 (and the arrival skipped)
    where there is none. Greedy is exact here: arrivals come in time order, so a later arrival
    never needs an earlier send than the one taken."""
    n, m = sv.size, rv.size
    out = np.full(m, -1, np.int64)
    where = _by_value(sv)
    lo = rr - max_hop if max_hop is not None else np.full(m, np.iinfo(np.int64).min)
    first_ok = np.searchsorted(ss, lo, side="left")  # the oldest send within the hop bound
    i = j = 0
    while j < m and i < n:
        k = min(_BLOCK, m - j, n - i)
        cand = ss[i : i + k]
        ok = (sv[i : i + k] == rv[j : j + k]) & (cand <= rr[j : j + k]) & (cand >= lo[j : j + k])
        run = int(k if ok.all() else np.argmin(ok))
        out[j : j + run] = np.arange(i, i + run)
        i, j = i + run, j + run
        if run == k:
            continue
        idx = where.get(int(rv[j]))
        pos = np.searchsorted(idx, max(i, int(first_ok[j]))) if idx is not None else 0
        if idx is not None and pos < idx.size and ss[idx[pos]] <= rr[j]:
            out[j] = idx[pos]
            i = int(idx[pos]) + 1
        j += 1  # matched after a skip of lost sends, or no send explains it
    return out


def _embed_latest(sv: np.ndarray, ss: np.ndarray, rv: np.ndarray, rr: np.ndarray) -> np.ndarray:
    """For each arrival, from the last back, the newest send before the next arrival's match
    with its bytes, sent before it arrived. Every arrival must be embeddable (the earliest
    embedding found a send for each)."""
    m = rv.size
    out = np.full(m, -1, np.int64)
    where = _by_value(sv)
    # The newest send each arrival could be (sent by its arrival): sends are in time order.
    sent_by = np.searchsorted(ss, rr, side="right") - 1
    hi = sv.size - 1  # the newest send still free
    j = m - 1
    while j >= 0 and hi >= 0:
        k = min(_BLOCK, j + 1, hi + 1)
        s_idx = np.arange(hi, hi - k, -1)
        a_idx = np.arange(j, j - k, -1)
        ok = (sv[s_idx] == rv[a_idx]) & (s_idx <= sent_by[a_idx])
        run = int(k if ok.all() else np.argmin(ok))
        out[a_idx[:run]] = s_idx[:run]
        hi, j = hi - run, j - run
        if run == k or j < 0:
            continue
        idx = where[int(rv[j])]
        bound = min(hi, int(sent_by[j]))
        pos = int(np.searchsorted(idx, bound, side="right")) - 1
        out[j] = idx[pos]  # exists: the earliest embedding is a witness
        hi = int(idx[pos]) - 1
        j -= 1
    return out


def _nearest(keys: np.ndarray, query: np.ndarray, tolerance_ns: int) -> np.ndarray:
    """For each query, the index of the key nearest to it within the tolerance (-1: none)."""
    if keys.size == 0:
        return np.full(query.size, -1, np.int64)
    order = np.argsort(keys, kind="stable")
    ks = keys[order]
    pos = np.clip(np.searchsorted(ks, query), 1, max(1, ks.size - 1))
    left = np.clip(pos - 1, 0, ks.size - 1)
    right = np.clip(pos, 0, ks.size - 1)
    pick = np.where(np.abs(ks[left] - query) <= np.abs(ks[right] - query), left, right)
    ok = np.abs(ks[pick] - query) <= tolerance_ns
    return np.where(ok, order[pick], -1)
