"""Is a change real? Intervals for a share, and two evaluations of one test set compared episode by episode.

Thirty-two episodes give the share within 2 mm to about +-15 points (95 %), so two runs that
differ by an episode or two say nothing by their shares alone. Run on the *same* test set, they
can be compared pair by pair: only the episodes that one run places within 2 mm and the other
does not (the discordant pairs) carry information about which is better, and under "no
difference" each such episode is equally likely to go either way (McNemar's exact test). The
belief's reported P(within 2 mm) is compared the same way, by its log loss per episode
(Wilcoxon's signed-rank test on the paired differences).
"""

from __future__ import annotations

import math

import numpy as np

from tactojax.localize._belief import WITHIN_MM
from tactojax.localize._calibrate import log_losses

LEVEL = 0.95
"""Confidence level of the reported intervals."""

PROBABILITY_FLOOR = 1e-3
"""Predicted probabilities are clipped to [floor, 1 - floor] in the log loss (one confident
miss must not decide a comparison of dozens)."""


def finite_or_none(value) -> float | None:
    """A float for JSON, None where it is not finite (an error of +inf: no estimate)."""
    return float(value) if math.isfinite(value) else None


def share_interval(successes: int, count: int, level: float = LEVEL) -> list[float] | None:
    """Wilson score interval ``[low, high]`` of a share ``successes / count`` (None for none)."""
    if count == 0:
        return None
    from scipy.stats import binomtest

    interval = binomtest(int(successes), int(count)).proportion_ci(confidence_level=level, method="wilson")
    return [float(interval.low), float(interval.high)]


def paired_shares(before: np.ndarray, after: np.ndarray) -> dict:
    """Two runs' outcomes (bool, one per episode, the same episodes in the same order) compared:
    the shares, the episodes only ``after`` gets right (``gained``) and only ``before`` does
    (``lost``), and McNemar's exact two-sided p-value (1.0 when no episode differs)."""
    before, after = np.asarray(before, bool), np.asarray(after, bool)
    if before.shape != after.shape:
        raise ValueError(f"paired outcomes need the same episodes: {before.shape} against {after.shape}")
    gained, lost = int(np.sum(after & ~before)), int(np.sum(before & ~after))
    p = 1.0
    if gained + lost:
        from scipy.stats import binomtest

        p = float(binomtest(gained, gained + lost, 0.5).pvalue)
    return {"before": float(np.mean(before)), "after": float(np.mean(after)), "gained": gained, "lost": lost,
            "p": p}


def paired_log_loss(p_before: np.ndarray, happened_before: np.ndarray, p_after: np.ndarray,
                    happened_after: np.ndarray) -> dict:
    """The mean log loss of two runs' P(within 2 mm), episode by episode, and the two-sided
    p-value of Wilcoxon's signed-rank test on their differences (1.0 when none differs)."""
    before = log_losses(p_before, happened_before, PROBABILITY_FLOOR)
    after = log_losses(p_after, happened_after, PROBABILITY_FLOOR)
    differences = after - before
    p = 1.0
    if np.any(np.abs(differences) > 1e-9):
        from scipy.stats import wilcoxon

        p = float(wilcoxon(differences, zero_method="wilcox").pvalue)
    return {"before": float(np.mean(before)), "after": float(np.mean(after)), "p": p}


def _errors(values: list) -> np.ndarray:
    """(N,) errors, mm, from a JSON list: None (no estimate) is a failure, +inf."""
    return np.array([np.inf if value is None else value for value in values], np.float64)


def _row_key(row: dict) -> tuple:
    """What identifies a row of an evaluation's JSON: the method or policy, fingers, grasps,
    and whether its localizations are fused episodes or single touches."""
    return (row.get("method", row.get("policy")), row.get("fingers"), row.get("grasps"), row.get("fused", True))


def compare_evaluations(before: dict, after: dict) -> list[dict]:
    """Every row that two evaluations' JSON share, compared localization by localization.

    Both must come from runs on the same test set (``tactojax eval-localization --test`` or
    ``tactojax eval-active``, whose rows carry ``per_localization``): the rows are matched by
    object, method (or policy), fingers and grasps, and their localizations pair up in order.

    Returns:
        one dict per shared row: ``object``, ``method``, ``fingers``, ``grasps``, ``fused``,
        ``count``, ``within_2mm`` (:func:`paired_shares`, on the symmetry-aware error where
        the object is symmetric) and ``outcomes`` (each run's, per localization), ``median_mm``
        (before, after), and ``log_loss`` (:func:`paired_log_loss`) where both runs report
        P(within 2 mm); then, for every method, fingers and grasps of two or more objects, a
        row of object ``"all"``: their localizations pooled (``within_2mm`` only).

    Raises:
        ValueError: the two share no row, a shared row lacks ``per_localization`` (a JSON written
            before it existed) or holds a different number of localizations (another test set).
    """
    compared = []
    for name, theirs in after.get("objects", {}).items():
        ours = before.get("objects", {}).get(name)
        if ours is None:
            continue
        symmetric = bool(theirs.get("symmetric", False))
        rows_before = {_row_key(row): row for row in ours.get("results", [])}
        for row in theirs.get("results", []):
            key = _row_key(row)
            if key not in rows_before:
                continue
            old, new = rows_before[key].get("per_localization"), row.get("per_localization")
            if old is None or new is None:
                raise ValueError(f"{name}, {key[0]}: a row without per-localization errors (written by an "
                                 "older tactojax): run the evaluation again")
            error_key = "symmetric_rmse_mm" if symmetric else "rmse_mm"
            error_before, error_after = _errors(old[error_key]), _errors(new[error_key])
            if error_before.shape != error_after.shape:
                raise ValueError(f"{name}, {key[0]}, {key[2]} grasp(s): {len(error_before)} localizations "
                                 f"against {len(error_after)}: not the same test set")
            out = {"object": name, "method": key[0], "fingers": key[1], "grasps": key[2], "fused": key[3],
                   "count": int(len(error_after)),
                   "within_2mm": paired_shares(error_before <= WITHIN_MM, error_after <= WITHIN_MM),
                   "outcomes": [(error_before <= WITHIN_MM).tolist(), (error_after <= WITHIN_MM).tolist()],
                   "median_mm": [float(np.median(error_before)), float(np.median(error_after))]}
            if "p_within_2mm" in old and "p_within_2mm" in new:
                out["log_loss"] = paired_log_loss(old["p_within_2mm"], error_before <= WITHIN_MM,
                                                  new["p_within_2mm"], error_after <= WITHIN_MM)
            compared.append(out)
    if not compared:
        raise ValueError("the two evaluations share no object and row (method, fingers, grasps)")
    return compared + _pooled(compared)


def _pooled(compared: list[dict]) -> list[dict]:
    """One row ``object="all"`` per method, fingers and grasps that two or more objects share:
    their localizations pooled (more pairs, a more sensitive test)."""
    groups: dict[tuple, list[dict]] = {}
    for row in compared:
        groups.setdefault((row["method"], row["fingers"], row["grasps"], row["fused"]), []).append(row)
    pooled = []
    for (method, fingers, grasps, fused), rows in groups.items():
        if len(rows) < 2:
            continue
        before = np.concatenate([r["outcomes"][0] for r in rows])
        after = np.concatenate([r["outcomes"][1] for r in rows])
        pooled.append({"object": "all", "method": method, "fingers": fingers, "grasps": grasps, "fused": fused,
                       "count": int(len(after)), "within_2mm": paired_shares(before, after), "median_mm": None})
    return pooled


def format_p(p: float) -> str:
    """A p-value for a table: two decimals, or ``< 0.001``."""
    return "< 0.001" if p < 1e-3 else f"{p:.3f}" if p < 0.01 else f"{p:.2f}" if not math.isnan(p) else "-"
