"""Sensor: specs and presets, the contact model and the optics (pure JAX apart from presets)."""

from tactojax.sensor._augment import augment_colors as augment_colors
from tactojax.sensor._contact import Contact as Contact
from tactojax.sensor._contact import gel_surface as gel_surface
from tactojax.sensor._contact import press as press
from tactojax.sensor._imprint import Imprint as Imprint
from tactojax.sensor._optics import add_sensor_noise as add_sensor_noise
from tactojax.sensor._optics import render_image as render_image
from tactojax.sensor._presets import SENSOR_PRESETS as SENSOR_PRESETS
from tactojax.sensor._presets import gelsight as gelsight
from tactojax.sensor._presets import gelsight_mini as gelsight_mini
from tactojax.sensor._presets import gelslim as gelslim
from tactojax.sensor._presets import sensor_preset as sensor_preset
from tactojax.sensor._smoothing import gaussian_blur as gaussian_blur
from tactojax.sensor._spec import PhotometricOptics as PhotometricOptics
from tactojax.sensor._spec import PolynomialTableOptics as PolynomialTableOptics
from tactojax.sensor._spec import SensorSpec as SensorSpec

__all__ = [
    "SENSOR_PRESETS",
    "Contact",
    "Imprint",
    "PhotometricOptics",
    "PolynomialTableOptics",
    "SensorSpec",
    "add_sensor_noise",
    "augment_colors",
    "gaussian_blur",
    "gel_surface",
    "gelsight",
    "gelsight_mini",
    "gelslim",
    "press",
    "render_image",
    "sensor_preset",
]
