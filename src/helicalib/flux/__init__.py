"""helicalib.flux: the target camera as a flux meter (Zhang & Wang), and cleanliness from the spot.

Modules: ``grid`` (metric board grid), ``corrections`` (dark, non-linearity, flat field,
distortion, perspective, non-Lambertian), ``calibration`` (Fe by two radiometers or the sun,
ε_sys), ``fluxmap`` (E = Fe·G, peak, power, centre, plots), ``measure`` (before/after → flux map),
``cleanliness`` (measured vs expected power), ``config`` (FLUX.yaml), ``synth`` (forward model
for tests and benchmarks). See ``docs/flux.md``.
"""
