"""Simulation: the capture model (eq. 2, 3, 5), ground truth, the gantry and sample-run recipes.

Only tests, benchmarks, the sample data and the ``simulate`` node use this stage; no pipeline
stage (calibration, reconstruction, evaluation) imports it.
"""

from .assembly import Gantry, simulate_run
from .camera_model import RGBCamera, SpectralCamera, capture, response_model
from .exposure_plan import exposure_plan
from .ground_truth import spectral_scene
from .recipes import RECIPES, GantryRecipe, get_recipe

__all__ = [
    "RGBCamera",
    "SpectralCamera",
    "capture",
    "response_model",
    "exposure_plan",
    "Gantry",
    "GantryRecipe",
    "simulate_run",
    "spectral_scene",
    "RECIPES",
    "get_recipe",
]
