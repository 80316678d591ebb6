"""Bayesian identification: priors, the posterior samplers (SMC by default; independence
Metropolis, HMC) and their report."""
