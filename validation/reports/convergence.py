"""Convergence rate: a least-squares line through log RMSE against log render time.

An unbiased Monte Carlo estimator's RMSE falls as time^(-1/2); a slope that flattens towards 0 is bias.
The fitted line also gives the time an estimator needs to reach a given RMSE.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats


@dataclass
class Fit:
    slope: float
    intercept: float   # of log(rmse) = intercept + slope * log(seconds)
    r2: float = 1.0
    points: int = 0

    @property
    def meaningful(self) -> bool:
        """At least 3 points on a line (r^2 >= 0.9) with a slope an estimator can have (-1 to 0)."""
        return self.points >= 3 and self.r2 >= 0.9 and -1.0 <= self.slope <= 0.0

    def predict(self, seconds) -> np.ndarray:
        return np.exp(self.intercept + self.slope * np.log(seconds))

    def seconds_to_reach(self, rmse: float) -> float:
        return float(np.exp((np.log(rmse) - self.intercept) / self.slope))


def fit(seconds: list[float], rmse: list[float]) -> Fit:
    """scipy.stats.linregress on the logarithms (no fit, NaN, where an error is 0: a black image)."""
    if min(rmse) <= 0 or len(seconds) < 2:
        return Fit(float("nan"), float("nan"), 0.0, len(seconds))
    result = stats.linregress(np.log(seconds), np.log(rmse))
    return Fit(float(result.slope), float(result.intercept), float(result.rvalue ** 2), len(seconds))


def common_error(curves: dict[str, list[float]]) -> float:
    """The smallest RMSE that every curve reached: the largest of the curves' minima."""
    return max(min(values) for values in curves.values())
