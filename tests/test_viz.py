"""tactojax.viz: figures are plain matplotlib Figures that leave the caller's backend alone."""

import subprocess
import sys

import numpy as np
from matplotlib.figure import Figure

from tactojax.viz import (
    confusion_figure,
    localization_histogram_figure,
    map_size_figure,
    save_png,
)


def test_importing_viz_keeps_the_backend_a_notebook_chose():
    code = ("import matplotlib; matplotlib.use('svg'); import tactojax.viz; "
            "tactojax.viz.confusion_figure([[1, 0], [0, 1]], ['a', 'b']); print(matplotlib.get_backend())")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "svg"


def test_histogram_panels_bin_every_touch_and_save_a_png(tmp_path):
    errors = {"a": {"cti": [1.0, 3.0, 200.0], "random": [50.0, 60.0]}, "b": {"cti": [7.0]}}
    figure = localization_histogram_figure(errors, max_mm=80.0, bin_mm=5.0)
    assert isinstance(figure, Figure)
    axes = [axis for axis in figure.axes if axis.get_visible() and axis.axison]
    assert [axis.get_title() for axis in axes] == ["a", "b"]
    for axis, name in zip(axes, errors):
        for patch, rmse in zip(axis.patches, errors[name].values()):  # one step outline per method
            heights = np.diff(patch.get_xy()[:, 1])
            assert np.isclose(np.abs(heights).sum() / 2, 100.0)  # percentages of touches sum to 100
    path = save_png(figure, tmp_path / "out" / "histogram.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_confusion_labels_are_row_percentages():
    figure = confusion_figure(np.array([[3, 1], [0, 2]]), ["a", "b"])
    texts = [text.get_text() for text in figure.axes[0].texts]
    assert texts == ["75", "25", "0", "100"]


def test_map_size_figure_draws_one_curve_per_method():
    results = {"a": {0.5: {"cti": 10.0, "cti-icp-5": 8.0}, 1.0: {"cti": 5.0, "cti-icp-5": 4.0}}}
    axis = map_size_figure(results).axes[0]
    assert [line.get_label() for line in axis.lines] == ["cti", "cti-icp-5"]
    np.testing.assert_allclose(axis.lines[1].get_xydata(), [[50.0, 8.0], [100.0, 4.0]])


def test_map_figure_shows_a_thin_object_at_true_scale_along_its_thinnest_axis(tmp_path):
    from tactojax.viz import tactile_map_figure
    from tactojax.viz._map import _map_figure

    # Scissors-like cloud: 200 mm along x, 14 mm along y (the closing axis), 90 mm along z.
    points = np.random.default_rng(0).uniform([-100, -7, -45], [100, 7, 45], (4000, 3))
    oblique, projection = _map_figure(points, title="", examples=None, mm_per_px=0.2).axes[:2]
    assert projection.name == "rectilinear" and projection.get_aspect() == 1.0  # mm on both axes alike
    assert (projection.get_xlabel(), projection.get_ylabel()) == ("x (mm)", "z (mm)")
    assert projection.get_title().startswith("seen from -y")
    np.testing.assert_allclose(projection.collections[0].get_offsets(), points[np.argsort(-points[:, 1])][:, [0, 2]])
    assert list(oblique.get_yticks()) == [] and oblique.get_ylabel() == "y: -7 to 7 mm"  # too thin for ticks
    assert len(oblique.get_xticks()) >= 3
    path = tactile_map_figure(points, tmp_path / "map.png", title="thin")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_belief_figure_shows_each_objects_hypotheses_and_the_calibration_curves(tmp_path):
    from tactojax.viz import belief_figure

    rng = np.random.default_rng(0)
    points = rng.uniform([-50, -5, -20], [50, 5, 20], (500, 3))  # thinnest along y: seen from y
    after = {k: {"positions": np.array([[1.0, 0.0, 2.0], [30.0, 0.0, -5.0], [0.0, 0.0, 0.0]]),
                 "probabilities": np.array([0.7, 0.3, 0.0]), "error_mm": 0.5 * k, "within": 0.7}
             for k in (1, 3)}
    examples = {"a": {"points": points, "true": np.array([1.0, 0.0, 2.0]), "after": after},
                "b": {"points": points, "true": np.array([0.0, 0.0, 0.0]), "after": after}}
    curves = {"a": {"grasps": [1, 2, 3], "observed": [0.5, 0.75, 1.0], "predicted": [0.4, 0.8, 0.9]},
              "b": {"grasps": [1, 2, 3], "observed": [0.25, 0.5, 0.5], "predicted": [0.3, 0.6, 0.7]}}
    figure = belief_figure(examples, curves)
    titles = [axis.get_title() for axis in figure.axes]
    assert titles[:4] == ["a, after 1 grasp\nP(within 2 mm) 0.70, error 0.5 mm",
                          "a, after 3 grasps\nP(within 2 mm) 0.70, error 1.5 mm",
                          "b, after 1 grasp\nP(within 2 mm) 0.70, error 0.5 mm",
                          "b, after 3 grasps\nP(within 2 mm) 0.70, error 1.5 mm"]
    panel = figure.axes[0]
    assert (panel.get_xlabel(), panel.get_ylabel()) == ("x (mm)", "z (mm)")
    hypotheses = panel.collections[1]  # map points, then the hypotheses with any probability, then the truth
    np.testing.assert_allclose(hypotheses.get_offsets(), [[30.0, -5.0], [1.0, 2.0]])  # the most probable on top
    curve_axis = figure.axes[-1]
    assert curve_axis.get_xlabel() == "grasps fused (both fingers)"
    assert [line.get_label() for line in curve_axis.lines] == ["a: observed", "a: predicted", "b: observed",
                                                               "b: predicted"]
    np.testing.assert_allclose(curve_axis.lines[1].get_xydata(), [[1, 0.4], [2, 0.8], [3, 0.9]])
    assert save_png(figure, tmp_path / "belief.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
