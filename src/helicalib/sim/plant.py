"""``SimulatedPlant``: the in-process simulated plant (implements ``devices.protocols.Plant``).

One state machine per heliostat, vectorised over the field (``PLANT_INTERFACE.md``): commands
act on a new sequence number; actuators travel at a finite speed, then settle (MOVING → HOLDING /
STOWED); stroke commands outside the range are refused (FAULT, code 1); during a field or wind
stow every command but stow is refused (code 2); unknown commands give code 3 (state unchanged);
offline heliostats never answer. Tracking = the *nominal* model's strokes for the aim point plus
the written corrections. Nothing reads the wall clock: plant time moves by ``advance_to``.

Two motions, one behaviour: ``SimulatedPlant(...)`` builds the closed-form
:class:`~helicalib.sim.lazy_plant.LazyPlant` (the default: each heliostat computed when read, a
clock advance costs the same at any field size), or with ``lazy=False`` the reference
:class:`~helicalib.sim.stepped_plant.SteppedPlant`, which steps every heliostat at every clock
advance. Both are ``SimulatedPlant`` instances (``isinstance``).
"""

from __future__ import annotations

from abc import ABC

from helicalib.sim.lazy_plant import LazyPlant
from helicalib.sim.scenario import Scenario
from helicalib.sim.stepped_plant import SteppedPlant


class SimulatedPlant(ABC):
    """A simulated tower plant with hidden true errors, weather, soiling and finite-speed drives.

    Takes :class:`~helicalib.sim.stepped_plant.SteppedPlant`'s parameters, and ``lazy``: True
    (default) builds a :class:`~helicalib.sim.lazy_plant.LazyPlant` (heliostats in closed form,
    computed when read), False the stepped reference itself.
    """

    def __new__(cls, cfg, scenario: Scenario | None = None, start_s: float = 0.0, rate: float = 1.0,
                zero_errors: bool = False, lazy: bool = True):
        if cls is not SimulatedPlant:  # a subclass would silently get a plant of another class
            raise TypeError(f"{cls.__name__}: subclass LazyPlant or SteppedPlant; SimulatedPlant only builds one of them")
        kind = LazyPlant if lazy else SteppedPlant
        return kind(cfg, scenario, start_s=start_s, rate=rate, zero_errors=zero_errors)


SimulatedPlant.register(SteppedPlant)  # both motions are SimulatedPlants (LazyPlant is a SteppedPlant)
