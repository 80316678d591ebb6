"""Least-squares identification: the residual objective, its compiled program, Levenberg-Marquardt,
the bounded transforms, ``fit`` with its diagnosis, profiles and the report."""
