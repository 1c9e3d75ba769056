//! Low-dimensional humanlike motion: PCA, B-splines, navigation functions, flow, time scaling (eq. 8-9).
