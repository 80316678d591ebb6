"""Bayesian identification: priors, the posterior sampler (HMC/NUTS) and its report."""
