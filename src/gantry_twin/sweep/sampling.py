"""Where a sweep's values come from: grids, ranges and random draws.

A grid axis lists its values, or spans a range: ``linspace`` (evenly spaced)
or ``logspace`` (evenly spaced in log, the ends given as values, not
exponents). A random field draws from ``uniform``, ``normal`` (optionally
truncated to [min, max]) or ``log_uniform``. Every draw is the inverse CDF
of a unit sample u in [0, 1): the ``random`` method takes u from numpy's
Generator, ``latin_hypercube`` from scipy's LatinHypercube (each field's
range cut into N equal-probability strata, one sample in each). Both are
seeded, so a sweep file always gives the same points.
"""

from __future__ import annotations

import math
from typing import Any, Literal

import numpy as np
from pydantic import model_validator

from gantry_twin.settings import Count, Model, Positive, Real, rule

#: Most points one sweep may hold (grid x samples x repeats).
POINTS_MAX = 100_000
Num = Count(1, POINTS_MAX)
Seed = Count(0, 2**63 - 1)
Method = Literal["random", "latin_hypercube"]


def _pair(cls: type, data: Any) -> Any:
    """``[low, high]`` is short for ``{low: ..., high: ...}``."""
    if isinstance(data, list | tuple) and len(data) == 2:
        return {"low": data[0], "high": data[1]}
    return data


def _ordered(lo: float, hi: float, field: str) -> None:
    if not hi > lo:
        raise rule(field, f"must be above {lo:g}, got {hi:g}")


class Linspace(Model):
    """``num`` values evenly spaced from ``start`` to ``stop`` (both included)."""

    start: Real
    stop: Real
    num: Num

    def values(self) -> list[float]:
        return [float(v) for v in np.linspace(self.start, self.stop, self.num)]


class Logspace(Model):
    """``num`` values from ``start`` to ``stop`` (both included, both > 0) evenly spaced in log."""

    start: Positive
    stop: Positive
    num: Num

    def values(self) -> list[float]:
        return [float(v) for v in np.geomspace(self.start, self.stop, self.num)]


class Uniform(Model):
    """Uniform on [low, high) (``uniform: [low, high]`` in a file)."""

    low: Real
    high: Real

    _short = model_validator(mode="before")(classmethod(_pair))

    @model_validator(mode="after")
    def _check(self) -> Uniform:
        _ordered(self.low, self.high, "high")
        return self

    def ppf(self, u: np.ndarray) -> np.ndarray:
        return self.low + u * (self.high - self.low)


class LogUniform(Model):
    """log(x) uniform on [log low, log high), low > 0 (``log_uniform: [low, high]`` in a file)."""

    low: Positive
    high: Positive

    _short = model_validator(mode="before")(classmethod(_pair))

    @model_validator(mode="after")
    def _check(self) -> LogUniform:
        _ordered(self.low, self.high, "high")
        return self

    def ppf(self, u: np.ndarray) -> np.ndarray:
        return np.exp(math.log(self.low) + u * (math.log(self.high) - math.log(self.low)))


class Normal(Model):
    """Gaussian N(mean, std^2), truncated to [min, max] when they are given."""

    mean: Real
    std: Positive
    min: Real | None = None
    max: Real | None = None

    @model_validator(mode="after")
    def _check(self) -> Normal:
        if self.min is not None and self.max is not None:
            _ordered(self.min, self.max, "max")
        return self

    def ppf(self, u: np.ndarray) -> np.ndarray:
        from scipy.stats import norm

        lo = 0.0 if self.min is None else norm.cdf(self.min, self.mean, self.std)
        hi = 1.0 if self.max is None else norm.cdf(self.max, self.mean, self.std)
        # u = 0 would map to -inf: keep the unit sample inside (0, 1).
        p = np.clip(lo + u * (hi - lo), np.finfo(float).tiny, 1.0 - np.finfo(float).eps)
        x = norm.ppf(p, self.mean, self.std)
        return np.clip(x, -math.inf if self.min is None else self.min, math.inf if self.max is None else self.max)


class RandomField(Model):
    """One scenario field drawn at random: exactly one of ``uniform``, ``normal``, ``log_uniform``."""

    field: str
    uniform: Uniform | None = None
    normal: Normal | None = None
    log_uniform: LogUniform | None = None

    @model_validator(mode="after")
    def _one_distribution(self) -> RandomField:
        given = [d for d in (self.uniform, self.normal, self.log_uniform) if d is not None]
        if len(given) != 1:
            raise rule("uniform", f"give exactly one of uniform, normal, log_uniform (got {len(given)})")
        return self

    @property
    def distribution(self) -> Uniform | Normal | LogUniform:
        return next(d for d in (self.uniform, self.normal, self.log_uniform) if d is not None)


class RandomSpec(Model):
    """``samples`` draws of every field in ``fields``, by ``method``, from ``seed``."""

    samples: Num
    seed: Seed = 0
    method: Method = "random"
    fields: list[RandomField]

    @model_validator(mode="after")
    def _some_fields(self) -> RandomSpec:
        if not self.fields:
            raise rule("fields", "must list at least one field to draw")
        return self


def unit_samples(n: int, d: int, method: Method, seed: int) -> np.ndarray:
    """(n, d) samples in [0, 1): independent uniforms, or a Latin hypercube."""
    rng = np.random.default_rng(seed)
    if method == "latin_hypercube":
        from scipy.stats import qmc

        return qmc.LatinHypercube(d=d, rng=rng).random(n)
    return rng.random((n, d))


def draws(spec: RandomSpec) -> list[dict[str, float]]:
    """The ``samples`` draws of a random spec, each a mapping field -> value."""
    u = unit_samples(spec.samples, len(spec.fields), spec.method, spec.seed)
    columns = [f.distribution.ppf(u[:, j]) for j, f in enumerate(spec.fields)]
    return [{f.field: float(col[i]) for f, col in zip(spec.fields, columns, strict=True)} for i in range(spec.samples)]


def grid_values(values: list[Any] | None, linspace: Linspace | None, logspace: Logspace | None) -> list[Any]:
    """An axis's values: as listed, or spanned by its range."""
    if values is not None:
        return list(values)
    span = linspace if linspace is not None else logspace
    assert span is not None  # the axis's validator requires one of the three
    return span.values()
