"""The peer pipeline for the whole-touch benchmark: what a user would deploy without JAX.

The same two networks, exported once to ONNX (``jax2onnx``) and run by ONNX Runtime on the CPU;
the steps around them in NumPy, SciPy and OpenCV; registration with Open3D's point-to-plane ICP:

1. heightmap: the shape model's slope network (ONNX Runtime), Poisson integration with SciPy's
   DCT, the background quantile and the contact threshold in NumPy;
2. features: OpenCV resize to the encoder's input, normalisation in NumPy, the encoder (ONNX
   Runtime). EfficientNet's depthwise convolutions are exported as grouped convolutions
   (``EfficientNetLite(grouped_depthwise=True)``), the graph a PyTorch export gives (tactojax
   computes them as fused shifted products instead, which XLA runs faster but ONNX Runtime 3-4x
   slower);
3. identification and CTI retrieval: cosine similarities and the opening filter in NumPy;
4. registration: Open3D ICP of the touch's contact points against the N retrieved imprints'
   clouds, started at the most similar one (as ``benchmarks/localization.py``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import scipy.fft

from tactojax.features import EfficientNetLite
from tactojax.shape import build_network, network_input, pixel_patches


def unit_rows(features):
    """Rows scaled to unit L2 norm, as the encoder's features are (an all-zero row stays zero)."""
    return features / jnp.maximum(jnp.linalg.norm(features, axis=-1, keepdims=True), 1e-12)


def onnx_session(function, example: np.ndarray, threads: int):
    """Export ``function`` of one float32 array to ONNX and open it in ONNX Runtime (CPU)."""
    import onnxruntime
    from jax2onnx import to_onnx

    proto = to_onnx(function, [jax.ShapeDtypeStruct(example.shape, jnp.float32)])
    options = onnxruntime.SessionOptions()
    options.intra_op_num_threads = threads
    options.log_severity_level = 3  # jax2onnx's NHWC transposes make shape-merge warnings
    # Idle threads sleep instead of spinning, so the NumPy and Open3D steps between the two
    # networks get the cores (spinning made them 10-20x slower on 2 cores).
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    session = onnxruntime.InferenceSession(proto.SerializeToString(), options, providers=["CPUExecutionProvider"])
    name = session.get_inputs()[0].name
    return lambda x: session.run(None, {name: x})


def integrate_gradient(slope: np.ndarray, mm_per_px: float) -> np.ndarray:
    """Least-squares integration of an (H, W, 2) slope field with SciPy's DCT (zero mean), mm."""
    height, width = slope.shape[:2]
    step_x = 0.5 * (slope[:, 1:, 0] + slope[:, :-1, 0]) * mm_per_px
    step_y = 0.5 * (slope[1:, :, 1] + slope[:-1, :, 1]) * mm_per_px
    rhs = (np.pad(step_x, ((0, 0), (1, 0))) - np.pad(step_x, ((0, 0), (0, 1)))
           + np.pad(step_y, ((1, 0), (0, 0))) - np.pad(step_y, ((0, 1), (0, 0))))
    eigenvalues = (4.0 * np.sin(np.pi * np.arange(height) / (2 * height))[:, None] ** 2
                   + 4.0 * np.sin(np.pi * np.arange(width) / (2 * width))[None, :] ** 2)
    coefficients = scipy.fft.dctn(rhs, type=2, norm="ortho")
    coefficients = np.where(eigenvalues > 0, coefficients / np.where(eigenvalues > 0, eigenvalues, 1.0), 0.0)
    return scipy.fft.idctn(coefficients, type=2, norm="ortho")


@dataclass
class PeerTimes:
    """Seconds per stage of one touch."""

    heightmap: float
    features: float
    retrieval: float
    registration: float

    @property
    def total(self) -> float:
        return self.heightmap + self.features + self.retrieval + self.registration


class PeerPipeline:
    """ONNX Runtime networks + NumPy/SciPy/OpenCV + Open3D ICP, for one map (see the module docstring).

    Args:
        model: the tactojax shape model (preset ``fast``: a slope network).
        encoder: the tactojax feature encoder.
        tactile_map: the object's map (features filled by ``encoder``).
        n: N of CTI-ICP-N.
        points: contact points per touch for ICP.
        threads: ONNX Runtime's intra-op threads.
    """

    def __init__(self, model, encoder, tactile_map, *, n: int, points: int, max_distance_mm: float,
                 iterations: int, max_opening_difference_mm: float, threads: int):
        import open3d

        self.o3d = open3d
        network = build_network(model.preset, model.mm_per_px)
        if not hasattr(network, "slope"):
            raise ValueError(f"the peer pipeline runs slope-network shape models, not {model.preset!r}")
        self.model, self.encoder = model, encoder
        height, width = model.image_shape
        self.background = np.asarray(model.background, np.float32)
        example = np.asarray(network_input(jnp.zeros((height, width, 3)), model.background, model.preset,
                                           model.color_gain))
        self.coordinates = example[..., 3:]
        self.slope = onnx_session(lambda x: network.apply({"params": model.params}, pixel_patches(x),
                                                          method=network.slope), example, threads)
        module = encoder.module
        if isinstance(module, EfficientNetLite):
            module = module.clone(grouped_depthwise=True)
        self.features = onnx_session(lambda x: unit_rows(module.apply(encoder.variables, x)),
                                     np.zeros((1, *encoder.input_size, 3), np.float32), threads)
        self.mean, self.std = np.asarray(encoder.mean, np.float32), np.asarray(encoder.std, np.float32)
        self.encoder_background = None if encoder.background is None else np.asarray(encoder.background, np.float32)
        self.map_features = np.asarray(tactile_map.features, np.float32)
        self.openings = np.asarray(tactile_map.openings, np.float32)
        self.imprint_valid = np.asarray(tactile_map.imprint_valid)
        self.points_object = np.asarray(tactile_map.points_object)
        self.normals_object = np.asarray(tactile_map.normals_object)
        self.point_valid = np.asarray(tactile_map.point_valid)
        self.T_object_sensor = np.asarray(tactile_map.T_object_sensor.as_matrix())
        self.n, self.points, self.max_distance_mm, self.iterations = n, points, max_distance_mm, iterations
        self.max_opening_difference_mm = max_opening_difference_mm
        rows, cols = np.mgrid[0:height, 0:width]
        self.pixel_x = (cols - (width - 1) / 2.0) * model.mm_per_px
        self.pixel_y = (rows - (height - 1) / 2.0) * model.mm_per_px
        self.order = np.random.default_rng(0).permutation(height * width)

    def heightmap(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(H, W, 3) uint8 -> heightmap (H, W) mm and contact mask."""
        color = self.model.color_gain * (image.astype(np.float32) / 255.0 - self.background)
        (slope,) = self.slope(np.concatenate([color, self.coordinates], axis=-1))
        heightmap = integrate_gradient(slope, self.model.mm_per_px)
        heightmap -= np.quantile(heightmap, 0.1)
        return np.maximum(heightmap, 0.0), heightmap > float(self.model.params["mask_threshold_mm"])

    def feature(self, image: np.ndarray) -> np.ndarray:
        """(H, W, 3) uint8 -> unit feature (F,)."""
        height, width = self.encoder.input_size
        x = cv2.resize(image, (width, height), interpolation=cv2.INTER_LINEAR).astype(np.float32) / 255.0
        if self.encoder_background is not None:
            x = x - self.encoder_background
        (feature,) = self.features(((x - self.mean) / self.std)[None])
        return feature[0]

    def retrieve(self, feature: np.ndarray, opening: float) -> np.ndarray:
        """The N most similar eligible imprints (indices)."""
        similarities = self.map_features @ feature
        eligible = self.imprint_valid & (np.abs(self.openings - opening) < self.max_opening_difference_mm)
        ranked = np.argsort(-np.where(eligible, similarities, -np.inf))[:self.n]
        return ranked[eligible[ranked]]

    def register(self, heightmap: np.ndarray, mask: np.ndarray, retrieved: np.ndarray) -> np.ndarray:
        """Open3D ICP of the touch's contact points from the first retrieved imprint; (4, 4) pose."""
        flat = np.flatnonzero(mask.reshape(-1)[self.order])
        pixels = self.order[flat[:self.points]]
        source_points = np.stack([self.pixel_x.reshape(-1)[pixels], self.pixel_y.reshape(-1)[pixels],
                                  -heightmap.reshape(-1)[pixels]], axis=-1)
        valid = self.point_valid[retrieved].reshape(-1)
        o3d = self.o3d
        source = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(source_points.astype(np.float64)))
        target = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(
            self.points_object[retrieved].reshape(-1, 3)[valid].astype(np.float64)))
        target.normals = o3d.utility.Vector3dVector(self.normals_object[retrieved].reshape(-1, 3)[valid]
                                                    .astype(np.float64))
        result = o3d.pipelines.registration.registration_icp(
            source, target, self.max_distance_mm, self.T_object_sensor[retrieved[0]],
            o3d.pipelines.registration.TransformationEstimationPointToPlane(),
            o3d.pipelines.registration.ICPConvergenceCriteria(max_iteration=self.iterations))
        return result.transformation

    def __call__(self, image: np.ndarray, opening: float) -> tuple[np.ndarray | None, PeerTimes]:
        """One touch: the (4, 4) sensor pose in the object frame (None: no contact or no imprint), times."""
        t0 = time.perf_counter()
        heightmap, mask = self.heightmap(image)
        t1 = time.perf_counter()
        feature = self.feature(image)
        t2 = time.perf_counter()
        retrieved = self.retrieve(feature, opening)
        t3 = time.perf_counter()
        pose = None
        if mask.any() and len(retrieved):
            pose = self.register(heightmap, mask, retrieved)
        t4 = time.perf_counter()
        return pose, PeerTimes(t1 - t0, t2 - t1, t3 - t2, t4 - t3)
