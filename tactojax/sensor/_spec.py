"""SensorSpec: everything about a tactile sensor that the simulator and the models need."""

from __future__ import annotations

from jaxtyping import Array, Float

from tactojax import _struct as struct


@struct.dataclass
class PhotometricOptics:
    """Parametric GelSlim-style optics: coloured directional lights on the gel's normals.

    The camera looks at the back of the reflective gel membrane (from -z). Light k arrives from
    the unit direction ``light_directions[k]`` (sensor frame, pointing from the membrane towards
    the light, so z < 0) and adds ``light_colors[k] * gain * (n . l_k - n_flat . l_k)`` to the
    background, where n is the membrane normal facing the camera. ``vignetting`` scales that
    signal down towards the image border, as the LEDs' light falls off.
    """

    background: Float[Array, "H W 3"]
    """Image of the undeformed gel, RGB in [0, 1]."""
    vignetting: Float[Array, "H W"]
    """Per-pixel gain of the shading signal, in [0, 1]."""
    light_directions: Float[Array, "K 3"]
    """Unit vectors towards each light, sensor frame."""
    light_colors: Float[Array, "K 3"]
    """RGB colour of each light, in [0, 1]."""
    gain: float = struct.field(pytree_node=False, default=1.0)


@struct.dataclass
class PolynomialTableOptics:
    """Calibrated GelSight optics (Taxim-style polynomial colour table).

    For a membrane slope of magnitude ``atan(|grad h|)`` in [0, pi/2] and direction
    ``atan2(dh/dy, dh/dx)`` in [-pi, pi], ``table[i_mag, i_dir]`` holds per-channel coefficients of
    a quadratic polynomial in the full-resolution pixel position (x^2, y^2, x*y, x, y, 1) that
    gives the colour change against the background. Bins are looked up bilinearly, so the
    rendering is differentiable in the heightmap.
    """

    background: Float[Array, "H W 3"]
    """Real background frame of the undeformed gel, RGB in [0, 1]."""
    table: Float[Array, "B B 6 3"]
    """Polynomial coefficients per (slope magnitude bin, slope direction bin), RGB, per unit [0, 1]."""
    calibration_height_px: int = struct.field(pytree_node=False, default=480)
    """Image rows of the calibration frames, for the polynomial's pixel coordinates."""
    calibration_width_px: int = struct.field(pytree_node=False, default=640)


@struct.dataclass
class SensorSpec:
    """A camera-based tactile sensor, static geometry plus optics arrays (a pytree).

    Geometry fields are static (hashable, part of the jit cache key); the optics' arrays are
    pytree leaves, so a spec can be passed straight into jitted functions.
    """

    name: str = struct.field(pytree_node=False)
    height_px: int = struct.field(pytree_node=False)
    """Image rows H."""
    width_px: int = struct.field(pytree_node=False)
    """Image columns W."""
    mm_per_px: float = struct.field(pytree_node=False)
    """Pixel pitch on the gel surface of the rectified (orthographic) image, mm."""
    gel_thickness_mm: float = struct.field(pytree_node=False)
    """Elastomer thickness, mm. Indentations deeper than this are not physical."""
    gel_smoothing_mm: float = struct.field(pytree_node=False)
    """Standard deviation of the gel's elastic smoothing kernel, mm (see ``press``)."""
    noise_std: float = struct.field(pytree_node=False)
    """Standard deviation of the camera's additive pixel noise, in [0, 1] intensity units."""
    optics: PhotometricOptics | PolynomialTableOptics

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of the tactile image and heightmap."""
        return (self.height_px, self.width_px)

    @property
    def field_of_view_mm(self) -> tuple[float, float]:
        """(width, height) of the imaged gel area, mm."""
        return (self.width_px * self.mm_per_px, self.height_px * self.mm_per_px)
