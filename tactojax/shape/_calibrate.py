"""Calibrate the classical colour -> slope model of a real sensor from ball presses.

A GelSight-type sensor is calibrated by pressing a ball of known radius R at many places
(Johnson & Adelson 2009; Taxim, Si & Yuan 2022). Each press is annotated with the centre and
radius r of its contact disc. Inside the disc the gel takes the ball's shape, a spherical cap,
so every contact pixel gets a known slope; :func:`fit_lookup_model` tabulates colour change ->
slope from these pixels and integrates slopes into heights at run time.

The ball radius sets the height scale and must in general be measured (callipers). The images
alone cannot tell it: inside a contact disc the gel at distance rho from the centre has the
same normal in every press, whatever the press depth, so any R gives a self-consistent table
(slopes reparametrised as ``rho / sqrt(R^2 - rho^2)``). :func:`estimate_ball_radius` therefore
relies on an extra assumption, stated in its docstring, and says when the data do not support
an estimate.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from tactojax.shape._data import ShapeData

BALL = "ball"
"""Object id of ball presses in the :class:`ShapeData` they become."""


@dataclasses.dataclass(frozen=True)
class BallPresses:
    """N annotated presses of a ball on one sensor, host memory (validated on construction).

    Pixel coordinates: x along image columns, y along image rows, pixel (row i, column j)
    centred at (x, y) = (j, i).
    """

    background: np.ndarray
    """(H, W, 3) float32 RGB in [0, 1]: the gel with nothing touching."""
    images: np.ndarray
    """(N, H, W, 3) uint8 RGB presses."""
    centers_px: np.ndarray
    """(N, 2) float32 contact-disc centres (x = column, y = row), pixels."""
    radii_px: np.ndarray
    """(N,) float32 contact-disc radii, pixels."""
    mm_per_px: float
    """Pixel pitch on the gel, mm."""
    sensor: str = ""
    """Sensor label carried into the calibrated model."""

    def __post_init__(self):
        background = np.asarray(self.background, np.float32)
        images = np.asarray(self.images)
        centers = np.asarray(self.centers_px, np.float32)
        radii = np.asarray(self.radii_px, np.float32)
        if background.ndim != 3 or background.shape[2] != 3:
            raise ValueError(f"background must be (H, W, 3) RGB, got shape {background.shape}")
        if not (np.all(np.isfinite(background)) and background.min() >= 0 and background.max() <= 1):
            raise ValueError("background must be RGB in [0, 1]")
        height_px, width_px = background.shape[:2]
        if images.ndim != 4 or images.shape[1:] != (height_px, width_px, 3):
            raise ValueError(f"press images must be (N, {height_px}, {width_px}, 3) like the "
                             f"background, got shape {images.shape}")
        if images.dtype != np.uint8:
            raise ValueError(f"press images must be uint8, got {images.dtype}")
        count = len(images)
        if count == 0:
            raise ValueError("no ball presses")
        if centers.shape != (count, 2) or radii.shape != (count,):
            raise ValueError(f"{count} presses need centres (N, 2) and radii (N,), got "
                             f"{centers.shape} and {radii.shape}")
        if not (np.isfinite(self.mm_per_px) and self.mm_per_px > 0):
            raise ValueError(f"mm_per_px must be positive, got {self.mm_per_px}")
        for index, ((x, y), r) in enumerate(zip(centers, radii)):
            if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(r) and r > 0):
                raise ValueError(f"press {index}: centre ({x}, {y}) and radius {r} px must be finite, "
                                 "radius positive")
            if x - r < 0 or y - r < 0 or x + r > width_px - 1 or y + r > height_px - 1:
                raise ValueError(f"press {index}: contact disc at ({x:g}, {y:g}) px with radius {r:g} px "
                                 f"reaches outside the {width_px} x {height_px} px image")
        object.__setattr__(self, "background", background)
        object.__setattr__(self, "images", images)
        object.__setattr__(self, "centers_px", centers)
        object.__setattr__(self, "radii_px", radii)
        object.__setattr__(self, "mm_per_px", float(self.mm_per_px))

    def __len__(self) -> int:
        return len(self.images)

    @property
    def image_shape(self) -> tuple[int, int]:
        """(H, W) of the frames."""
        return tuple(self.background.shape[:2])

    @property
    def contact_radii_mm(self) -> np.ndarray:
        """(N,) contact-disc radii, mm."""
        return self.radii_px.astype(np.float64) * self.mm_per_px

    def take(self, indices) -> BallPresses:
        """The presses at ``indices`` (an index array or boolean mask)."""
        return dataclasses.replace(self, images=self.images[indices], centers_px=self.centers_px[indices],
                                   radii_px=self.radii_px[indices])


def _check_ball_radius(presses: BallPresses, ball_radius_mm: float) -> float:
    ball_radius_mm = float(ball_radius_mm)
    if not (np.isfinite(ball_radius_mm) and ball_radius_mm > 0):
        raise ValueError(f"ball radius must be positive, got {ball_radius_mm} mm")
    contact = presses.contact_radii_mm
    worst = int(np.argmax(contact))
    if contact[worst] >= ball_radius_mm:
        raise ValueError(f"press {worst} has a contact radius of {contact[worst]:.4f} mm, not smaller than "
                         f"the ball radius {ball_radius_mm:.4f} mm: a ball that small cannot make it "
                         "(check the ball radius, mm_per_px and the annotated radii)")
    return ball_radius_mm


def _squared_distance_mm(presses: BallPresses, index: int) -> np.ndarray:
    """(H, W) squared distance of every pixel centre to the press's disc centre, mm^2."""
    height_px, width_px = presses.image_shape
    x, y = presses.centers_px[index].astype(np.float64)
    cols = (np.arange(width_px) - x) ** 2
    rows = (np.arange(height_px) - y) ** 2
    return (rows[:, None] + cols[None, :]) * presses.mm_per_px**2


def ball_press_data(presses: BallPresses, ball_radius_mm: float) -> ShapeData:
    """The ground truth a ball imposes on each press, as (image, heightmap, mask) pairs.

    Inside a contact disc of radius r the gel follows the ball, a spherical cap of radius R:
    ``h(rho) = sqrt(R^2 - rho^2) - sqrt(R^2 - r^2)`` (depth ``R - sqrt(R^2 - r^2)`` at the
    centre); outside it the gel is taken as undeformed (h = 0). The mask is the disc
    ``rho < r``.

    Args:
        presses: annotated presses.
        ball_radius_mm: R, mm; larger than every contact radius.

    Returns:
        A :class:`ShapeData` with object id ``"ball"`` for every press.
    """
    radius = _check_ball_radius(presses, ball_radius_mm)
    count = len(presses)
    heightmaps = np.zeros((count, *presses.image_shape), np.float32)
    masks = np.zeros((count, *presses.image_shape), bool)
    for index, contact in enumerate(presses.contact_radii_mm):
        rho2 = _squared_distance_mm(presses, index)
        inside = rho2 < contact**2
        cap = np.sqrt(np.maximum(radius**2 - rho2, 0.0)) - np.sqrt(radius**2 - contact**2)
        heightmaps[index] = np.where(inside, cap, 0.0)
        masks[index] = inside
    if not masks.reshape(count, -1).any(axis=1).all():
        empty = int(np.flatnonzero(~masks.reshape(count, -1).any(axis=1))[0])
        raise ValueError(f"press {empty}: its contact disc covers no pixel centre")
    return ShapeData(images=presses.images, heightmaps=heightmaps, masks=masks,
                     object_ids=np.full(count, BALL), mm_per_px=presses.mm_per_px, sensor=presses.sensor)


def estimate_ball_radius(
    presses: BallPresses,
    candidates_mm=None,
    *,
    folds: int = 4,
    rim_px: float = 1.5,
    min_t_statistic: float = 3.0,
    min_explained: float = 0.95,
) -> tuple[float, dict]:
    """Estimate the ball radius from the presses by cross-validated photometric consistency.

    Why the obvious test does not work: the colour -> slope lookup table gives a consistent
    map for *every* candidate R. In each press the gel at distance rho from the disc centre
    has the ball's normal there whatever the press depth, so its colour is the same function
    of rho in every press, and a candidate R only relabels that colour with the slope
    ``rho / sqrt(R^2 - rho^2)``. Frames with different contact radii agree for every R; the
    held-out slope residual only shrinks as R grows (the slopes themselves shrink). On the 48
    taxim GelSight presses the relative held-out slope residual falls monotonically from 0.13
    at R = 1.99 mm to 0.044 at R = 8 mm.

    What is used instead (photometric stereo, an extra assumption): the colour change of the
    gel is an affine function of its unit normal, as for a Lambertian membrane under distant
    lights, ``c - background = A n + b`` (A: 3 x 3, b: 3, shared by all presses). Under a
    candidate R a contact pixel at offset (dx, dy) from the disc centre has the normal
    ``(dx, dy, sqrt(R^2 - rho^2)) / R``. For each candidate A and b are fitted by least squares
    on the contact pixels of all presses but one fold (presses ``i % folds == k``), and the
    colour residual is measured on the held-out fold; the score is the pooled held-out RMSE,
    in colour units whatever R, so candidates compare fairly. Pixels within ``rim_px`` of the
    annotated disc edge are left out (the edge is uncertain by a pixel and the gel's slope
    is discontinuous there). The signal is the curvature of ``sqrt(R^2 - rho^2)`` beyond a
    paraboloid: strong when contact radii reach a good fraction of R, nil for shallow presses
    (R >> r), where a sphere of any large radius looks like a paraboloid.

    The estimate is ``identifiable`` only when (1) the best candidate is not the largest, (2)
    the held-out presses prefer it to the largest candidate (the paraboloid limit)
    consistently: the paired t statistic of their per-press mean squared residuals is at
    least ``min_t_statistic``, and (3) the affine model explains at least ``min_explained`` of
    the held-out colour variance, so that the assumption holds. The real GelSight of taxim
    fails all three (held-out colour RMSE 7.99/255 at R = 2.0 mm and 7.96/255 at R = 7.9 mm,
    92 % explained): measure the ball instead.

    Args:
        presses: annotated presses (at least 2).
        candidates_mm: radii to try, mm; those not above the largest contact radius (the hard
            lower bound) are dropped. Default: 30 radii from 1.01 to 4 times that bound,
            geometrically spaced.
        folds: cross-validation folds (at most the number of presses).
        rim_px: width of the disc edge left out, pixels.
        min_t_statistic: consistency needed over the held-out presses.
        min_explained: fraction of held-out colour variance the model must explain.

    Returns:
        (best radius in mm, refined by a parabola through the best candidate and its
        neighbours in log R; table) where table holds ``ball_radius_mm`` and ``colour_rmse``
        (per candidate, RGB in [0, 1]), ``lower_bound_mm``, ``best_candidate_mm``,
        ``t_statistic``, ``explained``, ``identifiable``, ``folds`` and ``method``.
    """
    count = len(presses)
    if count < 2:
        raise ValueError(f"estimating the ball radius needs at least 2 presses, got {count}")
    lower_bound = float(presses.contact_radii_mm.max())
    candidates = _candidate_radii(lower_bound, candidates_mm)
    folds = max(2, min(int(folds), count))
    pixels = [_contact_pixels(presses, index, rim_px) for index in range(count)]
    sizes = np.array([change.size for _, _, change in pixels], np.float64)
    if np.any(sizes == 0):
        raise ValueError(f"press {int(np.argmin(sizes))}: no pixel inside its contact disc once the "
                         f"{rim_px} px rim is left out")
    # (candidates, presses) held-out sums of squared colour residuals.
    squared = np.stack([_cross_validated_squares(pixels, radius, folds) for radius in candidates])
    rmse = np.sqrt(squared.sum(axis=1) / sizes.sum())
    best = int(np.argmin(rmse))
    improvement = (squared[-1] - squared[best]) / sizes
    spread = improvement.std(ddof=1) / np.sqrt(count)
    # Capped so that the table stays finite JSON (noise-free data give a zero spread).
    t_statistic = float(np.clip(improvement.mean() / max(spread, 1e-300), -1e9, 1e9))
    total_variance = sum(np.sum((change - change.mean(axis=0)) ** 2) for _, _, change in pixels)
    explained = float(1.0 - squared[best].sum() / total_variance)
    identifiable = bool(best < len(candidates) - 1 and t_statistic >= min_t_statistic
                        and explained >= min_explained)
    estimate = float(candidates[best])
    if 0 < best < len(candidates) - 1:
        estimate = float(np.exp(_parabola_minimum(np.log(candidates[best - 1:best + 2]), rmse[best - 1:best + 2])))
    table = {
        "method": "cross-validated photometric stereo: colour change affine in the ball's unit normal",
        "ball_radius_mm": candidates.tolist(),
        "colour_rmse": rmse.tolist(),
        "lower_bound_mm": lower_bound,
        "best_candidate_mm": float(candidates[best]),
        "t_statistic": t_statistic,
        "explained": explained,
        "identifiable": identifiable,
        "folds": folds,
    }
    return estimate, table


def _candidate_radii(lower_bound: float, candidates_mm=None) -> np.ndarray:
    """The ball radii to try, mm, sorted: those of ``candidates_mm`` above ``lower_bound`` (the
    largest contact radius), or 30 geometrically spaced from 1.01 to 4 times it."""
    if candidates_mm is None:
        return lower_bound * np.geomspace(1.01, 4.0, 30)
    candidates = np.unique(np.asarray(candidates_mm, np.float64).reshape(-1))
    candidates = candidates[np.isfinite(candidates) & (candidates > lower_bound)]
    if len(candidates) == 0:
        raise ValueError(f"no candidate ball radius exceeds the largest contact radius {lower_bound:.4f} mm")
    return candidates


def _contact_pixels(
    presses: BallPresses, index: int, rim_px: float = 0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(dx mm, dy mm, colour change (P, 3)) of the pixels inside one press's contact disc."""
    rho2 = _squared_distance_mm(presses, index)
    inside = rho2 < (max(presses.radii_px[index] - rim_px, 0.0) * presses.mm_per_px) ** 2
    rows, cols = np.nonzero(inside)
    x, y = presses.centers_px[index].astype(np.float64)
    change = presses.images[index][inside].astype(np.float64) / 255.0 - presses.background[inside]
    return (cols - x) * presses.mm_per_px, (rows - y) * presses.mm_per_px, change


def _cross_validated_squares(pixels, radius: float, folds: int) -> np.ndarray:
    """(N,) held-out sum of squared residuals of each press under the affine normal -> colour model."""
    grams, crosses, sums = [], [], []
    for dx, dy, change in pixels:
        normal_z = np.sqrt(np.maximum(radius**2 - dx**2 - dy**2, 0.0))
        features = np.stack([dx / radius, dy / radius, normal_z / radius, np.ones_like(dx)], axis=-1)
        grams.append(features.T @ features)
        crosses.append(features.T @ change)
        sums.append(np.sum(change**2))
    grams, crosses, sums = np.stack(grams), np.stack(crosses), np.asarray(sums)
    fold_of = np.arange(len(pixels)) % folds
    squared = np.zeros(len(pixels))
    for fold in range(folds):
        train = fold_of != fold
        gram = grams[train].sum(axis=0)
        coefficients = np.linalg.solve(gram + 1e-9 * np.trace(gram) * np.eye(4), crosses[train].sum(axis=0))
        for index in np.flatnonzero(~train):
            # |C - F A|^2 from the press's Gram matrices.
            squared[index] = (sums[index] - 2.0 * np.sum(coefficients * crosses[index])
                              + np.sum(coefficients * (grams[index] @ coefficients)))
    return np.maximum(squared, 0.0)


def _parabola_minimum(x: np.ndarray, y: np.ndarray) -> float:
    """Abscissa of the vertex of the parabola through three points (the middle one if flat)."""
    curvature, slope, _ = np.polyfit(x, y, 2)
    if curvature <= 0:
        return float(x[1])
    return float(np.clip(-slope / (2 * curvature), x[0], x[2]))


def fit_sphere_cap(
    heightmap: np.ndarray, center_px, radius_px: float, mm_per_px: float
) -> tuple[float, float, float]:
    """Least-squares spherical cap through a heightmap inside a disc (centre fixed).

    Fits ``h(rho) = apex - (R - sqrt(R^2 - rho^2))`` to the heights of the pixels with
    ``rho < radius``: for a given R the best apex is the mean offset (closed form); R is found
    by a bounded 1-D search on log R (R above the disc radius).

    Args:
        heightmap: (H, W) heights, mm.
        center_px: disc centre (x = column, y = row), pixels.
        radius_px: disc radius, pixels.
        mm_per_px: pixel pitch, mm.

    Returns:
        (sphere radius mm, apex height mm, RMSE of the heights about the cap mm).
    """
    import scipy.optimize

    heightmap = np.asarray(heightmap, np.float64)
    rows, cols = np.indices(heightmap.shape)
    rho2 = ((cols - center_px[0]) ** 2 + (rows - center_px[1]) ** 2) * mm_per_px**2
    inside = rho2 < (radius_px * mm_per_px) ** 2
    if inside.sum() < 3:
        raise ValueError("a sphere cap needs at least 3 pixels inside the disc")
    rho2, heights = rho2[inside], heightmap[inside]
    smallest = np.sqrt(rho2.max()) * (1 + 1e-6)

    def residual(log_radius: float) -> np.ndarray:
        radius = np.exp(log_radius)
        drop = np.sqrt(np.maximum(radius**2 - rho2, 0.0)) - radius
        offsets = heights - drop
        return offsets - offsets.mean()

    def cost(log_radius: float) -> float:
        return float(np.mean(residual(log_radius) ** 2))

    grid = np.log(smallest) + np.linspace(0.0, np.log(1e3), 61)
    costs = [cost(t) for t in grid]
    best = int(np.argmin(costs))
    low, high = grid[max(best - 1, 0)], grid[min(best + 1, len(grid) - 1)]
    result = scipy.optimize.minimize_scalar(cost, bounds=(low, high), method="bounded",
                                            options={"xatol": 1e-6})
    log_radius = result.x if result.fun <= costs[best] else grid[best]
    radius = float(np.exp(log_radius))
    drop = np.sqrt(np.maximum(radius**2 - rho2, 0.0)) - radius
    apex = float(np.mean(heights - drop))
    return radius, apex, float(np.sqrt(cost(log_radius)))


PRESS_METRICS = ("contact_radius_mm", "ideal_depth_mm", "depth_mm", "fitted_radius_mm", "fitted_radius_error",
                 "fitted_apex_mm", "cap_residual_rmse_mm", "ideal_cap_rmse_mm", "mask_iou")
"""Per-press entries of :func:`evaluate_ball_fit`, in table order."""


def evaluate_ball_fit(
    model,
    presses: BallPresses,
    ball_radius_mm: float,
    *,
    press_ids=None,
) -> dict:
    """How well a calibrated model reconstructs ball presses it was not fitted to.

    Each press is reconstructed with :func:`predict`; a spherical cap is fitted to the
    reconstructed heights inside the annotated disc (:func:`fit_sphere_cap`). A good model
    gives back a cap of the ball's radius with a small residual, matches the ideal cap and
    finds the disc as its contact mask. Note that a model calibrated with a wrong radius R'
    gives back caps of radius about R' (the self-consistency of :func:`estimate_ball_radius`),
    so this checks the reconstruction, not the radius given to the calibration.

    Args:
        model: a calibrated :class:`ShapeModel` for these presses' sensor.
        presses: held-out presses.
        ball_radius_mm: R, mm.
        press_ids: (N,) labels of the presses in the report (default 0..N-1).

    Returns:
        ``{"ball_radius_mm", "count", "presses": [per press: "press" and PRESS_METRICS],
        "mean": {metric: value}, "std": {metric: value}}``; lengths in mm, ``mask_iou`` of the
        predicted contact mask with the disc, ``fitted_radius_error`` relative to R.
    """
    from tactojax.shape._metrics import batch_heightmap_errors
    from tactojax.shape._predict import check_image

    check_image(model, presses.images[:1])
    if not np.isclose(model.mm_per_px, presses.mm_per_px, rtol=1e-4):
        raise ValueError(f"the model is for {model.mm_per_px} mm/px but the presses are {presses.mm_per_px} mm/px")
    truth = ball_press_data(presses, ball_radius_mm)
    radius = float(ball_radius_mm)
    press_ids = np.arange(len(presses)) if press_ids is None else np.asarray(press_ids)
    heights, masks = _reconstruct(model, presses)
    errors = batch_heightmap_errors(heights, masks, truth.heightmaps, truth.masks)
    rows = []
    for index, heightmap in enumerate(heights):
        contact = float(presses.contact_radii_mm[index])
        fitted, apex, residual = fit_sphere_cap(heightmap, presses.centers_px[index],
                                                float(presses.radii_px[index]), presses.mm_per_px)
        rows.append({
            "press": int(press_ids[index]),
            "contact_radius_mm": contact,
            "ideal_depth_mm": float(radius - np.sqrt(radius**2 - contact**2)),
            "depth_mm": float(heightmap[truth.masks[index]].max()),
            "fitted_radius_mm": fitted,
            "fitted_radius_error": fitted / radius - 1.0,
            "fitted_apex_mm": apex,
            "cap_residual_rmse_mm": residual,
            "ideal_cap_rmse_mm": float(errors["patch_rmse"][index]),
            "mask_iou": float(errors["mask_iou"][index]),
        })
    values = {name: np.array([row[name] for row in rows]) for name in PRESS_METRICS}
    return {
        "ball_radius_mm": radius,
        "count": len(rows),
        "presses": rows,
        "mean": {name: float(v.mean()) for name, v in values.items()},
        "std": {name: float(v.std()) for name, v in values.items()},
    }


def _reconstruct(model, presses: BallPresses) -> tuple[np.ndarray, np.ndarray]:
    """(N, H, W) heightmaps (mm) and contact masks of the presses, one compiled ``predict``."""
    from tactojax.shape._predict import predict

    outputs = [predict(model, image.astype(np.float32) / 255.0) for image in presses.images]
    return np.stack([np.asarray(h) for h, _ in outputs]), np.stack([np.asarray(m) for _, m in outputs])


def best_mask_threshold(
    heights: np.ndarray, masks: np.ndarray, thresholds: np.ndarray
) -> tuple[float, np.ndarray]:
    """The height threshold whose contact masks ``heights > t`` best match ``masks`` (mean IoU).

    Every threshold is scored at once: per image, the pixels above t are counted from the
    sorted heights (all pixels, and those inside the true mask).

    Args:
        heights: (N, H, W) reconstructed heights, mm.
        masks: (N, H, W) true contact masks.
        thresholds: (T,) candidate thresholds, mm.

    Returns:
        (best threshold mm, (T,) mean IoU per threshold).
    """
    thresholds = np.asarray(thresholds, np.float64)
    ious = np.zeros((len(heights), len(thresholds)))
    for index, (heightmap, mask) in enumerate(zip(heights, masks)):
        above = heightmap.size - np.searchsorted(np.sort(heightmap, axis=None), thresholds, side="right")
        true_count = int(mask.sum())
        hits = true_count - np.searchsorted(np.sort(heightmap[mask]), thresholds, side="right")
        union = above + true_count - hits
        ious[index] = np.where(union > 0, hits / np.maximum(union, 1), 1.0)
    mean = ious.mean(axis=0)
    return float(thresholds[int(np.argmax(mean))]), mean


def split_presses(count: int, held_out_fraction: float) -> tuple[np.ndarray, np.ndarray]:
    """(train, held-out) press indices, deterministic and evenly spread.

    Press i is held out when ``floor((i + 1) f) > floor(i f)``: every 4th press for f = 0.25.
    """
    if not 0 < held_out_fraction < 1:
        raise ValueError(f"held-out fraction must be in (0, 1), got {held_out_fraction}")
    index = np.arange(count)
    held_out = np.floor((index + 1) * held_out_fraction + 1e-9) > np.floor(index * held_out_fraction + 1e-9)
    if held_out.all() or not held_out.any():
        raise ValueError(f"{count} presses with held-out fraction {held_out_fraction} leave "
                         f"{int((~held_out).sum())} to fit and {int(held_out.sum())} to evaluate; need at least 1 each")
    return index[~held_out], index[held_out]


class BallRadiusNotIdentifiableError(ValueError):
    """The presses cannot tell the ball radius (see :func:`estimate_ball_radius`); ``table`` says why."""

    def __init__(self, message: str, table: dict):
        super().__init__(message)
        self.table = table


def calibrate_from_presses(
    presses: BallPresses,
    ball_radius_mm: float | None = None,
    *,
    held_out_fraction: float = 0.25,
    bins: int = 24,
    candidates_mm=None,
    threshold_presses: int = 8,
):
    """Fit the classical lookup model of a sensor from ball presses and test it on held-out ones.

    Presses are split by :func:`split_presses`; the ball radius is estimated from the
    training presses by :func:`estimate_ball_radius` when not given; :func:`fit_lookup_model`
    is fitted to :func:`ball_press_data` of the training presses with the captured
    background; its contact threshold is picked by :func:`fit_mask_threshold` on
    ``threshold_presses`` training presses, over the whole range of reconstructed heights (a
    real gel sinks around the ball, so the disc edge sits well above zero height).
    :func:`evaluate_ball_fit` reports on the held-out presses.

    Args:
        presses: annotated presses (at least 2).
        ball_radius_mm: measured ball radius, mm, or None to estimate it.
        held_out_fraction: fraction of presses kept for evaluation, in (0, 1).
        bins: lookup-table bins per colour channel.
        candidates_mm: radii tried when estimating (see :func:`estimate_ball_radius`).
        threshold_presses: training presses reconstructed to pick the contact threshold.

    Returns:
        (:class:`ShapeModel` with preset ``lookup``, report dict: ``ball_radius_mm``,
        ``ball_radius_estimated``, ``radius_estimate`` (the estimator's table or None),
        ``presses``, ``train_presses``, ``held_out_presses``, ``bins``, ``mask_threshold_mm``,
        ``train_mask_iou`` and ``held_out`` from :func:`evaluate_ball_fit`).

    Raises:
        BallRadiusNotIdentifiableError: no radius given and the presses cannot tell it.
    """
    from tactojax.shape._lookup import fit_lookup_model, fit_mask_threshold

    train_ids, held_out_ids = split_presses(len(presses), held_out_fraction)
    train = presses.take(train_ids)
    estimate_table = None
    if ball_radius_mm is None:
        ball_radius_mm, estimate_table = estimate_ball_radius(train, candidates_mm)
        if not estimate_table["identifiable"]:
            raise BallRadiusNotIdentifiableError(
                "the ball radius cannot be estimated from these presses (best candidate "
                f"{estimate_table['best_candidate_mm']:.3f} mm, consistency t = {estimate_table['t_statistic']:.1f}, "
                f"colour explained {100 * estimate_table['explained']:.1f} %); they only bound it below by "
                f"the largest contact radius, {estimate_table['lower_bound_mm']:.4f} mm. Measure the ball "
                "and give its radius", estimate_table)
    radius = _check_ball_radius(presses, ball_radius_mm)
    train_data = ball_press_data(train, radius)
    model = fit_lookup_model(train_data, background=presses.background, bins=bins, threshold_pairs=0)
    model, train_mask_iou = fit_mask_threshold(model, train_data, max_pairs=threshold_presses)
    threshold = float(model.params["mask_threshold_mm"])
    evaluation = evaluate_ball_fit(model, presses.take(held_out_ids), radius, press_ids=held_out_ids)
    report = {
        "ball_radius_mm": radius,
        "ball_radius_estimated": estimate_table is not None,
        "radius_estimate": estimate_table,
        "presses": len(presses),
        "train_presses": train_ids.tolist(),
        "held_out_presses": held_out_ids.tolist(),
        "bins": int(bins),
        "mask_threshold_mm": threshold,
        "train_mask_iou": train_mask_iou,
        "held_out": evaluation,
    }
    return model, report
