"""What a fit minimises: losses as objects, several records in one padded batch with their nuisances, and the fit
problem (trained, separable and frozen parameters)."""
