"""Response-surface regression of the DoE response, ANOVA effect table, pure error and optimum.

Two models of the response (the runout MSE) on k >= 2 coded factors x = (value - centre)/half_range:
  eq9        main effects + every two-factor interaction; for k = 2 the paper's eq. (9):
             b0 + b1 x1 + b2 x2 + b12 x1 x2
  quadratic  the full second-order response surface: eq9 + every square (k = 2: + b11 x1^2 + b22 x2^2)
Fitted by ordinary least squares with statsmodels; the effect table is statsmodels' ANOVA with
partial (type III) sums of squares, i.e. JMP's "Effect Tests" that the paper's Table 4 reports,
with LogWorth = -log10(p). Replicated design points (the centre run with another packing seed)
give the pure error and a lack-of-fit test. The optimum of each model is the minimum of the fitted
surface within the factor bounds.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
import statsmodels.formula.api as smf
from numpy.typing import ArrayLike
from scipy import optimize, stats
from statsmodels.stats.anova import anova_lm

if TYPE_CHECKING:
    from doe.design import Factor

MODELS = ("eq9", "quadratic")
# symbols of the prediction expression; a factor not listed is written by its name
SYMBOLS = {
    "friction": "mu",
    "restitution": "e",
    "rolling_friction": "mu_r",
    "bond_number": "Bo",
    "friction_base": "mu_base",
    "sidewall_friction": "mu_wall",
}
# points of the global search grid before the bounded polish, all axes together: 201 per axis in
# 2-D (a 0.01 coded step), 33 per axis in 3-D; a fixed total keeps the search cheap for any k
GRID_TOTAL = 201**2


class RegressionError(ValueError):
    """The responses cannot be fitted; the message says why."""


def model_terms(model: str, factors: Sequence[Factor]) -> list[str]:
    """Formula terms of `model` (intercept aside) on the coded columns x_<name>: the main effects,
    every two-factor interaction x_a:x_b, and for the quadratic model every square I(x_a ** 2)."""
    x = [f"x_{f.name}" for f in factors]
    terms = x + [f"{a}:{b}" for a, b in itertools.combinations(x, 2)]
    if model == "quadratic":
        terms += [f"I({name} ** 2)" for name in x]
    elif model != "eq9":
        raise RegressionError(f"unknown model {model!r}; known: {list(MODELS)}")
    return terms


def formula(model: str, factors: Sequence[Factor], response: str = "response") -> str:
    """statsmodels/patsy formula of `model` on the coded factor columns x_<name>."""
    return f"{response} ~ " + " + ".join(model_terms(model, factors))


def grid_points_per_axis(n_factors: int, total: int = GRID_TOTAL) -> int:
    """Largest odd number of points per coded axis (3 at least) whose grid over n_factors axes has
    at most `total` points (odd: the centre and the face centres of the design are grid points)."""
    n = 3
    while (n + 2) ** n_factors <= total:
        n += 2
    return n


def term_label(term: str, factors: Sequence[Factor]) -> str:
    """JMP-style source name of a formula term: 'friction(0.3,0.9)', 'friction*restitution', ..."""
    bounds = {f"x_{f.name}": f"{f.name}({f.low:g},{f.high:g})" for f in factors}
    if term in bounds:
        return bounds[term]
    if term.startswith("I(") and term.endswith("** 2)"):
        name = term[2:].split()[0][2:]
        return f"{name}*{name}"
    return "*".join(part[2:] for part in term.split(":"))


@dataclass
class SurfaceFit:
    """One fitted response surface. result: statsmodels RegressionResults; factors: doe.design.Factor."""

    model: str
    factors: tuple
    result: object
    response: str = "mse"

    # -- fit summary -------------------------------------------------------------------------
    @property
    def r_squared(self) -> float:
        return float(self.result.rsquared)

    def coefficients(self) -> pd.DataFrame:
        """Coded-unit coefficients: term, estimate, std_error, t, p_value."""
        r = self.result
        return pd.DataFrame(
            {
                "term": r.params.index,
                "estimate": r.params.values,
                "std_error": r.bse.values,
                "t": r.tvalues.values,
                "p_value": r.pvalues.values,
            }
        )

    def effect_table(self) -> pd.DataFrame:
        """statsmodels' ANOVA (type III) per model term: source, sum_sq, df, F, p_value, logworth;
        sorted by LogWorth, largest first, as the paper's Table 4 (intercept and residual left out)."""
        anova = anova_lm(self.result, typ=3).drop(index=["Intercept", "Residual"])
        table = pd.DataFrame(
            {
                "source": [term_label(t, self.factors) for t in anova.index],
                "term": anova.index,
                "sum_sq": anova["sum_sq"].values,
                "df": anova["df"].values,
                "F": anova["F"].values,
                "p_value": anova["PR(>F)"].values,
            }
        )
        table["logworth"] = -np.log10(table["p_value"])
        return table.sort_values("logworth", ascending=False, ignore_index=True)

    # -- prediction and optimum --------------------------------------------------------------
    def frame(self, coded: ArrayLike) -> pd.DataFrame:
        """Coded points [n, n_factors] (or one point [n_factors]) as the model's x_<name> columns."""
        coded = np.atleast_2d(np.asarray(coded, float))
        return pd.DataFrame({f"x_{f.name}": coded[:, k] for k, f in enumerate(self.factors)})

    def predict(self, coded: ArrayLike) -> np.ndarray:
        """Predicted response at coded points [n, n_factors] -> [n]."""
        return np.asarray(self.result.predict(self.frame(coded)), float)

    def optimum(self) -> dict:
        """Minimum of the fitted surface within the bounds (coded [-1, 1] on every factor).

        A grid of about GRID_TOTAL points finds the best basin (a bilinear or saddle surface has
        its minimum on the boundary), then bounded L-BFGS-B polishes it. Returns coded and natural
        coordinates, the predicted response and its 95% confidence interval, and the factors whose
        optimum sits on a bound (on_bound).
        """
        axes = np.linspace(-1, 1, grid_points_per_axis(len(self.factors)))
        grid = np.stack([g.ravel() for g in np.meshgrid(*[axes] * len(self.factors), indexing="ij")], axis=1)
        start = grid[int(np.argmin(self.predict(grid)))]
        polished = optimize.minimize(
            lambda z: float(self.predict(z)[0]), start, method="L-BFGS-B", bounds=[(-1.0, 1.0)] * len(self.factors)
        )
        best = polished.x if polished.fun <= self.predict(start)[0] else start
        interval = self.result.get_prediction(self.frame(best)).summary_frame(alpha=0.05).iloc[0]
        return {
            "coded": {f.name: float(best[k]) for k, f in enumerate(self.factors)},
            "natural": {f.name: float(f.decode(best[k])) for k, f in enumerate(self.factors)},
            "predicted": float(interval["mean"]),
            "ci_low": float(interval["mean_ci_lower"]),
            "ci_high": float(interval["mean_ci_upper"]),
            # an optimum on a bound says the best setting may lie outside the design region
            "on_bound": [f.name for k, f in enumerate(self.factors) if abs(best[k]) > 1 - 1e-6],
        }


def coded_frame(responses: pd.DataFrame, factors: Sequence[Factor], response: str) -> pd.DataFrame:
    """Coded factor columns and the response column, checked."""
    missing = [c for c in [f.name for f in factors] + [response] if c not in responses.columns]
    if missing:
        raise RegressionError(f"responses lack column(s) {missing}")
    y = responses[response].to_numpy(float)
    if not np.all(np.isfinite(y)):
        raise RegressionError(
            f"response {response!r} has non-finite values in rows {np.flatnonzero(~np.isfinite(y)).tolist()}"
        )
    frame = pd.DataFrame({f"x_{f.name}": f.code(responses[f.name].to_numpy(float)) for f in factors})
    frame["response"] = y
    return frame


def fit_surface(responses: pd.DataFrame, model: str, factors: Sequence[Factor], response: str = "mse") -> SurfaceFit:
    """OLS fit of `model` to responses (one row per run, factor columns in natural units)."""
    if len(factors) < 2:
        raise RegressionError(f"a response surface needs at least 2 factors, got {len(factors)}")
    frame = coded_frame(responses, factors, response)
    n_coefficients = len(model_terms(model, factors)) + 1  # + the intercept
    if len(frame) <= n_coefficients:
        raise RegressionError(f"{len(frame)} runs cannot fit the {model} model ({n_coefficients} coefficients)")
    ols = smf.ols(formula(model, factors), frame)
    # a design that cannot separate the terms (e.g. no run off the corners for the squares) would
    # otherwise be fitted silently by a pseudo-inverse
    if np.linalg.matrix_rank(ols.exog) < n_coefficients:
        raise RegressionError(f"the runs cannot separate the {n_coefficients} coefficients of the {model} model")
    return SurfaceFit(model=model, factors=tuple(factors), result=ols.fit(), response=response)


def pure_error(responses: pd.DataFrame, factors: Sequence[Factor], response: str = "mse") -> dict:
    """Pure error from runs repeated at the same factor setting (different packing seeds).

    Returns sum_sq, df, std (sqrt of the pure-error mean square, in response units) and
    replicated (number of settings run more than once). df = 0 when nothing is replicated.
    """
    names = [f.name for f in factors]
    groups = responses.groupby(names)[response]
    deviation = responses[response] - groups.transform("mean")
    df = int((groups.size() - 1).sum())
    sum_sq = float((deviation**2).sum())
    return {
        "sum_sq": sum_sq,
        "df": df,
        "std": math.sqrt(sum_sq / df) if df else math.nan,
        "replicated": int((groups.size() > 1).sum()),
    }


def lack_of_fit(fit: SurfaceFit, pure: dict) -> dict:
    """Lack-of-fit F test: residual SS split into pure error and lack of fit."""
    ss_resid, df_resid = float(fit.result.ssr), int(round(fit.result.df_resid))
    ss_lof, df_lof = ss_resid - pure["sum_sq"], df_resid - pure["df"]
    if pure["df"] == 0 or df_lof <= 0 or pure["sum_sq"] <= 0:
        return {"sum_sq": ss_lof, "df": df_lof, "F": math.nan, "p_value": math.nan}
    F = (ss_lof / df_lof) / (pure["sum_sq"] / pure["df"])
    return {"sum_sq": ss_lof, "df": df_lof, "F": float(F), "p_value": float(stats.f.sf(F, df_lof, pure["df"]))}


def analyse(
    responses: pd.DataFrame, factors: Sequence[Factor], response: str = "mse", models: Iterable[str] = MODELS
) -> tuple[dict, dict]:
    """Fit every model; returns ({model: SurfaceFit}, a JSON-ready summary).

    Summary: n_runs, pure_error, best_run (lowest observed response), and per model: formula,
    r_squared, r_squared_adj, rmse, coefficients, effects (the effect table), lack_of_fit, optimum.
    """
    fits = {model: fit_surface(responses, model, factors, response) for model in models}
    pure = pure_error(responses, factors, response)
    best = responses.loc[responses[response].idxmin()]
    summary = {
        "response": response,
        "n_runs": int(len(responses)),
        "pure_error": pure,
        "factors": {f.name: [f.low, f.high] for f in factors},
        "best_run": {
            "run_id": str(best.get("run_id", best.name)),
            response: float(best[response]),
            **{f.name: float(best[f.name]) for f in factors},
        },
        "models": {},
    }
    for model, fit in fits.items():
        summary["models"][model] = {
            "formula": formula(model, factors),
            "r_squared": fit.r_squared,
            "r_squared_adj": float(fit.result.rsquared_adj),
            "rmse": float(math.sqrt(fit.result.mse_resid)),
            "coefficients": fit.coefficients().to_dict(orient="records"),
            "effects": fit.effect_table().to_dict(orient="records"),
            "lack_of_fit": lack_of_fit(fit, pure),
            "optimum": fit.optimum(),
        }
    return fits, summary


def prediction_expression(fit: SurfaceFit, digits: int = 3) -> str:
    """The fitted model written out like the paper's eq. (9), with coded factors spelled out."""
    names = {f"x_{f.name}": f"(({SYMBOLS.get(f.name, f.name)} - {f.centre:g})/{f.half_range:g})" for f in fit.factors}
    parts = []
    for term, value in fit.result.params.items():
        if term == "Intercept":
            parts.append(f"{value:.{digits}f}")
            continue
        if term.startswith("I("):
            body = names[term[2:].split()[0]] + "^2"
        else:
            body = " * ".join(names[p] for p in term.split(":"))
        parts.append(f"{'-' if value < 0 else '+'} {abs(value):.{digits}f} * {body}")
    return f"{fit.response} = " + " ".join(parts)
