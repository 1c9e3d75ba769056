//! The thin adapter over the NLP solver: the one place to swap solvers.
