"""Statistics over training seeds for the suite's report: t confidence intervals and Welch's test.

One training seed is an anecdote: every figure the report compares is a sample of training seeds
(each seed's value its mean over evaluation seeds). ``mean_ci`` gives a mean with the half-width
of its two-sided 95 % interval from Student's t with ``n - 1`` degrees of freedom; ``welch``
compares two samples without assuming equal variances (Welch-Satterthwaite degrees of freedom).
Student's t is computed here through the regularised incomplete beta function (a continued
fraction), so the report needs no statistics package; ``tests/test_suite_stats.py`` checks it
against tabulated values.
"""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass
from typing import Sequence

#: Two-sided significance level of every comparison the report marks.
ALPHA = 0.05


@dataclass(frozen=True)
class MeanCI:
    """A sample's mean and its two-sided 95 % t interval.

    Attributes:
        mean: the sample mean.
        sd: the sample standard deviation (None for one value).
        half_width: the interval's half-width, ``t(0.975, n - 1) * sd / sqrt(n)`` (None for one value).
        n: the sample size (training seeds).
    """

    mean: float
    sd: float | None
    half_width: float | None
    n: int

    @property
    def low(self) -> float | None:
        return None if self.half_width is None else self.mean - self.half_width

    @property
    def high(self) -> float | None:
        return None if self.half_width is None else self.mean + self.half_width

    def relation(self, value: float) -> str:
        """Where ``value`` (e.g. the paper's number) lies: ``inside`` the interval, or ours ``above``
        / ``below`` it; ``unknown`` without an interval (one seed)."""
        if self.half_width is None:
            return "unknown"
        if self.low is not None and value < self.low:
            return "above"
        if self.high is not None and value > self.high:
            return "below"
        return "inside"


@dataclass(frozen=True)
class Welch:
    """Welch's two-sample t-test of ``a`` against ``b``.

    Attributes:
        difference: mean of a minus mean of b.
        t: the statistic (None when both samples have no spread, or one has a single value).
        df: Welch-Satterthwaite degrees of freedom.
        p: two-sided p-value.
    """

    difference: float
    t: float | None
    df: float | None
    p: float | None

    @property
    def significant(self) -> bool:
        return self.p is not None and self.p < ALPHA

    def verdict(self, a: str = "a", b: str = "b") -> str:
        """``a above b``, ``a below b`` (p < ALPHA), ``tie``, or ``untested`` (too few seeds)."""
        if self.p is None:
            return "untested (fewer than 2 seeds on a side)"
        if not self.significant:
            return "tie"
        return f"{a} above {b}" if self.difference > 0 else f"{a} below {b}"


def mean_ci(values: Sequence[float], confidence: float = 0.95) -> MeanCI:
    """Mean and t interval of ``values`` (at least one)."""
    if not values:
        raise ValueError("mean_ci needs at least one value")
    n = len(values)
    mean = statistics.fmean(values)
    if n == 1:
        return MeanCI(mean, None, None, 1)
    sd = statistics.stdev(values)
    return MeanCI(mean, sd, t_quantile(0.5 + confidence / 2, n - 1) * sd / math.sqrt(n), n)


def welch(a: Sequence[float], b: Sequence[float]) -> Welch:
    """Welch's t-test of samples ``a`` and ``b`` (two-sided)."""
    if not a or not b:
        raise ValueError("welch needs two non-empty samples")
    diff = statistics.fmean(a) - statistics.fmean(b)
    if len(a) < 2 or len(b) < 2:
        return Welch(diff, None, None, None)
    va, vb = statistics.variance(a) / len(a), statistics.variance(b) / len(b)
    if va + vb == 0.0:
        return Welch(diff, None, None, 1.0 if diff == 0.0 else 0.0)
    t = diff / math.sqrt(va + vb)
    df = (va + vb) ** 2 / (va ** 2 / (len(a) - 1) + vb ** 2 / (len(b) - 1))
    return Welch(diff, t, df, t_two_sided_p(t, df))


def t_two_sided_p(t: float, df: float) -> float:
    """``P(|T| >= |t|)`` for Student's t with ``df`` degrees of freedom."""
    if df <= 0:
        raise ValueError(f"degrees of freedom must be > 0, got {df}")
    return _betainc(df / 2.0, 0.5, df / (df + t * t))


def t_cdf(t: float, df: float) -> float:
    """``P(T <= t)`` for Student's t with ``df`` degrees of freedom."""
    tail = 0.5 * t_two_sided_p(t, df)
    return 1.0 - tail if t > 0 else tail


def t_quantile(q: float, df: float) -> float:
    """The ``q``-quantile of Student's t (``0 < q < 1``), by bisection on ``t_cdf``."""
    if not 0.0 < q < 1.0:
        raise ValueError(f"quantile must be in (0, 1), got {q}")
    if q < 0.5:
        return -t_quantile(1.0 - q, df)
    lo, hi = 0.0, 1.0
    while t_cdf(hi, df) < q:
        hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if t_cdf(mid, df) < q:
            lo = mid
        else:
            hi = mid
        if hi - lo < 1e-12 * max(1.0, hi):
            break
    return 0.5 * (lo + hi)


def _betainc(a: float, b: float, x: float) -> float:
    """The regularised incomplete beta function ``I_x(a, b)``, by its continued fraction
    (modified Lentz), using the symmetry ``I_x(a, b) = 1 - I_{1-x}(b, a)`` where it converges faster."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    log_front = math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x) + b * math.log1p(-x)
    if x > (a + 1.0) / (a + b + 2.0):
        return 1.0 - _betainc(b, a, 1.0 - x)
    tiny, eps = 1e-300, 1e-15
    c, d = 1.0, 1.0 - (a + b) * x / (a + 1.0)
    d = 1.0 / (d if abs(d) > tiny else tiny)
    f = d
    for m in range(1, 500):
        for numerator in (m * (b - m) * x / ((a + 2 * m - 1) * (a + 2 * m)),
                          -(a + m) * (a + b + m) * x / ((a + 2 * m) * (a + 2 * m + 1))):
            d = 1.0 + numerator * d
            d = 1.0 / (d if abs(d) > tiny else tiny)
            c = 1.0 + numerator / c
            c = c if abs(c) > tiny else tiny
            f *= c * d
        if abs(c * d - 1.0) < eps:
            break
    return math.exp(log_front) * f / a
