"""Before a fit: the scales read off records, data-driven starts of each family, multi-element models' elements, and a
record's nuisances from its first samples (`fj.initialise`)."""
