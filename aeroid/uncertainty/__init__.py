"""What the numbers are worth: sensitivities, error propagation, experiment design,
Bayesian inference, manoeuvres, validation and prediction, the aerodynamic database."""
