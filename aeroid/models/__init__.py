"""Models and how they fly: `Model`, the integrators and compiled paths, the aircraft
models, the catalogue, aerodynamic coefficients."""
