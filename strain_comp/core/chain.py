"""Measurement-chain effects found from the resistance alone: alternation, isolated spikes,
baseline steps, quantisation, and the online corrector's kernels (docs/models.md, "The
measurement chain")."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from strain_comp._numba import njit

ALTERNATION_Z = 5.0
"""Significance (binomial z) of the sign agreement for an alternation to be present."""
PAIR_WINDOW = 5
"""Pairs per window of the medians ``pair_branch`` compares."""
PAIR_STEP_K = 8.0
"""A step of the alternation's size exceeds this many robust sigmas of its changes."""
PAIR_MIN_STEPS = 3
"""Fewest steps ``pair_branch`` needs to read a side."""


@dataclass(frozen=True)
class Alternation:
    """Alternation every other sample: amplitude A [ohm], noise sigma [ohm], significance z."""

    amplitude: float
    noise: float
    z: float

    @property
    def present(self) -> bool:
        return self.z > ALTERNATION_Z and abs(self.amplitude) >= self.noise

    def reading(self) -> str:
        return (f"alternation +-{abs(self.amplitude):.3g} ohm every other sample "
                f"(white noise {self.noise:.3g} ohm)")


def _finite(r: npt.ArrayLike) -> npt.NDArray[np.float64]:
    x = np.asarray(r, dtype=np.float64)
    return x[np.isfinite(x) & (x > 0)]


def _robust_sigma(x: np.ndarray) -> float:
    return 1.4826 * float(np.median(np.abs(x - np.median(x)))) if x.size else 0.0


def alternation(r: npt.ArrayLike) -> Alternation:
    """The alternation statistics of a resistance series (docs/models.md)."""
    r = _finite(r)
    if r.size < 8:
        return Alternation(0.0, 0.0, 0.0)
    d2 = np.diff(r, 2)
    m = d2 * (-1.0) ** np.arange(1, d2.size + 1)  # d2[i] is centred on sample i + 1
    amplitude = -float(np.median(m)) / 4.0
    noise = _robust_sigma(m + 4.0 * amplitude) / math.sqrt(6.0)
    nonzero = m[m != 0]
    if amplitude == 0.0 or nonzero.size == 0:
        return Alternation(amplitude, noise, 0.0)
    agreement = float(np.mean(np.sign(nonzero) == -np.sign(amplitude)))
    z = (agreement - 0.5) * 2.0 * math.sqrt(nonzero.size)
    return Alternation(amplitude, noise, z)


PAIR_BRANCHES = ("mean", "upper", "lower")
"""The pair statistics an alternating input can be read through (``pair_values``)."""


def pair_values(r: npt.NDArray[np.float64], previous: float = math.nan, branch: str = "mean",
                ) -> np.ndarray:
    """The pair statistic ``branch`` of R[i] and R[i-1], the first with ``previous``."""
    before = np.concatenate(([previous], r[:-1])) if r.size else r
    if branch == "mean":
        return np.where(np.isfinite(before), 0.5 * (r + before), r)
    # fmax/fmin: a NaN previous is skipped
    return np.fmax(r, before) if branch == "upper" else np.fmin(r, before)


def pair_branch(r: npt.ArrayLike, still: npt.ArrayLike) -> str:
    """The pair statistic to read an alternating ``r`` through, from its ``still`` stretches."""
    ra = np.asarray(r, dtype=np.float64)
    ok = np.isfinite(ra) & (ra > 0)
    ra, sa = ra[ok], np.asarray(still, dtype=bool)[ok]
    n = (ra.size // (2 * PAIR_WINDOW)) * 2 * PAIR_WINDOW
    if n < 4 * PAIR_WINDOW:
        return "mean"
    pairs = ra[:n].reshape(-1, 2)
    upper = np.median(pairs.max(axis=1).reshape(-1, PAIR_WINDOW), axis=1)
    lower = np.median(pairs.min(axis=1).reshape(-1, PAIR_WINDOW), axis=1)
    quiet = np.all(sa[:n].reshape(-1, 2 * PAIR_WINDOW), axis=1)
    d_size, d_lower = np.diff(upper - lower), np.diff(lower)
    sigma = _robust_sigma(d_size)
    steps = (np.abs(d_size) > PAIR_STEP_K * sigma) & quiet[1:] & quiet[:-1]
    if sigma <= 0 or np.sum(steps) < PAIR_MIN_STEPS:
        return "mean"
    share = float(np.median(-d_lower[steps] / d_size[steps]))
    return "upper" if share > 0.75 else "lower" if share < 0.25 else "mean"


def quantisation(r: npt.ArrayLike) -> float | None:
    """The resistance step [ohm] of a quantised series, or None when R is not quantised."""
    r = _finite(r)
    steps = np.abs(np.diff(r))
    steps = steps[steps > 0]
    if steps.size < 20:
        return None
    q = float(np.percentile(steps, 5))
    if not q > 0:
        return None
    ratio = steps / q
    on_grid = np.abs(ratio - np.round(ratio)) < 0.05
    return q if float(np.mean(on_grid)) > 0.9 and np.mean(np.diff(r) == 0) > 0.05 else None


# ------------------------------------------------------------------ online input correction

DESPIKE_K = 8.0
"""Default spike threshold of the online corrector: robust sigmas of its innovation."""
STEP_K = 12.0
"""Default least size of a baseline step, in robust sigmas of the innovation."""
# 1.5 x the spike threshold: measured run v19 has an 8-12 sigma change under load (strain)
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
"""A jump whose trend bends by more than this share of it (plus ``RELAX_Z``) is strain."""

# corrector state columns
(_OFFSET, _LAST, _LASTX, _NHIST, _MODE, _NBUF, _WPOS, _WN, _TPOS, _TN, _FIRST, _NPEND,
 _PPOS, _PN, _DRIFT0, _LASTT) = range(16)
STATE_SIZE = 16
REFERENCES = [_NHIST, _MODE, _TN, _TPOS, _PN, _PPOS]
"""State columns a restart (after a gap) clears: the references, not the scale or offset."""
LEVELS = [_OFFSET, _LAST, _LASTX, _FIRST, _DRIFT0]
"""State columns that scale with the samples: what a new tare gain multiplies."""
_NORMAL, _SUSPECT, _WATCH = 0, 1, 2
HELD, SPIKE, STEP = 1, 2, 3
"""Event codes of ``ChainCorrector.run``: sample held, a spike ended, a baseline step."""
NOISE_RATIO = 2.0
"""A baseline step keeps the noise: the scatter after it at most this x the sigma before."""


@njit(error_model="numpy")
def _scale(window: np.ndarray) -> float:
    """Robust sigma of innovations: 1.4826 x their median |value|, at least 1.2533 x the mean."""
    # equal for Gaussian noise; on a quantised series the median change may be 0
    return float(max(1.4826 * np.median(window), 1.2533 * np.mean(window)))


QUANT_STEPS = 3.0
"""The threshold is at least this many of the smallest non-zero |innovation| of the window."""
# a hold flickering by one ADC step coarser than the noise never makes a spike or a step


@njit(error_model="numpy")
def _least_change(window: np.ndarray) -> float:
    """The smallest non-zero value of ``window`` (0 if none)."""
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
    """(jump, slope) of a line with a jump fitted to the ring ``pre`` and ``post``."""
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
def _watch(st: np.ndarray, xi: float, dt: float, thr: float, sigma: float, step_k: float,
           buf: np.ndarray, pre: np.ndarray) -> tuple[bool, bool, float]:
    """One sample while a jump that stayed is watched: (accepted, a step found, its jump)."""
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
    # a step: a jump over ``step_k`` sigma, with no relaxation's bend, no more scatter than noise
    jump, slope = _level_jump(pre, int(st[_PPOS]), int(st[_PN]), buf, int(st[_NPEND]))
    noise = sigma / np.sqrt(2.0)  # per sample: e is a difference
    bend = (_slope(buf[:nbuf]) - _slope(np.roll(pre, -int(st[_PPOS])))) * nbuf
    bend_se = noise * np.sqrt(24.0 / (nbuf * (nbuf * nbuf - 1.0))) * nbuf
    scatter = _scale(np.abs(np.diff(buf[:nbuf]) - slope))
    return True, (abs(jump) > step_k * sigma
                  and abs(bend) <= RELAX_FRAC * abs(jump) + RELAX_Z * bend_se
                  and scatter <= NOISE_RATIO * sigma), jump


@njit(error_model="numpy")
def _judge(st: np.ndarray, xi: float, pred: float, dt: float, rate: float, thr: float,
           sigma: float, width: int, step_k: float, buf: np.ndarray, pre: np.ndarray,
           trend: np.ndarray) -> tuple[float, float, bool, int]:
    """One sample through the corrector's modes: (xi, innovation, accepted, event)."""
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


@dataclass(frozen=True)
class BaselineStep:
    """A confirmed baseline step: time of confirmation [s] and size [ohm]."""

    t: float
    size: float

    def reading(self) -> str:
        size = (f"{self.size / 1000.0:+.3g} kohm" if abs(self.size) >= 1000.0
                else f"{self.size:+.3g} ohm")
        return f"baseline step {size} at t={self.t:.4g} s, connector re-seated?"


class ChainCorrector:
    """Online, causal correction of isolated spikes and baseline steps of one sensor."""

    def __init__(self, *, k: float = DESPIKE_K, alternating: bool = False,
                 step_k: float = 0.0) -> None:
        self.k = float(k)
        self.width = 2 if alternating else 1
        self.step_k = float(step_k)
        self.state = np.zeros(STATE_SIZE)
        self.window = np.zeros(WINDOW)
        self.trend = np.zeros(TREND)
        self.buffer = np.zeros(STEP_SAMPLES)
        self.pre = np.zeros(STEP_SAMPLES)
        self.n_spikes = 0
        self.steps: list[BaselineStep] = []

    def restart(self) -> None:
        """Forget the references (after a gap): the next sample passes unjudged."""
        self.state[REFERENCES] = 0.0

    def rescale(self, factor: float) -> None:
        """Carry the state over to samples ``factor`` x as large (a new tare gain)."""
        self.state[LEVELS] *= factor
        for values in (self.window, self.trend, self.buffer, self.pre):
            values *= factor

    def run(self, t: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(corrected samples, event codes) of consecutive used samples ``x`` [ohm]."""
        x = np.ascontiguousarray(x, dtype=np.float64)
        events = np.zeros(x.size, np.int8)
        offsets = np.empty(x.size)
        before = float(self.state[_OFFSET])  # the baseline correction so far [ohm]
        y = correct_samples(np.ascontiguousarray(t, dtype=np.float64), x, self.state,
                            self.window, self.trend, self.buffer, self.pre, self.k,
                            self.width, self.step_k, events, offsets)
        self.n_spikes += int(np.count_nonzero(events == SPIKE))
        for i in np.flatnonzero(events == STEP).tolist():
            previous = offsets[i - 1] if i > 0 else before
            self.steps.append(BaselineStep(float(t[i]), float(offsets[i] - previous)))
        return y, events


def correct(t: npt.ArrayLike, r: npt.ArrayLike, *, alternating: bool, step_k: float = 0.0,
            pair: str = "mean") -> tuple[np.ndarray, np.ndarray, ChainCorrector]:
    """A whole run through a fresh ``ChainCorrector``: (what the models see, events, it)."""
    t = np.asarray(t, dtype=np.float64)
    r = np.asarray(r, dtype=np.float64)
    good = np.isfinite(r) & (r > 0)
    corrector = ChainCorrector(alternating=alternating, step_k=step_k)
    seen = pair_values(r[good], branch=pair) if alternating else r[good]
    out = np.full(r.size, np.nan)
    events = np.zeros(r.size, np.int8)
    out[good], events[good] = corrector.run(t[good], seen)
    return out, events, corrector
