"""The heightmap-error table printed by ``train`` and ``eval-shape``."""

from __future__ import annotations

from tactojax.cli._table import format_table


def print_shape_report(errors: dict, object_ids, *, title: str) -> dict:
    """Print errors per object and over all; return the summary (for JSON)."""
    from tactojax.shape import summarize_errors

    summary = summarize_errors(errors, object_ids)
    rows = [[name, row["count"], f"{row['patch_rmse']:.4f} ± {row['patch_rmse_std']:.4f}",
             f"{row['image_rmse']:.4f}", f"{row['mask_iou']:.3f}"] for name, row in summary.items()]
    print(f"\n{title}: RMSE in mm over the true contact patch and over the whole image")
    print(format_table(["object", "pairs", "patch RMSE (mm)", "image RMSE", "mask IoU"], rows))
    return summary
