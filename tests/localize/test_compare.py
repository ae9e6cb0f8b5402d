"""Intervals and paired comparisons of evaluations, against closed forms computed here."""

import math

import numpy as np
import pytest

from tactojax.localize.evaluation import compare_evaluations, paired_log_loss, paired_shares, share_interval


def wilson(successes, count, z=1.959963984540054):
    """The Wilson score interval, from its formula."""
    share = successes / count
    centre = (share + z * z / (2 * count)) / (1 + z * z / count)
    half = z / (1 + z * z / count) * math.sqrt(share * (1 - share) / count + z * z / (4 * count * count))
    return centre - half, centre + half


@pytest.mark.parametrize("successes, count", [(26, 32), (0, 16), (32, 32), (5, 7)])
def test_share_interval_is_wilsons(successes, count):
    assert np.allclose(share_interval(successes, count), wilson(successes, count), atol=1e-9)
    assert share_interval(0, 0) is None


def test_paired_shares_is_mcnemars_exact_test():
    before = np.array([True] * 20 + [False] * 12)
    after = before.copy()
    after[20:26] = True  # six episodes gained, none lost
    result = paired_shares(before, after)
    assert (result["gained"], result["lost"]) == (6, 0)
    assert result["before"] == 20 / 32 and result["after"] == 26 / 32
    assert np.isclose(result["p"], 2 * 0.5**6)  # two-sided: the six all going one way, either way
    after[0] = False  # and one lost: P(X <= 1 | 7, 1/2), twice
    assert np.isclose(paired_shares(before, after)["p"], 2 * (1 + 7) / 2**7)
    assert paired_shares(before, before)["p"] == 1.0
    with pytest.raises(ValueError, match="same episodes"):
        paired_shares(before, before[:-1])


def test_paired_log_loss():
    happened = np.array([True, True, False, True])
    same = paired_log_loss([0.9, 0.8, 0.2, 0.7], happened, [0.9, 0.8, 0.2, 0.7], happened)
    assert same["p"] == 1.0 and np.isclose(same["before"], same["after"])
    expected = -np.mean(np.log([0.9, 0.8, 0.8, 0.7]))
    assert np.isclose(same["before"], expected)
    # A confident miss is clipped, not infinite.
    assert np.isfinite(paired_log_loss([1.0], [False], [0.5], [False])["before"])


def evaluation(errors_by_row, symmetric=False):
    """A minimal evaluation JSON: one object, rows keyed by grasps."""
    rows = [{"method": "belief", "fingers": 2, "grasps": g, "fused": True, "count": len(e),
             "per_localization": {"rmse_mm": list(e), "symmetric_rmse_mm": list(np.minimum(e, 1.0)),
                                  "p_within_2mm": [0.5] * len(e)}} for g, e in errors_by_row.items()]
    return {"test": ["t"], "objects": {"box": {"symmetric": symmetric, "results": rows}}}


def test_compare_evaluations_pairs_rows_and_refuses_other_test_sets():
    before = evaluation({1: [1.0, 3.0, 4.0], 2: [1.0, 1.0, 5.0]})
    after = evaluation({1: [1.0, 1.0, 1.0], 3: [0.1, 0.1, 0.1]})
    [row] = compare_evaluations(before, after)  # only the 1-grasp row is in both
    assert row["grasps"] == 1 and row["count"] == 3
    assert (row["within_2mm"]["gained"], row["within_2mm"]["lost"]) == (2, 0)
    assert row["median_mm"] == [3.0, 1.0]
    assert "log_loss" in row
    # A localization without an estimate (None in the JSON) is a failure.
    missing = evaluation({1: [1.0, 1.0, 1.0]})
    missing["objects"]["box"]["results"][0]["per_localization"]["rmse_mm"][0] = None
    [row] = compare_evaluations(before, missing)
    assert (row["within_2mm"]["gained"], row["within_2mm"]["lost"]) == (2, 1)
    # Symmetric objects are judged on the symmetry-aware error (here every error below 1 mm).
    [row] = compare_evaluations(evaluation({1: [1.0, 3.0, 4.0]}, True), evaluation({1: [1.0, 1.0, 1.0]}, True))
    assert row["within_2mm"]["gained"] == row["within_2mm"]["lost"] == 0
    with pytest.raises(ValueError, match="not the same test set"):
        compare_evaluations(before, evaluation({1: [1.0, 1.0]}))
    with pytest.raises(ValueError, match="share no object"):
        compare_evaluations(before, evaluation({4: [1.0]}))
    old = evaluation({1: [1.0]})
    del old["objects"]["box"]["results"][0]["per_localization"]
    with pytest.raises(ValueError, match="run the evaluation again"):
        compare_evaluations(old, evaluation({1: [1.0]}))


def test_compare_evaluations_pools_the_objects():
    before, after = evaluation({1: [1.0, 3.0]}), evaluation({1: [1.0, 1.0]})
    before["objects"]["cup"] = before["objects"]["box"]
    after["objects"]["cup"] = after["objects"]["box"]
    rows = compare_evaluations(before, after)
    assert [r["object"] for r in rows] == ["box", "cup", "all"]
    assert rows[-1]["count"] == 4 and rows[-1]["within_2mm"]["gained"] == 2
    assert np.isclose(rows[-1]["within_2mm"]["p"], 2 * 0.5**2)
