"""Scenario files of the simulated plant: weather, soiling, hidden errors, optics, camera, faults.

A scenario is a YAML mapping; every section and key is optional (defaults below = a clear,
calm spring week with moderate errors). Unknown keys and bad values are refused with the key
path, like the field config. ``docs/simulator.md`` lists every key with its unit.
"""

from __future__ import annotations

from pathlib import Path
from datetime import datetime, timezone
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, BaseModel, BeforeValidator, ConfigDict, Field, ValidationError, field_validator, model_validator

from helicalib.config import read_yaml, validation_error


def _iso(value: Any) -> Any:
    """YAML turns unquoted times into datetimes (naive = UTC, as YAML says); keep ISO strings."""
    if isinstance(value, datetime):
        return (value if value.tzinfo else value.replace(tzinfo=timezone.utc)).isoformat()
    return value


def _instant(value: str) -> str:
    """An ISO 8601 instant with an offset (as the CLI's ``--start``), kept as the string given."""
    from helicalib.errors import HelicalibError
    from helicalib.geometry.sun import parse_time

    try:
        year = parse_time(value).year
    except HelicalibError as err:
        raise ValueError(str(err)) from None
    if not 1678 <= year <= 2261:  # pandas' nanosecond range, which the clocks and the sun code use
        raise ValueError(f"time {value!r}: expected a year in 1678..2261")
    return value


Time = Annotated[str, BeforeValidator(_iso), AfterValidator(_instant)]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class Wind(_Model):
    mean_ms: float = Field(default=3.0, ge=0)
    diurnal_amplitude_ms: float = Field(default=1.5, ge=0)   # extra wind at 15:00 local solar time
    variability_ms: float = Field(default=1.0, ge=0)        # std of the slow fluctuation
    correlation_h: float = Field(default=1.0, gt=0)
    direction_deg: float = 300.0
    direction_variability_deg: float = Field(default=25.0, ge=0)


class Dni(_Model):
    clear_sky_wm2: float = Field(default=1000.0, ge=0)      # DNI with the sun at the zenith, clear sky
    cloudy_fraction: float = Field(default=0.0, ge=0, le=1)  # share of daylight under passing clouds
    cloud_attenuation: float = Field(default=0.85, ge=0, le=1)
    cloud_duration_min: float = Field(default=10.0, gt=0)


class Temperature(_Model):
    mean_c: float = 12.0
    diurnal_amplitude_c: float = Field(default=7.0, ge=0)


class Pressure(_Model):
    mean_hpa: float | None = Field(default=None, gt=0)       # default: the site's pressure
    variability_hpa: float = Field(default=2.0, ge=0)


class Event(_Model):
    """An override during [start, end): any value given replaces the generated one."""

    start: Time
    end: Time
    wind_ms: float | None = Field(default=None, ge=0)
    wind_direction_deg: float | None = None
    dni_factor: float | None = Field(default=None, ge=0)
    temperature_c: float | None = None

    @model_validator(mode="after")
    def _ordered(self):
        from helicalib.geometry.sun import parse_time

        if not parse_time(self.start) < parse_time(self.end):
            raise ValueError(f"end {self.end} is not after start {self.start}")
        return self


class WeatherSpec(_Model):
    wind: Wind = Wind()
    dni: Dni = Dni()
    temperature: Temperature = Temperature()
    pressure: Pressure = Pressure()
    events: tuple[Event, ...] = ()


class Soiling(_Model):
    rate_per_day: float = Field(default=0.004, ge=0)        # cleanliness lost per day (field mean)
    rate_spread: float = Field(default=0.3, ge=0)           # relative std of the rate across heliostats
    clean_value: float = Field(default=0.97, gt=0, le=1)
    cleaning_interval_days: float = Field(default=14.0, gt=0)
    floor: float = Field(default=0.3, ge=0, le=1)


class Unmodelled(_Model):
    """Effects the error model does not contain (std across heliostats unless said otherwise)."""

    backlash_mm: float = Field(default=0.3, ge=0)           # dead band per actuator; half of it against the approach
    gravity_sag_mrad: float = Field(default=0.4, ge=0)      # mean sag of the normal at a horizontal mirror normal
    gravity_sag_spread_mrad: float = Field(default=0.1, ge=0)
    repeatability_mm: float = Field(default=0.05, ge=0)     # stroke noise, drawn anew at every move
    wind_jitter_mrad_per_ms: float = Field(default=0.05, ge=0)  # normal jitter std per m/s of wind
    drift_mrad_per_week: float = Field(default=0.05, ge=0)  # pedestal tilt drift (settlement), per axis


Range = tuple[float, float]


def _range(name: str, value: Range) -> Range:
    lo, hi = value
    if not 0 <= lo <= hi:
        raise ValueError(f"expected [low, high] with 0 <= low <= high, got [{lo}, {hi}]")
    return value


class Drift(_Model):
    """Drift events on a share of the heliostats: step changes and slow creep at random times.

    Each drifting heliostat gets one event, of a kind drawn with the ``kinds`` weights, at a time
    drawn uniformly in ``[start + after_days, start + after_days + within_days]``:

    * ``settle``: the pedestal tilts by a step of ``settle_mrad`` (uniform in the range) in a
      random direction (foundation settling; the beam moves by up to twice the tilt);
    * ``actuator``: one actuator's zero offset steps by ``actuator_mm`` with a random sign (an
      actuator or encoder swapped);
    * ``creep``: the pedestal tilts at ``creep_mrad_per_day`` in a random direction for
      ``creep_days``, then stays.
    """

    share: float = Field(default=0.0, ge=0, le=1)           # share of the heliostats that drift
    kinds: dict[Literal["settle", "actuator", "creep"], float] = Field(
        default_factory=lambda: {"settle": 0.4, "actuator": 0.3, "creep": 0.3})
    settle_mrad: Range = (2.0, 5.0)                          # pedestal tilt step [mrad]
    actuator_mm: Range = (1.0, 3.0)                          # zero-offset step of one actuator [mm]
    creep_mrad_per_day: Range = (0.1, 0.3)                   # pedestal tilt rate [mrad/day]
    creep_days: float = Field(default=30.0, gt=0)
    after_days: float = Field(default=1.0, ge=0)             # no event before start + after_days
    within_days: float | None = Field(default=None, gt=0)    # events spread over this span; default the scenario's rest

    @field_validator("settle_mrad", "actuator_mm", "creep_mrad_per_day")
    @classmethod
    def _ordered_range(cls, value, info):
        return _range(info.field_name, value)

    @field_validator("kinds")
    @classmethod
    def _weights(cls, value):
        if any(not w >= 0 for w in value.values()) or not sum(value.values()) > 0:
            raise ValueError("weights must be >= 0 with a positive sum")
        return value


class Optics(_Model):
    sun_sigma_mrad: float = Field(default=2.5, gt=0)        # Gaussian equivalent of the sun shape
    slope_error_mrad: float = Field(default=1.5, ge=0)      # mirror slope error (the beam gets twice this)
    reflectivity: float = Field(default=0.93, gt=0, le=1)


class Actuators(_Model):
    speed_mm_s: float = Field(default=10.0, gt=0)
    settle_s: float = Field(default=3.0, ge=0)


class CameraSpec(_Model):
    gain_counts_per_wm2: float = Field(default=0.2, gt=0)   # counts per W/m² on a white (albedo 1) surface: a 20 m² mirror at normal incidence peaks near 180 of 255
    noise_counts: float = Field(default=1.5, ge=0)          # std of the sensor noise
    ambient_fraction: float = Field(default=0.12, ge=0)     # diffuse light on the board per unit DNI
    ambient_offset_wm2: float = Field(default=30.0, ge=0)
    background_counts: float = Field(default=10.0, ge=0)    # sky/tower around the board at DNI 1000
    board_albedo: float = Field(default=0.9, gt=0, le=1)
    mark_albedo: float = Field(default=0.04, ge=0, le=1)   # T/GRLM's black L marks
    dot_albedo: float = Field(default=0.585, ge=0, le=1)   # a dot board's dots: light grey, 0.65 of the white (sim.render.DOT_ALBEDO)
    board_px_per_m: float = Field(default=40.0, gt=0)       # raster of the board before the warp
    exposure: bool = True                                   # the cameras take PLANT_INTERFACE 1.1's exposure_ms (false: fixed, no X-Exposure-Ms)
    exposure_ms: float = Field(default=1.0, gt=0)           # nominal exposure: the grey levels above hold at it
    exposure_range_ms: Range = (0.01, 100.0)                # what a camera applies, an asked exposure clamped to it
    read_noise_share: float = Field(default=0.45, ge=0, le=1)  # share of the noise variance at exposure_ms that does not grow with the exposure (read noise; the rest is shot noise)

    @field_validator("exposure_range_ms")
    @classmethod
    def _exposure_range(cls, value):
        lo, hi = _range("exposure_range_ms", value)
        if not lo > 0:
            raise ValueError(f"expected a positive low end, got {lo}")
        return value

    @model_validator(mode="after")
    def _nominal_in_range(self):
        lo, hi = self.exposure_range_ms
        if not lo <= self.exposure_ms <= hi:
            raise ValueError(f"exposure_ms {self.exposure_ms} lies outside exposure_range_ms [{lo}, {hi}]")
        return self


class Faults(_Model):
    modbus_drop_probability: float = Field(default=0.0, ge=0, le=1)
    modbus_slow_probability: float = Field(default=0.0, ge=0, le=1)
    modbus_slow_s: float = Field(default=3.0, ge=0)
    camera_503_probability: float = Field(default=0.0, ge=0, le=1)
    camera_truncate_probability: float = Field(default=0.0, ge=0, le=1)
    camera_slow_probability: float = Field(default=0.0, ge=0, le=1)
    camera_slow_s: float = Field(default=3.0, ge=0)
    offline: tuple[str, ...] = ()                           # heliostat ids that never answer commands


class Scenario(_Model):
    name: str = "default"
    start: Time | None = None          # ISO time with zone; the CLI's --start overrides
    duration_days: float = Field(default=7.0, gt=0)
    seed: int = 1
    tracking_aim: Literal["receiver", "target"] = "receiver"
    weather: WeatherSpec = WeatherSpec()
    soiling: Soiling = Soiling()
    errors: dict[str, float] | None = None   # std per error-model parameter; None = the model's priors
    unmodelled: Unmodelled = Unmodelled()
    drift: Drift = Drift()
    optics: Optics = Optics()
    actuators: Actuators = Actuators()
    camera: CameraSpec = CameraSpec()
    faults: Faults = Faults()

    @model_validator(mode="after")
    def _drift_within_the_scenario(self):
        if self.drift.share > 0 and self.drift.within_days is None and not self.drift.after_days < self.duration_days:
            raise ValueError(f"drift.after_days {self.drift.after_days} is not before the end of the scenario "
                             f"(duration_days {self.duration_days}); set drift.within_days")
        return self

    @field_validator("errors")
    @classmethod
    def _known_parameters(cls, value):
        if value is None:
            return value
        from helicalib.geometry import error_model as em

        for name, sigma in value.items():
            if name in em.BACKLASH:
                raise ValueError(f"{name}: the simulated backlash is unmodelled.backlash_mm, not an error parameter")
            if name not in em.GEOMETRIC:
                raise ValueError(f"unknown error-model parameter {name!r}; known: {', '.join(em.GEOMETRIC)}")
            if not sigma >= 0:
                raise ValueError(f"{name}: standard deviation must be >= 0")
        return value


def parse_scenario(data: Any, source: str | Path | None = None) -> Scenario:
    """Validate a scenario mapping (None or {} = all defaults)."""
    try:
        return Scenario.model_validate(data or {})
    except ValidationError as exc:
        raise validation_error(exc, source) from None


def load_scenario(path: str | Path | None) -> Scenario:
    """Read a scenario YAML file; ``None`` gives the default scenario."""
    if path is None:
        return Scenario()
    path = Path(path)
    return parse_scenario(read_yaml(path), path)
