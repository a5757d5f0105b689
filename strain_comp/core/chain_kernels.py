"""numba kernels of the chain corrector (``strain_comp.core.chain.ChainCorrector``): its
state layout, event codes and tuning, and the judgement of each sample against its
prediction."""

from __future__ import annotations

import numpy as np

from strain_comp._numba import njit

WINDOW = 32
"""Latest |innovation| values the corrector's robust scale is the median of."""
WINDOW_MIN = 16
"""Innovations seen before the corrector judges any sample (it passes them until then)."""
TREND = 5
"""Latest lag differences whose median is the corrector's trend (a ramp is not a jump)."""
STEP_SAMPLES = 16
"""Samples a jump must stay at its new level, without relaxing, to be a baseline step."""
RELAX_Z = 4.0
"""Standard errors of the bend allowed for noise (below)."""
RELAX_FRAC = 0.2
"""A jump after which the trend bends (the slope after it minus the slope before, times
``STEP_SAMPLES``) by more than ``RELAX_FRAC`` of the jump plus ``RELAX_Z`` standard errors
relaxes or starts a movement: a strain change, not a baseline step."""

# corrector state columns
(_OFFSET, _LAST, _LASTX, _NHIST, _MODE, _NBUF, _WPOS, _WN, _TPOS, _TN, _FIRST, _NPEND,
 _PPOS, _PN, _DRIFT0, _LASTT) = range(16)
STATE_SIZE = 16
"""Length of the corrector's state."""
OFFSET = _OFFSET
"""State column of the baseline offset [ohm] subtracted from every sample."""
REFERENCES = (_NHIST, _MODE, _TN, _TPOS, _PN, _PPOS)
"""State columns a restart (after a gap) clears: the references, not the scale or offset."""
LEVELS = (_OFFSET, _LAST, _LASTX, _FIRST, _DRIFT0)
"""State columns that scale with the samples (levels, the offset, an innovation, a rate):
what a new tare gain multiplies."""
_NORMAL, _SUSPECT, _WATCH = 0, 1, 2
HELD, SPIKE, STEP = 1, 2, 3
"""Event codes of ``ChainCorrector.run``: the sample was held (replaced by the
prediction), the excursion before ended here (a spike), a baseline step was confirmed here."""
NOISE_RATIO = 2.0
"""A baseline step keeps the noise: the scatter after the jump is at most this many times
the robust sigma before it."""


@njit(error_model="numpy")
def _scale(window: np.ndarray) -> float:
    """Robust sigma of innovations: 1.4826 x their median |value|, but at least 1.2533 x
    their mean |value| (equal for Gaussian noise; on a quantised series, whose median
    change may be 0, the mean still sees the noise)."""
    return float(max(1.4826 * np.median(window), 1.2533 * np.mean(window)))


QUANT_STEPS = 3.0
"""The threshold is at least this many of the smallest non-zero |innovation| of the window:
a read-out quantised coarser than its noise (a quiet hold flickering by one ADC step either
way, two steps from one side to the other, of which the mean floor of ``_scale`` sees one
in 32) never makes a spike or a step."""


@njit(error_model="numpy")
def _least_change(window: np.ndarray) -> float:
    """The smallest non-zero value of ``window`` (0 if none): one quantisation step where
    the read-out is quantised, negligible where it is not."""
    least = np.inf
    for v in window:
        if 0.0 < v < least:
            least = v
    return least if least < np.inf else 0.0


@njit(error_model="numpy")
def _slope(values: np.ndarray) -> float:
    """Least-squares slope of ``values`` against their index."""
    tau = np.arange(values.size) - 0.5 * (values.size - 1)
    return float(np.sum(tau * values) / np.sum(tau * tau))


@njit(error_model="numpy")
def _level_jump(pre: np.ndarray, ppos: int, npre: int, post: np.ndarray, gap: int
                ) -> tuple[float, float]:
    """(jump, slope) of one line with a jump fitted to the ring ``pre`` before it and
    ``post``, ``gap`` samples later; (0, 0) while the ring is not full."""
    if npre < pre.size:
        return 0.0, 0.0
    a = np.zeros((3, 3))
    rhs = np.zeros(3)
    for j in range(pre.size + post.size):
        if j < pre.size:
            tau, value, after = float(j - pre.size), pre[(ppos + j) % pre.size], 0.0
        else:
            tau, value, after = float(j - pre.size + gap), post[j - pre.size], 1.0
        row = np.array([1.0, tau, after])
        a += np.outer(row, row)
        rhs += row * value
    solution = np.linalg.solve(a, rhs)
    return solution[2], solution[1]


@njit(error_model="numpy")
def _is_step(st: np.ndarray, buf: np.ndarray, pre: np.ndarray, nbuf: int, sigma: float,
             step_k: float) -> tuple[bool, float]:
    """(is a step, its jump) of the ``nbuf`` watched samples ``buf`` against the ring
    ``pre`` before them: a step is a jump over ``step_k`` sigma, with no bend of a
    relaxation and no more scatter than the noise."""
    jump, slope = _level_jump(pre, int(st[_PPOS]), int(st[_PN]), buf, int(st[_NPEND]))
    noise = sigma / np.sqrt(2.0)  # per sample: e is a difference
    bend = (_slope(buf[:nbuf]) - _slope(np.roll(pre, -int(st[_PPOS])))) * nbuf
    bend_se = noise * np.sqrt(24.0 / (nbuf * (nbuf * nbuf - 1.0))) * nbuf
    scatter = _scale(np.abs(np.diff(buf[:nbuf]) - slope))
    return (abs(jump) > step_k * sigma
            and abs(bend) <= RELAX_FRAC * abs(jump) + RELAX_Z * bend_se
            and scatter <= NOISE_RATIO * sigma), jump


@njit(error_model="numpy")
def _watch(st: np.ndarray, xi: float, dt: float, thr: float, sigma: float, step_k: float,
           buf: np.ndarray, pre: np.ndarray) -> tuple[bool, bool, float]:
    """One sample while a jump that stayed is watched, against the trend before it:
    (accepted, a step found, its jump). A sample that moves on ends the watch (a strain
    change); after ``STEP_SAMPLES`` held ones the jump is judged (``_is_step``)."""
    drift = st[_DRIFT0] * dt
    nbuf = int(st[_NBUF])
    if abs(xi - buf[nbuf - 1] - drift) > thr:  # moves on: a strain change
        st[_MODE] = _NORMAL
        return True, False, 0.0
    buf[nbuf] = xi
    nbuf += 1
    st[_NBUF] = nbuf
    if nbuf != STEP_SAMPLES:
        return False, False, 0.0
    st[_MODE] = _NORMAL
    stepped, jump = _is_step(st, buf, pre, nbuf, sigma, step_k)
    return True, stepped, jump


@njit(error_model="numpy")
def _judge(st: np.ndarray, xi: float, pred: float, dt: float, rate: float, thr: float,
           sigma: float, width: int, step_k: float, buf: np.ndarray, pre: np.ndarray,
           trend: np.ndarray) -> tuple[float, float, bool, int]:
    """One sample through the corrector's modes (normal, suspect, watch) against its
    prediction ``pred`` and threshold ``thr``: (xi, its innovation e, accepted, event); a
    step found is taken out of xi and e and added to the offset."""
    e = xi - pred
    mode = int(st[_MODE])
    accept = True
    event = 0
    if mode == _NORMAL:
        if abs(e) > thr:
            st[_MODE] = _SUSPECT
            st[_FIRST] = e
            st[_NPEND] = 1
            st[_DRIFT0] = rate
            accept = False
    elif mode == _SUSPECT:
        if abs(e) <= thr:  # back: the held samples were a spike
            event = SPIKE
            st[_MODE] = _NORMAL
        elif st[_NPEND] < width:  # a spike may last ``width`` samples
            st[_NPEND] += 1
            st[_FIRST] = e
            accept = False
        elif abs(e - st[_FIRST]) <= thr and step_k > 0.0:  # stays: watch for a step
            st[_MODE] = _WATCH
            buf[0] = xi
            st[_NBUF] = 1
            accept = False
        else:  # a real change: let it through, and follow its rate at once
            st[_MODE] = _NORMAL
            trend[:] = (xi - st[_LASTX]) / dt if dt > 0.0 else 0.0
            st[_TN] = TREND
    else:  # watching a jump that stayed
        accept, stepped, jump = _watch(st, xi, dt, thr, sigma, step_k, buf, pre)
        if stepped:
            st[_OFFSET] += jump
            xi -= jump
            e = xi - pred
            event = STEP
    return xi, e, accept, event


@njit(error_model="numpy")
def correct_samples(t: np.ndarray, x: np.ndarray, st: np.ndarray, win: np.ndarray,
                    trend: np.ndarray, buf: np.ndarray, pre: np.ndarray, k: float, width: int,
                    step_k: float, events: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """The corrector of ``ChainCorrector`` over consecutive used samples ``x`` [ohm]."""
    y = np.empty(x.size)
    for i in range(x.size):
        xi = x[i] - st[_OFFSET]
        events[i] = 0
        dt = t[i] - st[_LASTT]
        if st[_NHIST] < 1:  # no reference yet: pass
            out = xi
        else:
            rate = np.median(trend[:int(st[_TN])]) if st[_TN] > 0 else 0.0
            drift = rate * dt
            pred = st[_LAST] + drift
            n_win = int(st[_WN])
            sigma = _scale(win[:n_win]) if n_win >= WINDOW_MIN else np.inf
            thr = (max(k * sigma, QUANT_STEPS * _least_change(win[:n_win])) if sigma > 0.0
                   else np.inf)
            mode = int(st[_MODE])
            xi, e, accept, event = _judge(st, xi, pred, dt, rate, thr, sigma, width, step_k,
                                          buf, pre, trend)
            events[i] = event
            if accept:
                out = xi
                if abs(e) <= thr or mode == _SUSPECT:  # a real change teaches the scale
                    win[int(st[_WPOS])] = abs(e)
                    st[_WPOS] = (st[_WPOS] + 1) % WINDOW
                    st[_WN] = min(st[_WN] + 1, WINDOW)
            else:
                out = pred
                if events[i] == 0:
                    events[i] = HELD
            trend[int(st[_TPOS])] = (xi - st[_LASTX]) / dt if dt > 0.0 else 0.0
            st[_TPOS] = (st[_TPOS] + 1) % TREND
            st[_TN] = min(st[_TN] + 1, TREND)
        if st[_MODE] == _NORMAL and events[i] != HELD:
            pre[int(st[_PPOS])] = xi
            st[_PPOS] = (st[_PPOS] + 1) % pre.size
            st[_PN] = min(st[_PN] + 1, pre.size)
        st[_LAST] = out
        st[_LASTX] = xi
        st[_LASTT] = t[i]
        st[_NHIST] = 1.0
        offsets[i] = st[_OFFSET]
        y[i] = out
    return y
