"""Which send each received CAN torque frame is: a matching that a lost frame cannot shift.

CANSimple frames carry no sequence number. The controller logs every Set_Input_Torque frame it
put on the bus (``can_tx``: node, send time, command, the float32 torque); the plant logs every
one its drives received (``cmd_rx`` path 1: node, receive time, the torque). Per node, a CAN bus
delivers frames in the order they were sent and never invents one, so the arrivals are a
subsequence of the sends with the same bytes, each received after it was sent. Two cases:

- **Named frames** (the ``zenoh_can`` bus names each frame by its modelled end of transmission,
  which sender and receiver both log): each arrival is the send of that name. Duplicates (a name
  seen again) and reorders (a name older than one already seen) are counted.
- **Unnamed frames** (SocketCAN, a PCAN adapter, ``udp_multicast``): the arrivals are embedded
  in the sends (same node, same bytes, order kept, received after sent). Two embeddings bound
  every other: the **earliest** (:func:`_embed_earliest`: nothing lost unless the bytes force
  it) and the **latest** (:func:`_embed_latest`: each arrival the newest unmatched send of its
  bytes before it, the smallest hops). A lost frame is a send no arrival takes; as an arrival
  only takes a send of its own bytes, it shifts no match outside a stretch where the two
  embeddings differ, which exists only where identical payloads repeat within the transport's
  delay or a loss keeps the pattern of payloads (two frames of an alternating torque). There
  they disagree by whole spacings of identical payloads, and the one whose hops jump least
  across the stretch, the agreed matches on either side included, is taken
  (:func:`_smoothest`): a transport's delay drifts, it does not jump by such spacings. Losses
  make the earliest jump (every later hop a spacing longer); a slow transport that lost nothing
  makes the latest jump (hops a spacing shorter where a newer send of the same bytes stood).
  Where both jump alike the logs cannot decide: those arrivals are ``ambiguous``, every CAN
  figure they feed carries that count (``not_relatable``), and the command age is also computed
  with the earliest embedding there, an upper bound on it, so the certificate is held only if
  it holds for both (hil.analysis.measure.figures). ``realigned`` counts the arrivals the two
  embeddings disagreed on and the smoother one settled. An arrival no send explains is
  ``unmatched``, and a duplicate if its bytes are the previous arrival's.
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
    in bus order; -1 none). ``chosen`` is the match the figures use, ``earliest`` the bound of
    the command age; they differ only where ``ambiguous``."""

    chosen: np.ndarray
    earliest: np.ndarray
    duplicated: np.ndarray  # bool per arrival: a copy of a frame already received
    reordered: int  # arrivals older than one received before them (named buses only)
    ambiguous: np.ndarray  # bool per arrival: the logs cannot tell which of two sends it is
    realigned: int = 0  # arrivals the two embeddings disagree on, settled by the smoother one


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
        dup = at >= 0  # duplicates: a name seen before
        dup[np.unique(at, return_index=True)[1]] = False
        first = at[(at >= 0) & ~dup]
        reordered = int((first[1:] < np.maximum.accumulate(first)[:-1]).sum()) if first.size else 0
        return NodeMatch(at, at, dup, reordered, np.zeros(m, bool))
    sv = np.asarray(send_value, np.float32).view(np.int32)  # compare the frame's bytes exactly
    rv = np.asarray(recv_value, np.float32).view(np.int32)
    early = _embed_earliest(sv, send_ns, rv, recv_ns)
    feasible = early >= 0
    late = np.full(m, -1, np.int64)
    late[feasible] = _embed_latest(sv, send_ns, rv[feasible], recv_ns[feasible])
    dup = np.zeros(m, bool)
    # An arrival no send explains, with the bytes of the arrival before it: a copy.
    dup[1:] = ~feasible[1:] & (rv[1:] == rv[:-1])
    chosen, tied = early.copy(), np.zeros(m, bool)
    f = feasible
    chosen[f], tied[f] = _smoothest(
        early[f], late[f], recv_ns[f] - send_ns[early[f]], recv_ns[f] - send_ns[late[f]]
    )
    bound = np.where(tied, early, chosen)  # the oldest sends the logs leave open
    return NodeMatch(chosen, bound, dup, 0, tied, int(((early != late) & f).sum()))


def _smoothest(
    early: np.ndarray, late: np.ndarray, h_early: np.ndarray, h_late: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(the match per arrival, where the logs could not decide): per stretch where the two
    embeddings differ, the one whose hops jump least across it, its agreed neighbours included
    (module docstring). A jump is a step of at least half the shift between the two; fewer
    jumps win, then the smaller total variation; a tie is undecidable (the latest, the smaller
    hops, is used and the stretch is marked)."""
    differ = early != late
    out, tied = early.copy(), np.zeros(early.size, bool)
    edges = np.diff(np.concatenate([[0], differ.astype(np.int8), [0]]))
    for a, b in zip(np.nonzero(edges == 1)[0].tolist(), np.nonzero(edges == -1)[0].tolist(),
                    strict=True):  # fmt: skip
        lo, hi = max(a - 1, 0), min(b + 1, early.size)  # with the agreed matches on either side
        jump = 0.5 * float(np.abs(h_early[a:b] - h_late[a:b]).min())
        steps_e, steps_l = np.abs(np.diff(h_early[lo:hi])), np.abs(np.diff(h_late[lo:hi]))
        key_e = (int((steps_e >= jump).sum()), float(steps_e.sum()))
        key_l = (int((steps_l >= jump).sum()), float(steps_l.sum()))
        if key_l <= key_e:
            out[a:b] = late[a:b]
        tied[a:b] = key_l == key_e
    return out, tied


def _by_value(values: np.ndarray) -> dict[int, np.ndarray]:
    """value -> the sorted indices where it occurs."""
    if values.size == 0:  # nothing sent (an outside device: no send log of the bench's)
        return {}
    order = np.argsort(values, kind="stable")
    keys, starts = np.unique(values[order], return_index=True)
    return dict(zip(keys.tolist(), np.split(order, starts[1:]), strict=True))


def _embed_earliest(sv: np.ndarray, ss: np.ndarray, rv: np.ndarray, rr: np.ndarray) -> np.ndarray:
    """For each arrival in order, the earliest send after the previous match with its bytes,
    sent before it arrived; -1 (and the arrival skipped) where there is none: an arrival that
    no send explains."""
    n, m = sv.size, rv.size
    out = np.full(m, -1, np.int64)
    where = _by_value(sv)
    i = j = 0
    while j < m and i < n:
        k = min(_BLOCK, m - j, n - i)
        ok = (sv[i : i + k] == rv[j : j + k]) & (ss[i : i + k] <= rr[j : j + k])
        run = int(k if ok.all() else np.argmin(ok))
        out[j : j + run] = np.arange(i, i + run)
        i, j = i + run, j + run
        if run == k:
            continue
        idx = where.get(int(rv[j]))
        pos = np.searchsorted(idx, i) if idx is not None else 0
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
    """For each query, the index of the key nearest to it within the tolerance (-1: none);
    ``keys`` not empty."""
    order = np.argsort(keys, kind="stable")
    ks = keys[order]
    pos = np.clip(np.searchsorted(ks, query), 1, max(1, ks.size - 1))
    left = np.clip(pos - 1, 0, ks.size - 1)
    right = np.clip(pos, 0, ks.size - 1)
    pick = np.where(np.abs(ks[left] - query) <= np.abs(ks[right] - query), left, right)
    ok = np.abs(ks[pick] - query) <= tolerance_ns
    return np.where(ok, order[pick], -1)
