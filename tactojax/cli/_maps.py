"""Loading tactile maps for the localization commands, with their feature vectors."""

from __future__ import annotations

from tactojax.io import DEFAULT_ENCODER, maps_encoder_name


def add_encoder_argument(parser) -> None:
    parser.add_argument("--encoder", default=None,
                        help="feature encoder: bundled:NAME or a checkpoint path; default: the features "
                             f"stored in the maps, else {DEFAULT_ENCODER}")


def load_maps_with_features(paths, encoder_name: str | None, *, progress: bool = True):
    """The maps at ``paths`` with the retrieval features of one encoder (:func:`maps_encoder_name`;
    :func:`~tactojax.io.load_tactile_map_with_features`).

    Returns:
        (maps, name): the maps, and the encoder's name (``encoder_label``).
    """
    from tactojax.io import load_tactile_map_with_features

    name = maps_encoder_name(paths, encoder_name)
    maps = [load_tactile_map_with_features(path, name, progress=progress) for path in paths]
    names = [m.object_id for m in maps]
    if len(set(names)) != len(names):
        raise ValueError(f"two maps of the same object: {names}")
    return maps, name


def maps_and_query_encoder(paths, encoder_name: str | None, *, progress: bool = True):
    """The maps with features (:func:`load_maps_with_features`), and the encoder of those
    features for new touches; raises a clear error when its features do not fit the maps."""
    from tactojax.io import resolve_encoder

    maps, name = load_maps_with_features(paths, encoder_name, progress=progress)
    encoder = resolve_encoder(name)
    if encoder.feature_dim != maps[0].features.shape[1]:
        raise ValueError(f"the maps store {maps[0].features.shape[1]}-long features but the encoder gives "
                         f"{encoder.feature_dim}: pass the encoder that built them with --encoder")
    return maps, encoder


def camera_source(text: str) -> int | str:
    """A ``--camera`` argument: a device index (digits) or a file path / stream URL."""
    return int(text) if text.isdigit() else text


def stored_calibration(path, encoder_name: str | None):
    """The belief calibration a map's header stores (``tactojax calibrate-belief``), or None
    (uncalibrated: said on stderr) when it has none or it was fit with another encoder."""
    import sys

    from tactojax.io import encoder_label, tactile_map_metadata
    from tactojax.localize import calibration_from_json

    encoder_name = maps_encoder_name([path], encoder_name)
    fit = tactile_map_metadata(path).get("metadata", {}).get("belief_calibration")
    if fit is None:
        print(f"note: {path} holds no belief calibration (run `tactojax calibrate-belief`): the belief runs with "
              "the default scales (the catalog objects' median fit), its P(within 2 mm) not fit to this object",
              file=sys.stderr)
        return None
    if encoder_label(fit.get("encoder", DEFAULT_ENCODER)) != encoder_name:
        print(f"note: {path}'s belief calibration was fit with the encoder {fit.get('encoder')!r}, not "
              f"{encoder_name!r}: not used", file=sys.stderr)
        return None
    return calibration_from_json(fit)


def stacked_localization_maps(paths, maps, encoder_name: str | None, *, shared: bool = True):
    """Each map's :class:`~tactojax.localize.LocalizationMap` with the belief calibration and the
    surface its file stores (:func:`stored_calibration`, :func:`~tactojax.io.stored_surface`); with ``shared`` and several maps, all under their median
    (:func:`~tactojax.localize.shared_calibration`), so that their evidences compare (P(object));
    stacked into one structure (:class:`~tactojax.localize.StackedMaps`: one compiled program for
    every map, no map padded to the largest).

    Returns:
        (stack, calibrated): the maps, and whether any map holds a calibration.
    """
    from tactojax.io import stored_surface
    from tactojax.localize import LocalizationMap, StackedMaps, shared_calibration

    calibrations = [stored_calibration(path, encoder_name) for path in paths]
    calibrated = any(c is not None for c in calibrations)
    if shared and len(maps) > 1:
        calibrations = [shared_calibration(calibrations)] * len(maps)
    views = [LocalizationMap.from_tactile_map(m, calibration=c, surface=stored_surface(path))
             for path, m, c in zip(paths, maps, calibrations)]
    return StackedMaps.from_maps(views), calibrated


def is_symmetric(tactile_map) -> bool:
    """Whether the map's object has a symmetry beyond the identity (a continuous axis, n-fold
    turns or flips: :attr:`~tactojax.mapping.TactileMap.object_symmetry`)."""
    return tactile_map.object_symmetry.symmetric


def histogram_panel(tactile_map, results: dict) -> tuple[str, dict]:
    """One panel of the localization histogram: ``(title, {method: per-query RMSE, mm})``.

    A symmetric object's plain RMSE mostly measures which symmetric copy was picked, so its
    panel shows the symmetry-aware RMSE, and says so.
    """
    object_id = tactile_map.object_id
    if is_symmetric(tactile_map):
        return f"{object_id} (symmetry-aware)", {name: r.symmetric_rmse for name, r in results.items()}
    return object_id, {name: r.rmse for name, r in results.items()}
