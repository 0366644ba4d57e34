"""The batch path compiled: one parallel numba kernel over robots, from the sources the
numpy path and the float path run.

What is compiled, and from where (no equation is written a second time):
- the law: :func:`controller_service.laws.unified.make_step`, the closure the float path runs
  on ``math``, bound to the same scalar functions;
- the plant under a held torque: :func:`plant_emulator.dynamics.held_steps` and
  :func:`~plant_emulator.dynamics.held_displacement`, the closed-form RK4 that the numpy path
  runs on arrays, here on one robot's complex scalars (with exact phasors of the small stage
  angles where the numpy path uses their Taylor polynomials: equal to rounding).

What the kernel writes itself is bookkeeping, not equations: the zero-order hold and the
landings of :mod:`plant_emulator.sampled` as index arithmetic over the landing-offset table
(numba cannot compile the numpy path's queue of command objects): command k lands at plant
step k m + offset, the newest by sequence number wins, an older one landing later is dropped
(counted); the law's bad-input rule (zero torque, memory unchanged); the extremes of (2).

It runs the common sweep and a long run's windowed ideal (robots with their own start time,
law memory and per-sample callback) when :func:`chosen` says so: the unified law (either
variant, no eta re-arm), an ideal sensor, no actuator lag, friction or top speed, a constant
(or no) disturbance, no traces recorded. Anything else, numba missing, or ``HIL_NO_COMPILED=1``
leaves the run to the numpy path, the reference: tests/test_batch_compiled.py checks that the
two agree to 1e-12.
"""

from __future__ import annotations

import functools
import math
import os
import threading
from collections.abc import Callable
from types import SimpleNamespace
from typing import Any

import numpy as np

from controller_service.laws.unified import TELEMETRY_KEYS, UnifiedController, make_step
from controller_service.references import sample_array
from plant_emulator.disturbances import disturbance_at
from plant_emulator.dynamics import VIOLATION_RTOL, PlantState, held_displacement, held_steps
from runtime.mathns import FLOAT_MATH

try:  # a declared dependency; without it (a platform with no wheel) the numpy path runs
    import numba
except ImportError:  # pragma: no cover
    numba = None

CHUNK = 256  # samples per kernel call: progress and Ctrl-C are served between calls
# Compiling the kernel takes a few seconds once per process (numba cannot cache the closures it
# is made of): below this many robot-steps the numpy path finishes sooner, unless the kernel is
# already compiled.
MIN_WORK = 20_000_000
_KERNEL: list[Any] = []
# numba's default threading layer (workqueue) aborts the process when two threads launch
# parallel kernels at once (e.g. a threaded sweep executor): one kernel call at a time.
_LAUNCH = threading.Lock()


def _plant_parts(njit: Any) -> tuple[Any, Any]:
    """The compiled plant step under a held command and the landing of commands."""
    steps = njit(held_steps)
    displacement = njit(held_displacement)

    @njit(inline="always")
    def linear(e: Any, row: int, lim: float, q: float, dq: float, last: float, n: int) -> None:
        """Extremes over the n step ends q + dq, ..., last (monotone: the peak is at an end)."""
        peak = max(abs(q + dq), abs(last))
        e[row] = max(e[row], peak)
        if peak > lim:  # count the steps beyond the limit by replaying the additions
            for _ in range(n):
                q = q + dq
                if abs(q) > lim:
                    e[4 + row] += 1.0

    @njit(inline="always")
    def advance(s: Any, c1: float, c2: float, d: Any, h: float, n: int, e: Any, lims: Any) -> Any:
        """n RK4 steps of model (1) under the held command (c1, c2), extremes updated."""
        x, y, th, v, w = s
        u1, u2 = c1 + d[0], c2 + d[1]
        hu1, hu2, hhu2 = h * u1, h * u2, 0.5 * h * u2
        ang_e = 0.5 * h * hhu2
        ang_r = 0.5 * h * w
        e_pos = complex(math.cos(ang_e), math.sin(ang_e))
        r2 = complex(math.cos(ang_r), math.sin(ang_r))
        z = complex(math.cos(th), math.sin(th))
        k = 2.0 * (1.0 + e_pos)
        z, s_sum, q_sum, ends = steps(z, r2, e_pos * e_pos, k, (th, w, v), (hu2, hu1, hhu2), h, n)
        disp = displacement(s_sum, q_sum, z, v, hu1, h / 6.0, n)
        e[2] = max(e[2], abs(c1))
        e[3] = max(e[3], abs(c2))
        e[6] += n * (abs(c1) > lims[2])
        e[7] += n * (abs(c2) > lims[3])
        linear(e, 0, lims[0], v, hu1, ends[2], n)
        linear(e, 1, lims[1], w, hu2, ends[1], n)
        return (x + disp.real, y + disp.imag, ends[0], ends[2], ends[1])

    @njit
    def first_nonfinite(s: Any, c: Any, d: Any, h: float, n: int, lims: Any) -> int:
        """The first of n steps from s whose end is not finite (0 when s is not), replayed
        one step at a time on scratch extremes."""
        if (s[0] + s[1] + s[2] + s[3] + s[4]) - (s[0] + s[1] + s[2] + s[3] + s[4]) != 0.0:
            return 0
        scratch = np.zeros(8)
        for i in range(n - 1):
            s = advance(s, c[0], c[1], d, h, 1, scratch, lims)
            q = s[0] + s[1] + s[3] + s[4]
            if q - q != 0.0:
                return i
        return n - 1

    @njit(inline="always")
    def nonfinite(e: Any, start: Any, s: Any, c: Any, d: Any, h: float, n: int, lims: Any,
                  t_start: float) -> None:  # fmt: skip
        """The non-finite steps of plant_emulator.dynamics.Extremes among the n steps from
        ``start`` (at ``t_start``) to ``s``: their count (e[8]), the first one's end (e[9])."""
        q = s[0] + s[1] + s[3] + s[4]  # theta and the torque reach these in a step
        if q - q != 0.0:
            first = first_nonfinite(start, c, d, h, n, lims)
            if e[8] == 0.0:
                e[9] = t_start + (first + 1) * h
            e[8] += n - first

    @njit(inline="always")
    def land(j: int, k: int, off: Any, m: int, ring: Any, hd: Any) -> None:
        """Land the commands due at plant step j, oldest first (hd: cmd1, cmd2, applied,
        oldest pending, dropped)."""
        nb = ring.shape[1]
        for c in range(int(hd[3]), k + 1):
            if c * m + off[c] == j:
                if c > hd[2]:
                    hd[0], hd[1], hd[2] = ring[0, c % nb], ring[1, c % nb], c
                else:
                    hd[4] += 1.0
        while hd[3] <= k and int(hd[3]) * m + off[int(hd[3])] <= j:
            hd[3] += 1.0

    return advance, land, nonfinite


def _build() -> Any:
    """Compile the kernel (once per process, on its first call)."""
    # Division by zero gives inf/NaN, as on numpy, instead of a test before every division
    # (~7 % of the kernel); the law's bad-input rule then rejects it, as the float path does.
    njit = functools.partial(numba.njit, error_model="numpy")
    # the float path's scalar functions, as numba compiles them
    ns = SimpleNamespace(sin=math.sin, cos=math.cos, tanh=math.tanh, sqrt=math.sqrt, exp=math.exp)
    ns.sign, ns.clip = njit(FLOAT_MATH.sign), njit(FLOAT_MATH.clip)
    law = njit(make_step(ns))
    advance, land, nonfinite = _plant_parts(njit)

    @njit
    def robot(i: int, a: Any, off: Any, c: Any, k0: int, k1: int) -> None:
        """Robot i from sample k0 to k1: law, send, land at t_k, advance to t_k+1, as the numpy
        loop does (a: state, memory, hold, sent torques by sequence modulo the ring's length,
        extremes, squared error sum, last sampled pose, the chunk's reference table (one
        column for all robots, or one per robot), the robots' first-sample times, the chunk's
        state table (empty: not kept); c: constants)."""
        st, mem, hold, ring, ext, sq, last, refs, t0, trail = a
        # one column for all robots, else robot i's (int64 both: prange's index may be unsigned)
        col = np.int64(i) if refs.shape[1] > 1 else np.int64(0)
        keep = trail.shape[0] > 0
        ts, m, h, rms_from = c[0], int(c[1]), c[2], int(c[3])
        d, lims = (c[4], c[5]), (c[6], c[7], c[8], c[9])
        p = (c[10], c[11], c[12], c[13], c[14], c[15], c[16], c[17], c[18], c[19])
        s = (st[0, i], st[1, i], st[2, i], st[3, i], st[4, i])
        memory = (mem[0, i], mem[1, i], mem[2, i])
        hd, e, rg = hold[:, i], ext[:, i], ring[:, i]
        nb = rg.shape[1]
        for k in range(k0, k1):
            r = refs[k - k0, col]
            ref = (r[0], r[1], r[2], r[3], r[4])
            if keep:  # the state at t_k, as the numpy loop hands it to on_sample
                row = trail[k - k0]
                row[0, i], row[1, i], row[2, i], row[3, i], row[4, i] = s
                row[5, i], row[6, i] = hd[0], hd[1]
            t_k = t0[i] + k * ts
            out = law(t_k, ts, s, ref, memory, p)
            # the law's rejection sum in its one order (unified._step_total)
            total = t_k + ts + out[5] + out[6] + out[14] + out[15] + out[2] + out[3] + out[4]
            if total - total == 0.0:
                rg[0, k % nb], rg[1, k % nb] = out[0], out[1]
                memory = (out[2], out[3], out[4])
            else:  # the law's bad-input rule
                rg[0, k % nb], rg[1, k % nb] = 0.0, 0.0
            j = k * m
            land(j, k, off, m, rg, hd)
            if k >= rms_from:
                sq[i] += (s[0] - ref[0]) ** 2 + (s[1] - ref[1]) ** 2
            last[0, i], last[1, i], last[2, i] = s[0], s[1], s[2]
            j_end = j + m
            while True:
                nxt = j_end
                for c in range(int(hd[3]), k + 1):
                    lc = c * m + off[c]
                    if j < lc < nxt:
                        nxt = lc
                start = s
                s = advance(s, hd[0], hd[1], d, h, nxt - j, e, lims)
                nonfinite(e, start, s, (hd[0], hd[1]), d, h, nxt - j, lims, t0[i] + j * h)
                if nxt == j_end:
                    break
                land(nxt, k, off, m, rg, hd)
                j = nxt
        st[0, i], st[1, i], st[2, i], st[3, i], st[4, i] = s
        mem[0, i], mem[1, i], mem[2, i] = memory

    @njit(parallel=True)
    def kernel(a: Any, off: Any, group: Any, c: Any, k0: int, k1: int) -> None:
        # Robots outside, each running its samples k0..k1 in registers: one barrier a chunk.
        # (Samples outside, robots inside, measured 20 % less per CPU second and stalls at each
        # sample's barrier when another process takes a core.)
        for i in numba.prange(group.shape[0]):
            robot(i, a, off[group[i]], c, k0, k1)

    return kernel


def kernel() -> Any:
    """The compiled kernel, built on first use."""
    with _LAUNCH:
        if not _KERNEL:
            _KERNEL.append(_build())
    return _KERNEL[0]


def chosen(controller: Any, scenario: Any, work: int) -> bool:
    """Whether a batch of ``work`` robot-steps of this law and plant runs on the kernel: numba
    present and allowed, a law and plant it computes (module doc), and the work repays the
    compilation (unless already compiled)."""
    if numba is None or os.environ.get("HIL_NO_COMPILED") == "1":
        return False
    # Friction and a top speed (a plant's optional drag) are integrated stage by stage, which
    # only the numpy path does.
    return (
        (bool(_KERNEL) or work >= MIN_WORK)
        and type(controller) is UnifiedController
        and not scenario.plant.drag.active
        and scenario.sensor.is_ideal
        and scenario.plant.lag <= 0.0
        and scenario.disturbance.is_constant
    )


def _references(batch: Any, ts: float, k0: int, k1: int, shared: Any) -> np.ndarray:
    """The reference of samples k0 .. k1 - 1: (samples, 1, 5) from the table of all samples
    when the robots share the clock, else (samples, robots, 5), sampled on arrays at each
    robot's own t0 + k Ts as the numpy loop samples it."""
    if batch.starts is None:
        return shared[k0:k1, None, :]
    t = batch.starts[None, :] + (np.arange(k0, k1, dtype=float) * ts)[:, None]
    ref = sample_array(batch.reference, t)
    return np.ascontiguousarray(np.stack([np.asarray(q, dtype=float) for q in ref[:5]], axis=-1))


def run(
    batch: Any,
    scenario: Any,
    progress: Any,
    on_sample: Callable[[int, PlantState], None] | None = None,
) -> None:
    """Run the batch's loops in the kernel and leave in ``batch`` what the numpy loop leaves
    (state, memory, extremes, hold, rms, last sample); ``on_sample(k, state)`` is called as the
    numpy loop calls it, after each chunk for its samples; Ctrl-C between chunks interrupts."""
    n = len(batch.group)
    n_samples, ts, m = batch.n_samples, scenario.timing.ts, scenario.substeps
    shared = None
    if batch.starts is None:
        shared = np.array([tuple(batch.reference.sample(k * ts))[:5] for k in range(n_samples)])
    off = np.ascontiguousarray(np.reshape(np.asarray(batch.land, dtype=np.int64), (-1, n_samples)))
    group = np.zeros(n, dtype=np.intp) if off.shape[0] == 1 else batch.group
    state, ext, lim_r = batch.state, batch.ext, 1.0 + VIOLATION_RTOL
    limits = scenario.limits
    peaks = (ext.max_abs_v, ext.max_abs_omega, ext.max_abs_tau1, ext.max_abs_tau2)
    rms_from = math.floor(0.9 * n_samples)
    t0 = np.zeros(n) if batch.starts is None else np.asarray(batch.starts, dtype=float)
    head = (
        np.array([state.x, state.y, state.theta, state.v, state.omega], dtype=float),
        np.array(batch.memory[:3], dtype=float),
        np.array([np.zeros(n), np.zeros(n), np.full(n, -1.0), np.zeros(n), np.zeros(n)]),
        np.zeros((2, n, int(off.max()) // m + 3)),
        np.array([*peaks, *[np.zeros(n)] * 4, ext.nonfinite_steps, ext.nonfinite_first_t]),
        np.zeros(n),
        np.zeros((3, n)),
    )
    # the kernel's c: loop sizes, the constant disturbance, the limits of (2), the law's p
    loop = (ts, m, scenario.plant_step, rms_from, *disturbance_at(batch.plant.disturbance, 0.0))
    bounds = (q * lim_r for q in (limits.phi1, limits.phi2, limits.varpi1, limits.varpi2))
    consts = np.array([*loop, *bounds, *batch.controller.constants()], dtype=float)
    compiled = kernel()
    every = max(1, n_samples // 200)
    ref = None
    try:
        for k0 in range(0, n_samples, CHUNK):
            k1 = min(n_samples, k0 + CHUNK)
            refs = _references(batch, ts, k0, k1, shared)
            # a new table each chunk: a callback may keep the state it was handed
            trail = np.empty((k1 - k0 if on_sample else 0, 7, n))
            with _LAUNCH:
                compiled((*head, refs, t0, trail), off, group, consts, k0, k1)
            batch.done, ref = k1, refs[-1]
            if on_sample is not None:
                for k in range(k0, k1):
                    on_sample(k, PlantState(*trail[k - k0]))
            if progress is not None:
                progress(k0 - k0 % every, n_samples)
    except KeyboardInterrupt:
        batch.interrupted = True
    # the kernel's arrays back into the batch
    st, mem, hold, _, e, sq, last = head
    ext.max_abs_v, ext.max_abs_omega, ext.max_abs_tau1, ext.max_abs_tau2 = (e[q] for q in range(4))
    counts = e[4:8].astype(np.int64)
    ext.violations_v, ext.violations_omega, ext.violations_tau1, ext.violations_tau2 = counts
    ext.nonfinite_steps, ext.nonfinite_first_t = e[8].astype(np.int64), e[9].copy()
    # The kernel's peaks compare (a NaN drops out): a state that ended non-finite keeps it.
    ext.max_abs_v = np.maximum(ext.max_abs_v, np.abs(st[3]))
    ext.max_abs_omega = np.maximum(ext.max_abs_omega, np.abs(st[4]))
    ext.steps += batch.done * m
    batch.state = PlantState(*st, hold[0], hold[1])
    batch.memory = type(batch.memory)(*mem)
    batch.hold.cmd1, batch.hold.cmd2 = hold[0], hold[1]
    batch.hold.dropped = hold[4].astype(np.int64)
    sq_n = batch.done - rms_from
    batch.rms = np.sqrt(sq / sq_n) if sq_n > 0 else np.full(len(sq), np.nan)
    if batch.done:
        # the last sample's reference: a float each for robots that share it, else arrays
        pose = (float(ref[0, q]) if batch.starts is None else ref[:, q].copy() for q in range(3))
        batch.last = (last[0], last[1], last[2], *pose)
    batch.tel_keys = list(TELEMETRY_KEYS)
    if on_sample is not None and not batch.interrupted:
        on_sample(n_samples, batch.state)
