//! Kinematics: URDF -> immutable `Model`; per-call scratch `Data`; FK, Jacobians, IK, manipulability.
