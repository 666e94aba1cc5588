"""helicalib: closed-loop calibration controller for heliostat fields of solar tower plants."""

from helicalib.errors import ConfigError, GeometryError, HelicalibError, MeasurementError, PlantError

__version__ = "0.1.0"

__all__ = [
    "ConfigError",
    "GeometryError",
    "HelicalibError",
    "MeasurementError",
    "PlantError",
    "__version__",
]
